"""``dem-ros launch``: the node graph without ROS tooling, each node its own process.

Writes the run's full configuration as a ROS 2 params file, starts recorder,
reference, estimator, controller and plant_sim (last, so it starts its clock
once the others have matched), shows the plant's status line live, stops every
process cleanly at the end or on Ctrl-C / SIGTERM (recorder last, so the bag
is complete), and prints a summary read back from the bag: tracking metrics
(e = true gap - y_m, matched by stamp), loop statistics and CPU per node.
"""

from __future__ import annotations

import argparse
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
from collections.abc import Callable, Collection, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from .. import __version__
from ..core.params import SCHEMA
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

__all__ = ["GraphError", "StartupError", "cmd_launch", "launch", "run_graph", "write_params_file"]

NODES = ("recorder", "reference", "estimator", "controller", "plant_sim")


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


def _wait_ready(logs: dict, procs: dict, timeout: float) -> None:
    """Block until every log says 'ready' (kernels loaded, subscriptions made)."""
    end = time.monotonic() + timeout
    pending = dict(logs)
    while pending and time.monotonic() < end:
        for n, path in list(pending.items()):
            if procs[n].poll() is not None:
                why = _last_line(path)
                raise StartupError(f"node {n} exited during start-up (code {procs[n].returncode})"
                                 + (f": {why}" if why else "") + f"; see {path}")
            try:
                if "ready" in path.read_text(errors="replace"):
                    del pending[n]
            except OSError:
                pass
        time.sleep(0.05)
    if pending:
        raise StartupError(f"nodes not ready after {timeout:.0f} s: {', '.join(pending)}")


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


