"""``dem-ros launch``: the node graph without ROS tooling, each node its own process.

Writes the run's full configuration as a ROS 2 params file, starts recorder,
reference, estimator, controller and plant_sim (last, so it starts its clock
once the others are set up; on hardware the driver first, so that a link with no
board behind it ends the start-up in seconds), shows the plant's status line live,
stops every process cleanly at the end or on Ctrl-C / SIGTERM (recorder last, so
the bag is complete), and prints a summary read back from the bag: the run's
verdict first (:mod:`.verdict`), tracking metrics (e = true gap - y_m, matched by
stamp), loop statistics and CPU per node.

Three steps (:class:`_Graph`): start, run, stop. What the launcher waits for comes from
the nodes' run-state events (:mod:`dem_ros.runstate`: set up, board answered, t = 0,
driver fault, finished), never from their log text; the progress line names it.
Options are typed (:class:`LaunchOptions`).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, fields
from datetime import datetime
from pathlib import Path
from typing import Any

from .. import __version__, runstate
from ..core.params import SCHEMA, with_board_limit
from ..core.scenarios import Scenario
from .common import (
    CONTROLLER_TYPES,
    ESTIMATOR_TYPES,
    UsageError,
    domain_id,
    env_domain_id,
    fmt_pair,
    load_config,
    out_dir,
    out_file,
    seconds,
    warm_kernels,
    write_json,
    yaml_scalar,
)
from .progress import Progress
from .runmetrics import RunMetrics
from .verdict import FAILED, INTERRUPTED_EXIT, OK, Verdict, judge
from .view import port as view_port

__all__ = ["GraphError", "LaunchOptions", "StartupError", "cmd_launch", "launch", "run_graph", "write_params_file"]

NODES = ("recorder", "reference", "estimator", "controller", "plant_sim")
#: the loop's nodes that ``--apart`` can take out of the container (the plant or driver and the recorder stay)
APART_NODES = ("estimator", "controller", "reference")


#: ``run_graph``'s hook: (wall s since t = 0 or None, node processes, restart(name)) -> names that may be down
Supervise = Callable[[float | None, dict[str, subprocess.Popen], Callable[[str], None]], Collection[str]]


class GraphError(RuntimeError):
    """The graph could not be started or run; the message says which node and where its log is."""


class StartupError(GraphError):
    """The graph did not start (a node exited or was not ready): nothing ran, no bag is kept."""


def write_params_file(cfg: dict[str, dict[str, Any]], path: Path) -> Path:
    """The run's full configuration as a ROS 2 params file (every group, every value)."""
    lines = ["# full configuration of one dem-ros launch run (ROS 2 params file)"]
    for group in SCHEMA.groups:
        lines += [f"{group}:", "  ros__parameters:"]
        lines += [f"    {k}: {yaml_scalar(v)}" for k, v in cfg[group].items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _last_line(path: Path) -> str:
    """The last non-empty line of a node's log (its error, when it exits during start-up)."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def _cpu_seconds(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _node_cmd(name: str, transport: str, params: Path, extra: list[str]) -> list[str]:
    return [sys.executable, "-m", "dem_ros.tools.node_main", name, "--transport", transport, *extra,
            "--ros-args", "--params-file", str(params)]


#: the run's run-state events (JSON lines, dem_ros.runstate), beside the node logs
RUN_STATE_FILE = "run_state.jsonl"
RIG_SUMMARY_FILE = "rig_summary.json"  # the emulated board's summary at its end (dem-ros rig --summary-file)
#: s: start-up bounds. A node must be set up (its "ready" event) within READY_S of its start; the board must
#: answer the driver's hello within BOARD_S of the driver's "ready"; t = 0 must come within T0_S of the last
#: node's "ready" (the plant's pre-roll, or the driver's arming and pre-roll)
READY_S = 120.0
BOARD_S = 10.0
T0_S = 60.0


class _Graph:
    """One run of the graph in three steps: :meth:`start` (every process up, the board answering, t = 0 reached
    or why not), :meth:`run` (until the plant ends the run), :meth:`stop` (every process stopped, the recorder
    last). Each node says what it is doing through the run-state pipe (:mod:`dem_ros.runstate`), never
    through its log text. ``not_started`` / ``cut_short`` say why the run did not start or ended early."""

    def __init__(self, cfg: dict, *, duration: float, transport: str, bag: Path | None, meta: dict,
                 domain_id: int | None, status: bool, workdir: Path | None, compose: bool, hardware: str | None,
                 faults: Sequence[str], supervise: Supervise | None,
                 node_transports: Mapping[str, str] | None = None, view_port: int | None = None,
                 apart: Sequence[str] = ()):
        self.workdir = workdir or Path(tempfile.mkdtemp(prefix="dem_ros_launch_"))
        self.workdir.mkdir(parents=True, exist_ok=True)
        cfg = {g: dict(v) for g, v in cfg.items()}
        cfg["plant_sim"]["duration"] = float(duration)
        if hardware is not None:
            cfg["hw_driver"]["duration"] = float(duration)
            cfg["hw_driver"]["auto_arm"] = True  # the launcher's run is the operator's arm
            if hardware not in ("rig", "rig-serial"):
                cfg["hw_driver"]["url"] = hardware
        self.cfg, self.duration, self.transport, self.bag = cfg, duration, transport, bag
        self.status, self.compose, self.hardware, self.faults, self.supervise = (
            status, compose, hardware, faults, supervise)
        self.node_transports = dict(node_transports or {})  # a node's own transport (e.g. the controller on rclpy)
        self.apart = tuple(apart)  # composed: these loop nodes in processes of their own beside the container
        self.view_port = view_port
        self.viewer: subprocess.Popen | None = None
        self.params = write_params_file(cfg, self.workdir / "params.yaml")
        env = dict(os.environ)
        if domain_id is None:
            domain_id = env_domain_id() or 0  # the ROS 2 default (what `ros2 topic list` in another shell sees)
        self.domain_id = domain_id
        env["ROS_DOMAIN_ID"] = str(domain_id)
        env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        env["PYTHONUNBUFFERED"] = "1"
        self.state_r, self.state_w = os.pipe()  # the nodes' run-state events (dem_ros.runstate)
        os.set_blocking(self.state_r, False)
        env[runstate.ENV] = str(self.state_w)
        self.env = env
        self.meta_file = self.workdir / "run_info.json"
        self.meta_file.write_text(json.dumps(meta))
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.started: dict[str, float] = {}
        self.interrupted = False
        self.cpu_start: dict[str, float] | None = None  # CPU seconds of each process when t = 0 was reached
        self.exits: list[dict[str, Any]] = []  # node processes that exited before the end (see _report_exit)
        self.seen_exits: set[int] = set()
        self.ready: set[str] = set()
        self.events: list[dict[str, Any]] = []  # every run-state event, in order (dem_ros.runstate)
        self.board: dict[str, Any] | None = None  # the driver's "board" event: the board answered
        self.t_zero: float | None = None
        self.finished: dict[str, Any] | None = None
        self.not_started: str | None = None
        self.cut_short: str | None = None
        self.rig: subprocess.Popen | None = None
        self.rig_summary: dict | None = None
        self.plant_node = "plant_sim" if hardware is None else "hw_driver"
        # the lead: its exit ends the run, its stdout has the status lines
        self.lead = "container" if compose and hardware is None else self.plant_node
        names = ["container"] if compose else [n if n != "plant_sim" else self.plant_node for n in NODES
                                               if n != "recorder" or bag is not None]
        if compose and hardware is not None:  # the loop's nodes composed, the driver beside them (it owns the link)
            names = ["container", *self.apart, "hw_driver"]
        elif compose and self.apart:  # the nodes apart first: the container's plant starts its clock when it is ready
            names = [*self.apart, "container"]
        if hardware is not None:  # the driver first: the board answers (or not) while the others start; the
            # controller last, once they are set up: its first commands arm the loop (the driver waits armed)
            names = ["hw_driver", *(n for n in names if n != "hw_driver")]
        self.names = names
        self._buf = ""
        self.t0 = time.monotonic()
        self.wall = 0.0
        self.cpu: dict[str, float] = {}

    # -- events -------------------------------------------------------------------------------------------
    def _events(self) -> None:
        """Read the nodes' run-state events (non-blocking) into the graph's state."""
        while True:
            try:
                chunk = os.read(self.state_r, 65536)
            except BlockingIOError:
                return
            if not chunk:
                return
            events, self._buf = runstate.parse(self._buf + chunk.decode(errors="replace"))
            for ev in events:
                self._on_event(ev)

    def _on_event(self, ev: dict[str, Any]) -> None:
        self.events.append(ev)
        with contextlib.suppress(OSError), open(self.workdir / RUN_STATE_FILE, "a") as out:  # kept with the logs
            out.write(json.dumps(ev) + "\n")
        kind, node = ev.get("event"), str(ev.get("node", ""))
        if kind == "ready":
            self.ready.add(node)
        elif kind == "board":
            self.board = ev
        elif kind == "t0" and self.t_zero is None:
            self.t_zero = time.monotonic()
            self.cpu_start = {n: _cpu_seconds(p.pid) for n, p in self.procs.items()}
            self.started = {n: time.monotonic() for n in self.procs}
        elif kind == "fault" and self.t_zero is None and self.not_started is None:
            # a driver fault before t = 0: the run ends at once, naming it (a fault during the run is the bag's)
            self.not_started = f"driver fault before t = 0: {ev.get('reason') or 'fault'}"
        elif kind == "finished":
            self.finished = ev

    # -- the emulated rig -----------------------------------------------------------------------------------
    def _start_rig(self) -> str:
        """Start ``dem-ros rig`` (UDP on a free loopback port, or a pty) and return the URL the driver opens, from
        the emulator's ``listening`` run-state event; its RIG lines go to rig.log (for people)."""
        import socket

        assert self.hardware is not None
        if self.hardware == "rig":
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:  # a free port (the rig binds it next)
                sock.bind(("127.0.0.1", 0))
                url = f"udp://127.0.0.1:{sock.getsockname()[1]}"
        else:
            url = "pty://"
        self.cfg["rig"]["url"] = url
        params = write_params_file(self.cfg, self.workdir / "rig_params.yaml")
        cmd = [sys.executable, "-m", "dem_ros.hardware.rig", "--params", str(params), "--url", url,
               "--summary-file", str(self.workdir / RIG_SUMMARY_FILE)]
        for f in self.faults:
            cmd += ["--fault", f]
        log = self.workdir / "rig.log"
        with open(log, "w") as out:
            self.rig = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                        env=self.env, pass_fds=(self.state_w,))
        end = time.monotonic() + 60.0
        while time.monotonic() < end and self.rig.poll() is None:
            self._events()
            for ev in self.events:
                if ev.get("node") == "rig" and ev.get("event") == "listening":
                    return str(ev["url"])
            time.sleep(0.05)
        if self.rig.poll() is None:
            self.rig.kill()
            self.rig.wait()
        raise StartupError(f"dem-ros rig did not start (code {self.rig.returncode}); see {log}")

    def _stop_rig(self) -> dict | None:
        """Stop the emulator (after the driver: it has landed the plate) and return its summary (None: it wrote
        none)."""
        if self.rig is None:
            return None
        _interrupt(self.rig)
        self._events()  # its last mode changes and statuses
        try:
            return json.loads((self.workdir / RIG_SUMMARY_FILE).read_text())
        except (OSError, ValueError):
            return None

    # -- start -------------------------------------------------------------------------------------------
    def _popen(self, name: str, params: Path, extra: list[str], append: bool = False) -> None:
        with open(self.logs[name], "ab" if append else "wb") as log_file:  # the child writes through its own fd
            lead = name == self.lead and not append
            self.procs[name] = subprocess.Popen(
                _node_cmd(name, self.node_transports.get(name, self.transport), params, extra), env=self.env,
                stdout=subprocess.PIPE if lead else log_file, stderr=subprocess.STDOUT, start_new_session=True,
                text=lead, pass_fds=(self.state_w,))
        self.started[name] = time.monotonic()

    def _check_exits(self, boot: bool) -> None:
        """A node that exited while the graph starts: StartupError naming it and its last log line."""
        for n, p in self.procs.items():
            if p.poll() is not None and boot:
                why = _last_line(self.logs[n])
                raise StartupError(f"node {n} exited during start-up (code {p.returncode})"
                                   + (f": {why}" if why else "") + f"; see {self.logs[n]}")

    def _wait(self, done: Callable[[], bool], timeout: float, what: Callable[[], str] | str, boot: Progress) -> bool:
        """Wait until ``done()`` (events read, exits checked), saying ``what()`` it waits for; False on timeout."""
        end = time.monotonic() + timeout
        t_start = time.monotonic()
        while time.monotonic() < end and not self.interrupted:
            self._events()
            if done() or self.not_started:
                return True
            self._check_exits(boot=True)
            boot.stage(f"waiting for {what if isinstance(what, str) else what()} ({time.monotonic() - t_start:.0f} s)")
            time.sleep(0.05)
        return done()

    def start(self, boot: Progress) -> None:
        """Every process started; returns once the run is under way (t = 0 may follow: the plant's pre-roll).

        Raises:
            StartupError: a node exited or was not ready, no board answered (hardware), the driver faulted.
        """
        url = self.cfg["hw_driver"]["url"]
        if self.view_port is not None:  # first: subscribed before the plant starts its clock
            with open(self.workdir / "view.log", "wb") as view_log:
                self.viewer = subprocess.Popen(
                    [sys.executable, "-m", "dem_ros.tools.view", "--port", str(self.view_port),
                     "--transport", self.transport], env=self.env, stdout=view_log, stderr=subprocess.STDOUT,
                    start_new_session=True)
            where = f"ws://127.0.0.1:{self.view_port}" if self.view_port else "the port in its log"
            print(f"dem-ros launch: live view on {where} (Foxglove; log {self.workdir / 'view.log'})",
                  file=sys.stderr, flush=True)
        for name in self.names:
            bag_args = ["--bag", str(self.bag), "--meta", str(self.meta_file)] if self.bag is not None else []
            extra = bag_args if name in ("recorder", "container") else []
            if name == "container" and (self.hardware is not None or self.apart):
                inside = [n for n in NODES if n != "recorder" and n not in self.apart
                          and (n != "plant_sim" or self.hardware is None)]  # the container orders them itself
                extra = [*extra, "--nodes", ",".join(inside)]
                if self.apart and self.hardware is None:  # its plant starts the clock: the nodes apart are up first
                    self._wait_nodes(boot, list(self.apart))
            self.logs[name] = self.workdir / f"{name}.log"
            node_params = self.params
            if name == "hw_driver" and self.hardware in ("rig", "rig-serial"):  # the emulator first, then its driver
                url = self._start_rig()
                self.cfg["hw_driver"]["url"] = url
                node_params = write_params_file(self.cfg, self.workdir / "hw_driver_params.yaml")
            if name == "plant_sim":  # last, once the others are set up: it starts its clock at once
                self._wait_nodes(boot)
            if name == "controller" and self.hardware is not None:  # its commands start the loop: last
                self._wait_nodes(boot, [n for n in self.started if n not in ("hw_driver", "container")])
            self._popen(name, node_params, extra)
            if name == "hw_driver":  # the link first: no board, no run (and no waiting for the other nodes)
                if not self._wait(lambda: "hw_driver" in self.ready, READY_S, "hw_driver", boot):
                    raise StartupError(f"node hw_driver not ready after {READY_S:.0f} s; see {self.logs['hw_driver']}")
                if not self._wait(lambda: self.board is not None, BOARD_S, f"the board at {url}", boot):
                    raise StartupError(_no_board(url, BOARD_S))
        self._wait_nodes(boot)
        if self.not_started:
            raise StartupError(self.not_started)

    def _wait_nodes(self, boot: Progress, names: Sequence[str] | None = None) -> None:
        """Until every node of ``names`` said "ready" (default: all but the plant; composed, the loop's nodes
        in the container)."""
        if names is not None:
            waiting = list(names)
        elif self.compose:
            waiting = ["reference", "estimator", "controller"] if self.hardware is not None else []
        else:
            waiting = [n for n in self.names if n != self.plant_node]
        if not self._wait(lambda: all(n in self.ready for n in waiting), READY_S,
                          lambda: ", ".join(n for n in waiting if n not in self.ready), boot):
            raise StartupError(f"nodes not ready after {READY_S:.0f} s: "
                               + ", ".join(n for n in waiting if n not in self.ready))

    # -- run ---------------------------------------------------------------------------------------------
    def restart(self, name: str) -> None:
        """``supervise``'s restart: ``name`` started again, its log appended."""
        self._popen(name, self.params, [], append=True)

    def run(self, boot: Progress) -> None:
        """Until the plant's process ends the run (or Ctrl-C, a node's unexpected exit, a fault before t = 0)."""
        plant = self.procs[self.lead]
        assert plant.stdout is not None  # a pipe (stdout=PIPE in _popen)
        plant_out = plant.stdout
        limit = time.monotonic() + 60.0 + 10.0 * (self.duration + self.cfg["plant_sim"]["preroll"])
        t0_limit = time.monotonic() + T0_S
        os.set_blocking(plant_out.fileno(), False)
        buf = ""
        tty = sys.stderr.isatty()
        last_status = 0.0
        with open(self.logs[self.lead], "w") as plant_log:
            while plant.poll() is None and not self.interrupted and time.monotonic() < limit:
                was_zero = self.t_zero
                self._events()
                if self.t_zero is not None and was_zero is None:
                    boot.close(f"dem-ros launch: the run began (t = 0) {boot.elapsed:.0f} s after the start")
                if self.not_started:
                    break  # a driver fault before t = 0
                if self.t_zero is None:
                    boot.stage("waiting for t = 0 (" + ("the driver's arming and pre-roll" if self.hardware
                                                          else "the plant's pre-roll") + ")")
                    if time.monotonic() > t0_limit:
                        self.not_started = (f"never reached t = 0 within {T0_S:.0f} s of start-up; "
                                            f"see {self.logs[self.lead]}")
                        break
                t = None if self.t_zero is None else time.monotonic() - self.t_zero
                may_be_down = self.supervise(t, self.procs, self.restart) if self.supervise is not None else ()
                for name, p in self.procs.items():
                    if name == self.lead or p.poll() is None:
                        continue
                    _report_exit(self.exits, self.seen_exits, name, p, self.t_zero, self.logs[name])
                    if name not in may_be_down and name != "recorder" and self.cut_short is None:
                        # a dead recorder costs the recording, not the plate
                        self.cut_short = f"node {name} exited early with code {p.returncode}; see {self.logs[name]}"
                if self.cut_short is not None:
                    break
                time.sleep(0.1)
                try:
                    chunk = plant_out.read()
                except (BlockingIOError, TypeError):
                    chunk = None
                if chunk:
                    plant_log.write(chunk)
                    plant_log.flush()  # users (and tests) follow the run in the log
                    buf += chunk
                    lines = buf.split("\n")
                    buf = lines[-1]
                    for line in lines[:-1]:  # the status lines, for people (the run's state comes as events)
                        if self.status and line.startswith("t ="):
                            if tty:  # redrawn in place on a terminal; a log gets a line every 5 s
                                print("\r  " + line.strip(), end="", file=sys.stderr, flush=True)
                            elif time.monotonic() - last_status >= 5.0:
                                print("  " + line.strip(), file=sys.stderr, flush=True)
                                last_status = time.monotonic()
            if self.status and tty:
                print(file=sys.stderr)
            self._events()
            if plant.poll() is not None and self.t_zero is None and not self.not_started and not self.interrupted:
                why = _last_line(self.logs[self.lead])
                self.not_started = (f"{self.lead} exited before t = 0 (code {plant.returncode})"
                                    + (f": {why}" if why else ""))
            rest = plant_out.read() if plant.poll() is not None else None
            if rest:
                plant_log.write(rest)

    # -- stop --------------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Stop every process: the plant (if still running) and controllers first, the recorder last (so the
        bag is complete). On hardware the driver goes first: stopped, it lands the plate before it lets go
        of the link (nodes/hw_driver.py), while the controller still runs; stopping the controller first
        would leave the board without commands, and its watchdog landing would end the run as a failure."""
        self.wall = time.monotonic() - self.t0
        for name, p in self.procs.items():
            self.cpu[name] = _cpu_seconds(p.pid)
        halt = Progress("dem-ros launch", None, enabled=self.status)
        halt.stage("stopping the nodes (the recorder last, so the bag is complete)")
        if self.viewer is not None:  # the live view first: it never ends the run
            if self.viewer.poll() is not None:
                print(f"dem-ros launch: the live view exited early (code {self.viewer.returncode}); see "
                      f"{self.workdir / 'view.log'}", file=sys.stderr, flush=True)
            _interrupt(self.viewer)
        order: tuple[str, ...] = ("container", "plant_sim", "hw_driver", "controller", "estimator", "reference",
                                  "recorder")
        if self.hardware is not None:
            order = ("hw_driver", *(n for n in order if n != "hw_driver"))
        for name in order:
            proc = self.procs.get(name)
            if proc is None or proc.poll() is not None:
                continue
            if name == "recorder":
                time.sleep(0.3)  # last samples in flight
            _interrupt(proc)
        self.rig_summary = self._stop_rig()
        self._events()  # the last ones (the recorder's counters when it closed the bag)
        halt.close()
        for fd in (self.state_r, self.state_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def facts(self) -> dict[str, Any]:
        """The raw facts of the run (see :func:`run_graph`)."""
        elapsed = {n: (time.monotonic() - self.started[n]) for n in self.procs}
        base = self.cpu_start or {}
        cpu = {n: c - base.get(n, 0.0) for n, c in self.cpu.items()}
        cpu_pct = {n: round(100.0 * cpu[n] / max(elapsed[n], 1e-9), 1) for n in self.procs if cpu[n] == cpu[n]}
        recorder_counts = None  # the recorder's per-topic counters when it closed the bag (its "recorded" event)
        for ev in self.events:
            if ev.get("event") == "recorded" and ev.get("node") == "recorder":
                recorder_counts = ev.get("counts")
        return {"interrupted": self.interrupted, "wall_s": self.wall, "cpu_percent": cpu_pct,
                "returncodes": {n: p.returncode for n, p in self.procs.items()},
                "logs": {n: str(p) for n, p in self.logs.items()}, "recorder": recorder_counts,
                "domain_id": self.domain_id, "workdir": str(self.workdir), "rig": self.rig_summary,
                "exits": self.exits, "cut_short": self.cut_short, "reached_t0": self.t_zero is not None,
                "events": self.events}


def _no_board(url: str, waited: float) -> str:
    """The one line for a link on which no board answered the driver's hello, with what to check."""
    check = ("the board is powered and its firmware runs the dem_ros link on that port; nothing else holds the"
             " port; a firewall lets UDP through" if url.startswith("udp:")
             else "the cable, the device path and the baud rate; the board is powered and runs the dem_ros link")
    return f"no board answered at {url} within {waited:g} s; check that {check}"