def run_graph(cfg: dict, *, duration: float, transport: str, bag: Path | None, meta: dict,
              domain_id: int | None = None, status: bool = True, workdir: Path | None = None,
              compose: bool = False, hardware: str | None = None, faults: Sequence[str] = (),
              supervise: Supervise | None = None) -> dict:
    """Start the graph, wait for the plant to finish ``duration`` s, stop everything; return raw facts.

    ``compose``: all nodes in one ``container`` process (intra-process topics)
    instead of one process per node. ``hardware``: ``hw_driver`` in place of
    ``plant_sim``, on the link ``udp://HOST:PORT`` or ``serial:///dev/...``; ``rig``
    (UDP on loopback) or ``rig-serial`` (a pty pair) also start the emulator
    ``dem-ros rig`` with ``faults`` (see :mod:`dem_ros.hardware.rig`).

    ``supervise(t, procs, restart)`` (``dem-ros faults``) is called every 0.1 s with the wall time
    since t = 0 (None before), the node processes by name (it may kill them) and ``restart(name)``
    (starts that node again, its log appended); it returns the names that may be down now. Any
    other node that exits ends the run with a :class:`GraphError` (the run was cut short).
    """
    workdir = workdir or Path(tempfile.mkdtemp(prefix="dem_ros_launch_"))
    workdir.mkdir(parents=True, exist_ok=True)
    cfg = {g: dict(v) for g, v in cfg.items()}
    cfg["plant_sim"]["duration"] = float(duration)
    rig = None
    if hardware is not None:
        cfg["hw_driver"]["duration"] = float(duration)
        cfg["hw_driver"]["auto_arm"] = True  # the launcher's run is the operator's arm
        if hardware not in ("rig", "rig-serial"):
            cfg["hw_driver"]["url"] = hardware
    params = write_params_file(cfg, workdir / "params.yaml")
    env = dict(os.environ)
    if domain_id is None:
        domain_id = env_domain_id() or 0  # the ROS 2 default (what `ros2 topic list` in another shell sees)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env["PYTHONUNBUFFERED"] = "1"
    meta_file = workdir / "run_info.json"
    meta_file.write_text(json.dumps(meta))
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    started = {}
    cpu: dict[str, float] = {}
    interrupted = False
    cpu_start: dict[str, float] | None = None  # CPU seconds of each process when t = 0 was reached
    exits: list[dict[str, Any]] = []  # node processes that exited before the end (reported at once, see _report_exit)
    seen_exits: set[int] = set()  # their pids

    def on_signal(signum, frame):
        nonlocal interrupted
        interrupted = True

    old = {}
    if threading.current_thread() is threading.main_thread():  # Ctrl-C / SIGTERM stop the graph cleanly
        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    plant_node = "plant_sim" if hardware is None else "hw_driver"
    lead = "container" if compose and hardware is None else plant_node  # its exit ends the run; its stdout has the status lines
    names = ["container"] if compose else [n if n != "plant_sim" else plant_node for n in NODES if n != "recorder" or bag is not None]
    if compose and hardware is not None:  # the loop's nodes composed, the driver beside them (it owns the link)
        names = ["container", "hw_driver"]
    boot = Progress("dem-ros launch", None, enabled=status)  # never silent while the nodes start (a first run: minutes)
    boot.stage(f"starting {', '.join(names)}; the plant starts the clock once all are ready")
    t0 = time.monotonic()
    try:
        for name in names:
            bag_args = ["--bag", str(bag), "--meta", str(meta_file)] if bag is not None else []
            extra = bag_args if name in ("recorder", "container") else []
            if name == "container" and hardware is not None:
                extra = [*extra, "--nodes", "estimator,controller,reference"]
            logs[name] = workdir / f"{name}.log"
            node_params = params
            if name == "hw_driver" and hardware in ("rig", "rig-serial"):  # the emulator starts last, with the driver
                rig, cfg["hw_driver"]["url"] = _start_rig(cfg, hardware, faults, workdir)
                node_params = write_params_file(cfg, workdir / "hw_driver_params.yaml")
            with open(logs[name], "wb") as log_file:  # the child writes through its own descriptor
                procs[name] = subprocess.Popen(_node_cmd(name, transport, node_params, extra), env=env,
                                               stdout=subprocess.PIPE if name == lead else log_file,
                                               stderr=subprocess.STDOUT, start_new_session=True,
                                               text=(name == lead))
            started[name] = time.monotonic()
            if name == "controller" or (name == "container" and hardware is not None):  # wait for their "ready"
                _wait_ready({n: logs[n] for n in procs if n != plant_node}, procs, timeout=120.0)
        plant = procs[lead]
        assert plant.stdout is not None  # a pipe (stdout=PIPE above)
        plant_out = plant.stdout
        with open(logs[lead], "w") as plant_log:
            limit = time.monotonic() + 60.0 + 10.0 * (duration + cfg["plant_sim"]["preroll"])  # lockstep may run below real time
            os.set_blocking(plant_out.fileno(), False)
            buf = ""
            tty = sys.stderr.isatty()
            last_status = 0.0
            t_zero: float | None = None

            def restart(name: str) -> None:
                with open(logs[name], "ab") as out:
                    procs[name] = subprocess.Popen(_node_cmd(name, transport, params, []), env=env, stdout=out,
                                                   stderr=subprocess.STDOUT, start_new_session=True)

            while plant.poll() is None and not interrupted and time.monotonic() < limit:
                may_be_down = supervise(None if t_zero is None else time.monotonic() - t_zero, procs, restart) \
                    if supervise is not None else ()
                for name, p in procs.items():
                    if name == lead or p.poll() is None:
                        continue
                    _report_exit(exits, seen_exits, name, p, t_zero, logs[name])
                    if name not in may_be_down and name != "recorder":  # a dead recorder costs the recording, not the plate
                        raise GraphError(f"node {name} exited early with code {p.returncode}; see {logs[name]}")
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
                    for line in lines[:-1]:
                        if line.startswith("t =") and cpu_start is None:  # the run (t >= 0) has begun
                            t_zero = time.monotonic()
                            boot.close(f"dem-ros launch: the nodes were ready in {boot.elapsed:.0f} s")
                            cpu_start = {n: _cpu_seconds(p.pid) for n, p in procs.items()}
                            started = {n: time.monotonic() for n in procs}
                        if status and line.startswith("t ="):
                            if tty:  # redrawn in place on a terminal; a log gets a line every 5 s
                                print("\r  " + line.strip(), end="", file=sys.stderr, flush=True)
                            elif time.monotonic() - last_status >= 5.0:
                                print("  " + line.strip(), file=sys.stderr, flush=True)
                                last_status = time.monotonic()
            if status and tty:
                print(file=sys.stderr)
            rest = plant_out.read() if plant.poll() is not None else None
            if rest:
                plant_log.write(rest)
    finally:
        boot.close()
        wall = time.monotonic() - t0
        for name, p in procs.items():
            cpu[name] = _cpu_seconds(p.pid)
        halt = Progress("dem-ros launch", None, enabled=status)
        halt.stage("stopping the nodes (the recorder last, so the bag is complete)")
        # stop: plant (if still running) and controllers first, recorder last. On hardware the driver goes first:
        # stopped, it lands the plate before it lets go of the link (nodes/hw_driver.py), while the controller
        # still runs; stopping the controller first would leave the board without commands, and its watchdog
        # landing would end the run as a failure
        order: tuple[str, ...] = ("container", "plant_sim", "hw_driver", "controller", "estimator", "reference", "recorder")
        if hardware is not None:
            order = ("hw_driver", *(n for n in order if n != "hw_driver"))
        for name in order:
            proc = procs.get(name)
            if proc is None or proc.poll() is not None:
                continue
            if name == "recorder":
                time.sleep(0.3)  # last samples in flight
            _interrupt(proc)
        rig_summary = _stop_rig(rig)
        halt.close()
        for s, h in old.items():
            signal.signal(s, h)
    elapsed = {n: (time.monotonic() - started[n]) for n in procs}
    base = cpu_start or {}
    cpu = {n: c - base.get(n, 0.0) for n, c in cpu.items()}
    cpu_pct = {n: round(100.0 * cpu[n] / max(elapsed[n], 1e-9), 1) for n in procs if cpu[n] == cpu[n]}
    recorder_counts = None
    rec_log = logs.get("container" if compose else "recorder")
    if bag is not None and rec_log is not None and rec_log.exists():
        for line in rec_log.read_text(errors="replace").splitlines():
            if line.startswith("RECORDER "):
                recorder_counts = json.loads(line[len("RECORDER "):])
    return {"interrupted": interrupted, "wall_s": wall, "cpu_percent": cpu_pct, "returncodes": {n: p.returncode for n, p in procs.items()},
            "logs": {n: str(p) for n, p in logs.items()}, "recorder": recorder_counts, "domain_id": domain_id, "workdir": str(workdir),
            "rig": rig_summary, "exits": exits}


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