def run_graph(cfg: dict, *, duration: float, transport: str, bag: Path | None, meta: dict,
              domain_id: int | None = None, status: bool = True, workdir: Path | None = None,
              compose: bool = False, hardware: str | None = None, faults: Sequence[str] = (),
              supervise: Supervise | None = None, node_transports: Mapping[str, str] | None = None,
              view_port: int | None = None, apart: Sequence[str] = ()) -> dict:
    """Start the graph, wait for the plant to finish ``duration`` s, stop everything; return raw facts.

    ``compose``: all nodes in one ``container`` process (intra-process topics)
    instead of one process per node. ``hardware``: ``hw_driver`` in place of
    ``plant_sim``, on the link ``udp://HOST:PORT`` or ``serial:///dev/...``; ``rig``
    (UDP on loopback) or ``rig-serial`` (a pty pair) also start the emulator
    ``dem-ros rig`` with ``faults`` (see :mod:`dem_ros.hardware.rig`). With hardware the driver starts
    first; no board answering its hello within :data:`BOARD_S` s ends the start-up.

    ``supervise(t, procs, restart)`` (``dem-ros faults``) is called every 0.1 s with the wall time
    since t = 0 (None before), the node processes by name (it may kill them) and ``restart(name)``
    (starts that node again, its log appended); it returns the names that may be down now. Any
    other node that exits ends the run: ``cut_short`` in the facts says which (the run failed).
    ``node_transports``: a node's own transport instead of ``transport`` (e.g. the controller on
    rclpy/Fast DDS, the rest on dds/Cyclone).
    ``view_port``: also run ``dem-ros view`` on that port (the live view, :mod:`.view`), started first
    and stopped first; its log is ``view.log``; it never ends the run.
    ``apart``: with ``compose``, these of the loop's nodes (estimator, controller, reference) run in processes
    of their own beside the container, e.g. a controller that can be killed and restarted on its own.

    Raises:
        StartupError: the run never started (a node exited or was not ready, no board answered, a driver fault
            before t = 0, no t = 0 within :data:`T0_S` s); every process is stopped first.
    """
    g = _Graph(cfg, duration=duration, transport=transport, bag=bag, meta=meta, domain_id=domain_id, status=status,
               workdir=workdir, compose=compose, hardware=hardware, faults=faults, supervise=supervise,
               node_transports=node_transports, view_port=view_port, apart=apart)

    def on_signal(signum, frame):
        g.interrupted = True

    old = {}
    if threading.current_thread() is threading.main_thread():  # Ctrl-C / SIGTERM stop the graph cleanly
        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    boot = Progress("dem-ros launch", None, enabled=status)  # never silent while the nodes start (a first run: minutes)
    boot.stage(f"starting {', '.join(g.names)}")
    try:
        g.start(boot)
        g.run(boot)
    finally:
        boot.close()
        g.stop()
        for s, h in old.items():
            signal.signal(s, h)
    if g.not_started and not g.interrupted:
        raise StartupError(g.not_started)
    return g.facts()


def _report_exit(exits: list[dict[str, Any]], seen: set[int], name: str, proc: subprocess.Popen,
                 t_zero: float | None, log: Path) -> None:
    """A node process that ended before the run: said at once on stderr (always: a fault is never silent) and
    kept in ``exits`` as {node, code, wall_s (since t = 0, None before), log}; each process once."""
    if proc.pid in seen:
        return
    seen.add(proc.pid)
    wall = None if t_zero is None else round(time.monotonic() - t_zero, 3)
    exits.append({"node": name, "code": proc.returncode, "wall_s": wall, "log": str(log)})
    when = "before t = 0" if wall is None else f"{wall:.1f} s (wall) after t = 0"
    what = {"recorder": "the recording is lost from then on; the bag keeps what was written (see dem-ros bag check)"}
    print(f"dem-ros launch: node {name} exited with code {proc.returncode} {when}: "
          + what.get(name, "its topics stop") + f"; see {log}", file=sys.stderr, flush=True)


def _interrupt(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """Ctrl-C for a node or the emulator (it shuts down cleanly); killed if not gone within ``timeout`` [s]."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _resolve_transport(transport: str) -> str:
    """``auto`` -> the transport the nodes will use (rclpy when it imports, else dds)."""
    from ..transport import rclpy_available

    if transport == "rclpy" and not rclpy_available():
        raise UsageError("--transport rclpy needs a sourced ROS 2 (import rclpy failed); use dds")
    return ("rclpy" if rclpy_available() else "dds") if transport == "auto" else transport


@dataclass
class LaunchOptions:
    """The options of one ``dem-ros launch`` run (the command line's, typed; ``dem-ros faults`` and ``bench``
    build them directly). See :func:`add_arguments` for each."""

    scenario: str = "S1"
    controller: str | None = None
    estimator: str | None = None
    duration: float | None = None  # s; None: the scenario's
    transport: str = "auto"
    compose: bool = False
    free_run: bool = False
    params: str | None = None
    set: list[str] = field(default_factory=list)
    bag_dir: str = "bags"
    no_record: bool = False
    json: str | None = None
    domain_id: int | None = None
    hardware: str | None = None
    fault: list[str] = field(default_factory=list)
    view: int | None = None  # the live view's port (dem-ros view); None: none
    apart: list[str] = field(default_factory=list)  # with compose: loop nodes in processes of their own

    @classmethod
    def from_namespace(cls, ns: argparse.Namespace) -> LaunchOptions:
        """From the parsed command line (its unknown keys, e.g. the sub-command's, left out)."""
        known = {f.name for f in fields(cls)}
        given = {k: v for k, v in vars(ns).items() if k in known}
        for k in ("set", "fault", "apart"):
            given[k] = list(given.get(k) or [])
        return cls(**given)


#: controller.command_delay of a run on the emulated rig (``--hardware rig`` / ``rig-serial``: the launcher
#: configures the emulated board too), unless the configuration sets it. With a process per node a measurement
#: crosses three processes (driver -> estimator -> controller -> driver) over DDS, p50 0.8 ms, p99 1.8-2.6 ms
#: on a loaded 2-core host: with 1 sample half the commands came too late (the board held, then landed); 3
#: samples leave the loop's tail room, composed as well (the law predicts over it; offline simulates it). A
#: real board applies commands at its firmware's delay (its hello says which; the driver refuses another):
#: there the configuration must name it.
RIG_COMMAND_DELAY = 3


def _options(args: LaunchOptions | argparse.Namespace) -> LaunchOptions:
    return args if isinstance(args, LaunchOptions) else LaunchOptions.from_namespace(args)


def _delay_is_set(opts: LaunchOptions) -> bool:
    """The run's configuration names controller.command_delay (--set or --params): the user's, kept."""
    if any(s.split("=", 1)[0].strip() == "controller.command_delay" for s in opts.set):
        return True
    if opts.params:
        from .common import load_params_file

        return "command_delay" in (load_params_file(opts.params).get("controller") or {})
    return False


def _config_from_args(args: LaunchOptions | argparse.Namespace) -> tuple[dict[str, dict[str, Any]], Scenario, float]:
    opts = _options(args)
    cfg, sc = load_config(opts.scenario, opts.params, opts.set)
    if opts.controller:
        cfg["controller"]["type"] = opts.controller
    if opts.estimator:
        cfg["estimator"]["type"] = opts.estimator
    if opts.free_run:
        cfg["plant_sim"]["lockstep"] = False
    if opts.hardware in ("rig", "rig-serial") and not _delay_is_set(opts):
        d = RIG_COMMAND_DELAY
        cfg["controller"]["command_delay"] = d
        cfg["controller"]["max_age"] = max(cfg["controller"]["max_age"], (d + 1) * cfg["plant_sim"]["dt"])
    duration = opts.duration if opts.duration is not None else sc.duration
    return cfg, sc, duration


def _check_hardware(opts: LaunchOptions) -> None:
    """--hardware and --fault checked before anything starts: a malformed or unreachable link is one line."""
    hw = opts.hardware
    if opts.fault and hw not in ("rig", "rig-serial"):
        raise UsageError("--fault needs --hardware rig or rig-serial (faults are injected by the emulated rig)")
    if hw is None or hw in ("rig", "rig-serial"):
        return
    from urllib.parse import urlsplit

    from ..hardware.channel import ChannelError, check_link

    if urlsplit(hw).scheme not in ("udp", "serial"):
        raise UsageError(f"--hardware: got {hw!r}, expected udp://HOST:PORT, serial:///dev/PATH, rig or rig-serial")
    try:
        check_link(hw)
    except ChannelError as exc:
        raise UsageError(f"--hardware: {exc}") from None


def launch(args: LaunchOptions | argparse.Namespace, *, quiet: bool = False, supervise: Supervise | None = None,
           logs_dir: Path | None = None) -> tuple[RunMetrics, dict[str, Any]]:
    """Run the graph as ``dem-ros launch`` does: (metrics read back from the bag, launch facts).

    ``logs_dir``: where the node logs go (default: beside the bag, ``<bag>_logs``; ``dem-ros faults``
    keeps them off the small disk its disk-full row fills).

    The facts: ``composed``, ``offline_rms_error_um`` (the same configuration
    simulated offline), ``bag`` (None without recording), ``recorder`` (per-topic
    counts), ``interrupted``, ``cut_short``. The metrics carry the run's verdict (:mod:`.verdict`).

    Raises:
        UsageError: a bad option or link (nothing started, nothing written).
        StartupError: the run never started (no bag is kept): the verdict is failed, the message says why.
    """
    opts = _options(args)
    cfg, sc, duration = _config_from_args(opts)
    # every check before anything starts or is written
    # the ROS 2 default, as `ros2 topic echo` in another shell uses it: --domain-id, else ROS_DOMAIN_ID, else 0
    domain_id = opts.domain_id if opts.domain_id is not None else (env_domain_id() or 0)
    hardware = opts.hardware
    _check_hardware(opts)
    bad = [n for n in opts.apart if n not in APART_NODES]
    if bad or len(set(opts.apart)) != len(opts.apart):
        raise UsageError(f"--apart: got {', '.join(opts.apart)}; distinct names of {', '.join(APART_NODES)}")
    if opts.apart and not opts.compose:
        raise UsageError("--apart needs --compose (without it every node has a process of its own)")
    transport = _resolve_transport(opts.transport)
    cfg = with_board_limit(cfg, "plant_sim" if hardware is None else "hw_driver")  # the law clips where the board does
    if not quiet:
        print(f"dem-ros launch: {sc.name} ({sc.description}), controller {cfg['controller']['type']},"
              f" estimator {cfg['estimator']['type']}, {duration:g} s, transport {transport},"
              f" ROS_DOMAIN_ID {domain_id}",
              file=sys.stderr, flush=True)
    # compile once, here, with progress; the nodes then load the cache instead of compiling in parallel
    # and the offline loop of the comparison run (the longest compile of all, else silent at the very end)
    warm_kernels("dem-ros launch", stream=io.StringIO() if quiet else None,
                 offline=[(cfg["controller"]["type"], cfg["estimator"]["type"])])
    from ..core.simulate import simulate  # numba: loaded (or compiled) above, under the progress line

    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    bag_root = Path(opts.bag_dir)
    bag_root.mkdir(parents=True, exist_ok=True)
    record = not opts.no_record
    tmp = None
    if record:
        bag = bag_root / f"{stamp}_{sc.name}_{cfg['controller']['type']}"
    else:
        tmp = Path(tempfile.mkdtemp(prefix="dem_ros_bag_"))
        bag = tmp / "run"
    meta = {"scenario": sc.name, "scenario_description": sc.description, "controller": cfg["controller"]["type"],
            "estimator": cfg["estimator"]["type"], "transport": transport, "duration_s": duration,
            "dem_ros_version": __version__, "config": cfg, "started": datetime.now().isoformat(timespec="seconds")}
    compose = opts.compose
    meta["composed"] = compose
    if hardware is not None:  # a rig measures no gap rates: the offline comparison neither
        cfg["plant_sim"]["measure_velocity"] = False
        # one command delay: the controller predicts over it, the board applies it, offline simulates it
        d = cfg["controller"]["command_delay"]
        cfg["hw_driver"]["command_delay"] = cfg["plant_sim"]["command_delay"] = d
        meta["hardware"] = hardware
    try:
        facts = run_graph(cfg, duration=duration, transport=transport, bag=bag, meta=meta, domain_id=domain_id,
                          status=not quiet,
                          workdir=logs_dir or ((bag.parent / (bag.name + "_logs")) if record else None),
                          compose=compose, hardware=hardware, faults=opts.fault,
                          supervise=supervise, view_port=opts.view, apart=opts.apart)
        if facts["interrupted"] and not facts["reached_t0"]:  # Ctrl-C while starting: no run, no bag (exit 130)
            raise KeyboardInterrupt
        with Progress("dem-ros launch", None, enabled=not quiet) as bar:
            bar.stage(f"reading the bag for the metrics ({bag.name})")
            metrics = RunMetrics.from_bag(bag)
    except (StartupError, KeyboardInterrupt):
        if record:  # nothing ran: no partial bag (the node logs stay, the error names them)
            shutil.rmtree(bag, ignore_errors=True)
        raise
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    metrics.wall_time_s = facts["wall_s"]
    for e in facts["exits"]:  # a node that died during the run: the summary says so (and what it cost)
        when = "before t = 0" if e["wall_s"] is None else f"{e['wall_s']:.1f} s (wall) after t = 0"
        cost = (f"the recording is lost from t = {metrics.samples * cfg['plant_sim']['dt']:.3f} s (the bag's last"
                " complete chunk)" if e["node"] == "recorder" else "see its log")
        metrics.problems.insert(0, f"node {e['node']} exited with code {e['code']} {when}: {cost}")
    if metrics.loop is not None:  # the plant's process exits before the launcher can read its CPU time: it reports it
        cpu = dict(facts["cpu_percent"])
        if metrics.loop.plant_cpu_percent is not None:
            cpu["hw_driver" if hardware is not None else ("container" if compose else "plant_sim")] = (
                metrics.loop.plant_cpu_percent)
        metrics.loop.cpu_percent = cpu
    ran = duration
    if facts["interrupted"]:  # compare like with like: the offline run over the time the graph ran
        ran = metrics.samples * cfg["plant_sim"]["dt"]
    with Progress("dem-ros launch", None, enabled=not quiet) as bar:
        bar.stage(f"the offline run to compare with ({ran:g} s, same configuration and timing)")
        offline = simulate(cfg, controller=cfg["controller"]["type"], estimator=cfg["estimator"]["type"], duration=ran,
                           scenario=sc.name).metrics() if ran > 0 else {"rms_error_um": None}
    info = {"composed": compose, "apart": list(opts.apart), "offline_rms_error_um": offline["rms_error_um"],
            "offline_duration_s": ran, "bag": str(bag) if record else None,
            "hardware": hardware, "rig": facts.get("rig"), "cut_short": facts["cut_short"], "events": facts["events"],
            "recorder": facts["recorder"], "interrupted": facts["interrupted"], "exits": facts["exits"]}
    _judge(metrics, facts)
    if record and bag.is_dir():  # the run-time summary travels with the bag (replay compares against it)
        try:
            write_json(bag / "summary.json", metrics.to_dict() | info)
        except OSError as exc:  # a full disk (the recorder reported it): the summary is still printed
            metrics.problems.append(f"summary.json not written beside the bag: {exc.strerror or exc}")
            _judge(metrics, facts)
    return metrics, info


def _judge(metrics: RunMetrics, facts: dict[str, Any]) -> None:
    """The run's verdict from the bag's facts and the launcher's own (a node that cut the run short, the
    problems added here): the one rule of :func:`dem_ros.tools.verdict.judge`."""
    f = metrics.facts
    if f is None:  # pragma: no cover - from_bag always sets them
        return
    f.problems = metrics.problems
    f.cut_short = facts["cut_short"]
    metrics.set_verdict(judge(f))


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``dem-ros launch`` (also parsed by ``dem-ros faults`` for its runs)."""
    p.add_argument("--scenario", default="S1", help="scenario name from config/scenarios.yaml (default S1; "
                   "see dem-ros sim --scenario): plant truth, reference steps and perturbations of the run")
    p.add_argument("--controller", default=None, choices=CONTROLLER_TYPES,
                   help="control law (default: config, 'adaptive')")
    p.add_argument("--estimator", default=None, choices=ESTIMATOR_TYPES, help="state estimator (default: config, 'kf')")
    p.add_argument("--duration", type=seconds, default=None, help="seconds (default: the scenario's)")
    p.add_argument("--transport", default="auto", choices=["auto", "rclpy", "dds"],
                   help="auto (rclpy when it imports, else dds) | rclpy (ROS 2 Jazzy sourced, or pip install "
                        "-e '.[ros]'; on Fast DDS the one whose parameters and services `ros2` reaches) | dds (no "
                        "ROS install; rmw_cyclonedds' wire: topics reach any vendor, services only Cyclone); "
                        "docs/manual/transports.md")
    p.add_argument("--compose", action="store_true",
                   help="all nodes in one process on one executor, topics between them in memory; "
                        "the real-time configuration")
    p.add_argument("--apart", action="append", default=[], metavar="NODE", choices=APART_NODES,
                   help="with --compose: run NODE (estimator, controller or reference) in a process of its own beside "
                        "the container, e.g. a controller to kill and restart on its own (repeatable)")
    p.add_argument("--free-run", action="store_true",
                   help="free-running plant (plant_sim.lockstep false): hardware-like timing, a late command is held "
                        "at most hold_timeout, then the simulated board lands the plate; default: lockstep (exact)")
    p.add_argument("--params", default=None, help="ROS 2 params file")
    p.add_argument("--set", action="append", metavar="GROUP.NAME=VALUE", help="override a parameter, e.g. k1=60")
    p.add_argument("--bag-dir", type=out_dir, default="bags", help="where the run's bag goes (default ./bags)")
    p.add_argument("--no-record", action="store_true", help="do not record a bag")
    p.add_argument("--json", type=out_file, default=None, help="write the summary as JSON")
    p.add_argument("--domain-id", type=domain_id, default=None, help="ROS_DOMAIN_ID for this run")
    p.add_argument("--hardware", default=None, metavar="LINK",
                   help="hw_driver instead of plant_sim, on udp://HOST:PORT or serial:///dev/PATH; 'rig' (UDP) or "
                        "'rig-serial' (a pty pair) also start the emulator 'dem-ros rig'")
    p.add_argument("--view", type=view_port, nargs="?", const=8765, default=None, metavar="PORT",
                   help="also serve the run live to Foxglove on ws://127.0.0.1:PORT (default 8765; dem-ros view)")
    p.add_argument("--fault", action="append", default=None, metavar="SPEC",
                   help="with --hardware rig: inject a rig fault, e.g. linkloss@10+0.05 (dem-ros rig --help-faults)")


def cmd_launch(args: argparse.Namespace) -> int:
    opts = LaunchOptions.from_namespace(args)
    try:
        metrics, info = launch(opts)
    except StartupError as exc:  # the run never started: failed, one line (and the JSON says the same)
        v = Verdict(FAILED, (str(exc),))
        print(f"dem-ros launch: {v.line().replace('verdict  ', '', 1)}", file=sys.stderr)
        if opts.json:
            write_json(opts.json, v.to_dict())
        return v.exit_code
    how = "one process (composed)" if info["composed"] else "a process per node"
    if info.get("apart"):
        how = f"composed, {', '.join(info['apart'])} in a process of its own"
    extra = [("processes", how)]
    if info["offline_rms_error_um"] is not None:
        extra.append(("offline RMS error e1 / e2 [um]",
                      f"{fmt_pair(info['offline_rms_error_um'])} (same configuration and timing, "
                      f"first {info['offline_duration_s']:g} s)"))
    if info["recorder"]:
        rc = info["recorder"]
        lost = (rc.get("/dem/measurement") or {}).get("lost")  # the plant's samples the bag lacks (its stamp grid)
        extra.append(("recorded", f"{sum(v['written'] for v in rc.values())} messages,"
                                  f" {sum(v['dropped'] for v in rc.values())} dropped"
                                  + (f", {lost} plant samples lost" if lost is not None else "")))
    if info.get("rig"):
        r = info["rig"]
        extra.append(("rig (emulated board)", f"{r['ticks']} samples, {r['late_over_1ms']} ticks > 1 ms late,"
                                              f" {r['commands_fresh']} fresh commands,"
                                              f" board {r.get('board', 'python')}: {r['mode']}"
                                              + (f" ({r['reason']})" if r.get("reason") else "")
                                              + (f", FAILED: {r['failed']}" if r.get("failed") else "")))
        for f in r.get("faults", []):
            extra.append((f"  fault {f['kind']}" + (f":{f['channel']}" if f["channel"] else ""),
                          f"at {f['start']:g} s, acted on {f['hits']} samples"))
    if info["bag"]:
        extra.append(("bag", info["bag"]))
    metrics.print(extra=extra)
    if opts.json:
        write_json(opts.json, metrics.to_dict() | info)
        print(f"  summary written to {opts.json}")
    if metrics.verdict != OK:
        print(f"dem-ros launch: {metrics.verdict_line().replace('verdict  ', '', 1)}", file=sys.stderr)
    return INTERRUPTED_EXIT if info["interrupted"] else metrics.exit_code