def _start_rig(cfg: dict, kind: str, faults: Sequence[str], workdir: Path) -> tuple[subprocess.Popen, str]:
    """Start ``dem-ros rig`` (UDP on a free loopback port, or a pty) and return (process, the URL the driver opens)."""
    import socket

    if kind == "rig":
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:  # a free port (the rig binds it next)
            sock.bind(("127.0.0.1", 0))
            url = f"udp://127.0.0.1:{sock.getsockname()[1]}"
    else:
        url = "pty://"
    cfg["rig"]["url"] = url
    params = write_params_file(cfg, workdir / "rig_params.yaml")
    cmd = [sys.executable, "-m", "dem_ros.hardware.rig", "--params", str(params), "--url", url]
    for f in faults:
        cmd += ["--fault", f]
    log = workdir / "rig.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    end = time.monotonic() + 60.0
    while time.monotonic() < end:
        for line in log.read_text(errors="replace").splitlines():
            if line.startswith("RIG ") and '"listening"' in line:
                proc.log = log  # type: ignore[attr-defined]
                return proc, json.loads(line[4:])["url"]
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    if proc.poll() is None:
        proc.kill()
        proc.wait()
    raise StartupError(f"dem-ros rig did not start (code {proc.returncode}); see {log}")


def _interrupt(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """Ctrl-C for a node or the emulator (it shuts down cleanly); killed if not gone within ``timeout`` [s]."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _stop_rig(proc: subprocess.Popen | None) -> dict | None:
    """Stop the emulator (after the driver: it has landed the plate) and return its summary."""
    if proc is None:
        return None
    _interrupt(proc)
    summary = None
    for line in proc.log.read_text(errors="replace").splitlines():  # type: ignore[attr-defined]
        if line.startswith("RIG ") and '"summary"' in line:
            summary = json.loads(line[4:])
    return summary


def _resolve_transport(transport: str) -> str:
    """``auto`` -> the transport the nodes will use (rclpy when it imports, else dds)."""
    from ..transport import rclpy_available

    if transport == "rclpy" and not rclpy_available():
        raise UsageError("--transport rclpy needs a sourced ROS 2 (import rclpy failed); use dds")
    return ("rclpy" if rclpy_available() else "dds") if transport == "auto" else transport


def _config_from_args(args: Any) -> tuple[dict[str, dict[str, Any]], Scenario, float]:
    cfg, sc = load_config(args)
    if args.controller:
        cfg["controller"]["type"] = args.controller
    if args.estimator:
        cfg["estimator"]["type"] = args.estimator
    if getattr(args, "free_run", False):
        cfg["plant_sim"]["lockstep"] = False
    duration = args.duration if args.duration is not None else sc.duration
    return cfg, sc, duration


def launch(args: Any, *, quiet: bool = False, supervise: Supervise | None = None,
           logs_dir: Path | None = None) -> tuple[RunMetrics, dict[str, Any]]:
    """Run the graph as ``dem-ros launch`` does: (metrics read back from the bag, launch facts).

    ``logs_dir``: where the node logs go (default: beside the bag, ``<bag>_logs``; ``dem-ros faults``
    keeps them off the small disk its disk-full row fills).

    The facts: ``composed``, ``offline_rms_error_um`` (the same configuration
    simulated offline), ``bag`` (None without recording), ``recorder`` (per-topic
    counts), ``interrupted``.
    """
    cfg, sc, duration = _config_from_args(args)
    # every check before anything starts or is written
    # the ROS 2 default, as `ros2 topic echo` in another shell uses it: --domain-id, else ROS_DOMAIN_ID, else 0
    domain_id = args.domain_id if args.domain_id is not None else (env_domain_id() or 0)
    hardware = getattr(args, "hardware", None)
    if hardware is not None and hardware not in ("rig", "rig-serial"):
        from urllib.parse import urlsplit

        if urlsplit(hardware).scheme not in ("udp", "serial"):
            raise UsageError(f"--hardware: got {hardware!r}, expected udp://HOST:PORT, serial:///dev/PATH, rig or rig-serial")
    if getattr(args, "fault", None) and hardware not in ("rig", "rig-serial"):
        raise UsageError("--fault needs --hardware rig or rig-serial (faults are injected by the emulated rig)")
    transport = _resolve_transport(args.transport)
    if not quiet:
        print(f"dem-ros launch: {sc.name} ({sc.description}), controller {cfg['controller']['type']},"
              f" estimator {cfg['estimator']['type']}, {duration:g} s, transport {transport}, ROS_DOMAIN_ID {domain_id}",
              file=sys.stderr, flush=True)
    # compile once, here, with progress; the nodes then load the cache instead of compiling in parallel
    # and the offline loop of the comparison run (the longest compile of all, else silent at the very end)
    warm_kernels("dem-ros launch", stream=io.StringIO() if quiet else None,
                 offline=[(cfg["controller"]["type"], cfg["estimator"]["type"])])
    from ..core.simulate import simulate  # numba: loaded (or compiled) above, under the progress line

    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    bag_root = Path(args.bag_dir)
    bag_root.mkdir(parents=True, exist_ok=True)
    record = not args.no_record
    tmp = None
    if record:
        bag = bag_root / f"{stamp}_{sc.name}_{cfg['controller']['type']}"
    else:
        tmp = Path(tempfile.mkdtemp(prefix="dem_ros_bag_"))
        bag = tmp / "run"
    meta = {"scenario": sc.name, "scenario_description": sc.description, "controller": cfg["controller"]["type"],
            "estimator": cfg["estimator"]["type"], "transport": transport, "duration_s": duration,
            "dem_ros_version": __version__, "config": cfg, "started": datetime.now().isoformat(timespec="seconds")}
    compose = bool(getattr(args, "compose", False))
    meta["composed"] = compose
    if hardware is not None:  # a rig measures no gap rates: the offline comparison neither
        cfg["plant_sim"]["measure_velocity"] = False
        # one command delay: the controller predicts over it, the board applies it, offline simulates it
        d = cfg["controller"]["command_delay"]
        cfg["hw_driver"]["command_delay"] = cfg["plant_sim"]["command_delay"] = d
        meta["hardware"] = hardware
    try:
        facts = run_graph(cfg, duration=duration, transport=transport, bag=bag, meta=meta, domain_id=domain_id,
                          status=not quiet, workdir=logs_dir or ((bag.parent / (bag.name + "_logs")) if record else None),
                          compose=compose, hardware=hardware, faults=getattr(args, "fault", None) or (),
                          supervise=supervise)
        with Progress("dem-ros launch", None, enabled=not quiet) as bar:
            bar.stage(f"reading the bag for the metrics ({bag.name})")
            metrics = RunMetrics.from_bag(bag)
    except StartupError:
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
            cpu["hw_driver" if hardware is not None else ("container" if compose else "plant_sim")] = metrics.loop.plant_cpu_percent
        metrics.loop.cpu_percent = cpu
    ran = duration
    if facts["interrupted"]:  # compare like with like: the offline run over the time the graph ran
        ran = metrics.samples * cfg["plant_sim"]["dt"]
    with Progress("dem-ros launch", None, enabled=not quiet) as bar:
        bar.stage(f"the offline run to compare with ({ran:g} s, same configuration and timing)")
        offline = simulate(cfg, controller=cfg["controller"]["type"], estimator=cfg["estimator"]["type"], duration=ran,
                           scenario=sc.name).metrics() if ran > 0 else {"rms_error_um": None}
    info = {"composed": compose, "offline_rms_error_um": offline["rms_error_um"], "offline_duration_s": ran, "bag": str(bag) if record else None,
            "hardware": hardware, "rig": facts.get("rig"),
            "recorder": facts["recorder"], "interrupted": facts["interrupted"], "exits": facts["exits"]}
    if record and bag.is_dir():  # the run-time summary travels with the bag (replay compares against it)
        try:
            write_json(bag / "summary.json", metrics.to_dict() | info)
        except OSError as exc:  # a full disk (the recorder reported it): the summary is still printed
            metrics.problems.append(f"summary.json not written beside the bag: {exc.strerror or exc}")
    return metrics, info


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``dem-ros launch`` (also parsed by ``dem-ros faults`` for its runs)."""
    p.add_argument("--scenario", default="S1", help="scenario name from config/scenarios.yaml (default S1; "
                   "see dem-ros sim --scenario): plant truth, reference steps and perturbations of the run")
    p.add_argument("--controller", default=None, choices=CONTROLLER_TYPES, help="control law (default: config, 'adaptive')")
    p.add_argument("--estimator", default=None, choices=ESTIMATOR_TYPES, help="state estimator (default: config, 'kf')")
    p.add_argument("--duration", type=seconds, default=None, help="seconds (default: the scenario's)")
    p.add_argument("--transport", default="auto", choices=["auto", "rclpy", "dds"],
                   help="auto (rclpy when it imports, else dds) | rclpy | dds (no ROS install needed)")
    p.add_argument("--compose", action="store_true",
                   help="all nodes in one process on one executor, topics between them in memory (dds); "
                        "the real-time configuration")
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
    p.add_argument("--fault", action="append", default=None, metavar="SPEC",
                   help="with --hardware rig: inject a rig fault, e.g. linkloss@10+0.05 (dem-ros rig --help-faults)")


def cmd_launch(args: Any) -> int:
    metrics, info = launch(args)
    how = "one process (composed)" if info["composed"] else "a process per node"
    extra = [("processes", how)]
    if info["offline_rms_error_um"] is not None:
        extra.append(("offline RMS error e1 / e2 [um]",
                      f"{fmt_pair(info['offline_rms_error_um'])} (same configuration and timing, first {info['offline_duration_s']:g} s)"))
    if info["recorder"]:
        rc = info["recorder"]
        lost = (rc.get("/dem/measurement") or {}).get("lost")  # the plant's samples the bag lacks (its stamp grid)
        extra.append(("recorded", f"{sum(v['written'] for v in rc.values())} messages,"
                                  f" {sum(v['dropped'] for v in rc.values())} dropped"
                                  + (f", {lost} plant samples lost" if lost is not None else "")))
    if info.get("rig"):
        r = info["rig"]
        extra.append(("rig (emulated board)", f"{r['ticks']} samples, {r['late_over_1ms']} ticks > 1 ms late,"
                                              f" {r['commands_fresh']} fresh commands, board {r['mode']}"
                                              + (f" ({r['reason']})" if r.get("reason") else "")
                                              + (f", FAILED: {r['failed']}" if r.get("failed") else "")))
        for f in r.get("faults", []):
            extra.append((f"  fault {f['kind']}" + (f":{f['channel']}" if f["channel"] else ""),
                          f"at {f['start']:g} s, acted on {f['hits']} samples"))
    if info["bag"]:
        extra.append(("bag", info["bag"]))
    metrics.print(extra=extra)
    if args.json:
        write_json(args.json, metrics.to_dict() | info)
        print(f"  summary written to {args.json}")
    if info["interrupted"]:
        return 130
    if metrics.failed or metrics.problems:
        why = (["the run failed"] if metrics.failed else []) + metrics.problems
        print(f"dem-ros launch: degraded run: {'; '.join(why)}", file=sys.stderr)
        return 1
    return 0
