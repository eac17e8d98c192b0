"""``dem-ros faults``: the fault catalogue of issue #12, injected into the real graph, one run per row.

Each row launches the graph (``dem-ros launch``: real processes over DDS, or ``--compose``), injects one
fault at t = ``--at`` s of the experiment and reads the outcome back from the run's bag:

* **outcome**: ``levitating`` (the board still runs the controller's commands at the end and the true
  gap is within 1 mm of the reference), ``landed safely`` (the board landed the plate, never nearer the
  rail than ``trip_gap_min``), or ``failed`` (rail contact, a plant failure, or a run cut short by an
  unexpected exit). The plant's truth (``/dem/plant/truth``) gives the minimum gap and the largest
  tracking error (true gap - reference) from the fault on.
* **reported**: the ``/diagnostics`` statuses at WARN or ERROR after the fault (from the bag, and those heard
  live by this process that the bag lacks, marked "(live)": a full disk stops the recording before the
  recorder's own ERROR), and the node log lines at WARN or ERROR (count per node).
* **data lost**: what the recorder dropped and what the bag reports about itself (truncated, recording
  stopped early, samples without a reference); "none" when the bag is complete.

A row passes when its outcome is one the row allows (messages, steps and spikes must leave the plate
levitating; a killed node may end in a safe landing where the outage outlasts the board's hold) and the
fault is reported. Injected messages come from this process, a foreign DDS participant on the graph's
domain (:class:`Injector`); nodes are killed with SIGKILL and restarted by the launcher's hook.

**Hardware rows** (``--hardware rig``, :data:`RIG_CATALOGUE`): ``dem-ros launch --hardware rig --compose`` (the
hardware driver, and the emulated board and rig ``dem-ros rig`` as its own free-running 1 kHz process, over UDP on
loopback; ``controller.command_delay=2``), one row per rig fault (``dem-ros rig --fault``, scheduled on the board's
clock at the experiment's t = ``--at``), an e-stop on ``/dem/hw/estop`` or a killed controller (for that row the
controller runs in a process of its own beside the container: ``--apart controller``). A rig has no truth topic, so
the plate's truth is the emulator's own (its ``RIG`` summary in ``rig.log``: smallest true gap since the release,
fastest descent while the board landed it, rail contact):

* **outcome**: ``failed`` on rail contact (the emulated plant's failure, or a true gap at ``gap_min``), a board
  FAULT (0 V), a landing nearer the rail than ``trip_gap_min`` or descending faster than ``landing_speed`` (where
  the row's design bounds it: a failed coil's end or a bus below what holds the plate cannot be bounded); else
  ``landed safely`` when the driver's loop status says the board landed the plate (or the driver faulted) during
  the experiment, ``levitating`` when the measured gaps end within 1 mm of the reference (the max error column:
  measured gap - reference, from the fault on).
* **reported**: one of the row's words (``reports``) in a WARN/ERROR ``/diagnostics`` status or a WARN/ERROR log
  line from the fault on (e.g. the driver's "e-stop: ..." ERROR, its "corrupt +48" WARN).
* **counted**: the row's counters (``counts``) of the driver (its last loop status in the bag), the board (the
  emulated board's Supervisor counters) or the estimator, each at least its minimum; the emulator's own hit
  count beside them.

A hardware row passes when its outcome is allowed, the fault is reported and counted, and the board did not land
the plate before the fault (a host stall on a loaded machine: that landing is not the fault's, the row says so).

Exit status: 0 when every row passes, 1 otherwise (2: usage).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import contract
from .common import UsageError, write_json

if TYPE_CHECKING:
    from .launcher import LaunchOptions

__all__ = ["CATALOGUE", "RIG_CATALOGUE", "FaultSpec", "Injector", "Row", "add_arguments", "cmd_faults", "run_row"]

DT_NS = 1_000_000
_LEVEL = re.compile(r"^\[(WARN|ERROR)\] \[[0-9.]+\] \[([^\]]+)\]")


class Injector:
    """A foreign participant on the graph's domain: follows the experiment clock, injects messages.

    ``t`` is the experiment time [s] of the newest ``/dem/measurement`` (None before t = 0). The
    injection (``act(self)``) runs on this object's thread, once per received sample from ``at`` s
    until it returns False.
    """

    def __init__(self, act: Callable[[Injector], bool] | None, at: float, extra: tuple[contract.Topic, ...] = ()):
        from ..transport import make_node

        self.node = make_node("dem_ros_faults", transport="dds", args=[])
        self.js = self.node.msg("sensor_msgs/msg/JointState")
        self.act, self.at = act, at
        self.epoch: int | None = None
        self.meas: Any = None
        self.est: Any = None
        self.ref: Any = None
        self.t: float | None = None
        self.injected = 0
        self.killed_ns: int | None = None  # ROS (system) time of a SIGKILL by the kill hook
        self.events: list[str] = []  # what was done when (experiment time)
        self.counts: dict[str, int] = {}  # injected samples, by outcome
        self.pubs: dict[str, Any] = {}
        for topic in (contract.COMMAND, contract.MEASUREMENT, contract.ESTIMATE, contract.REFERENCE, contract.APPLIED,
                      *extra):
            self.pub(topic)  # matched long before t = 0 (a writer made at the fault would miss its first samples)
        self.node.subscribe(contract.MEASUREMENT, self._on_meas)
        self.node.subscribe(contract.ESTIMATE, lambda m: setattr(self, "est", m))
        self.node.subscribe(contract.REFERENCE, lambda m: setattr(self, "ref", m))
        # /diagnostics as it is published: what a bag cannot keep (a full disk stops the recording) is seen here
        self.diags: list[tuple[float, str, int]] = []  # (experiment time, name, level) at WARN or ERROR
        self.node.subscribe(contract.DIAGNOSTICS, self._on_diag)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, name="dem-ros-faults", daemon=True)
        self.thread.start()

    def pub(self, topic: contract.Topic) -> Any:
        if topic.name not in self.pubs:
            self.pubs[topic.name] = self.node.publisher(topic)
        return self.pubs[topic.name]

    def _on_meas(self, m: Any) -> None:
        from ..nodes.common import stamp_ns

        if m.header.frame_id == contract.FRAME and len(m.position) >= 2:
            t = stamp_ns(m)
            if self.epoch is None:
                self.epoch = t
            self.t = (t - self.epoch) * 1e-9
            self.meas = m
            if self.act is not None and self.t >= self.at and not self.act(self):
                self.act = None

    def _on_diag(self, m: Any) -> None:
        for st in m.status:
            level = contract.status_level(st)
            if level >= 1:
                self.diags.append((-math.inf if self.t is None else self.t, str(st.name), level))

    def live_levels(self, t_from: float) -> list[str]:
        """'name LEVEL' of the statuses heard at WARN or ERROR from experiment time ``t_from`` on (worst per name)."""
        return _worst_levels((name, level) for t, name, level in list(self.diags) if t >= t_from)

    def _spin(self) -> None:
        while not self.stop.is_set():
            self.node.spin_once(0.01)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=2.0)
        self.node.shutdown()


# -- the injections ------------------------------------------------------------------------------------
def _copy(inj: Injector, m: Any, *, t_ns: int | None = None, position=None, frame: str | None = None) -> Any:
    from ..nodes.common import stamp_ns

    h = inj.js().header
    t = stamp_ns(m) if t_ns is None else t_ns
    h.stamp.sec, h.stamp.nanosec = t // 1_000_000_000, t % 1_000_000_000
    h.frame_id = m.header.frame_id if frame is None else frame
    return inj.js(header=h, name=list(m.name), position=list(m.position) if position is None else list(position),
                  velocity=list(m.velocity), effort=list(m.effort))


def _n_times(n: int, fn: Callable[[Injector], None]) -> Callable[[Injector], bool]:
    def act(inj: Injector) -> bool:
        from ..transport import TransportError

        try:
            fn(inj)
        except TransportError:  # Cyclone DDS refuses to write some malformed samples
            inj.counts["refused by the DDS writer"] = inj.counts.get("refused by the DDS writer", 0) + 1
        inj.injected += 1
        return inj.injected < n
    return act


def _rogue_command(inj: Injector) -> None:
    m = inj.meas
    inj.pub(contract.COMMAND).publish(inj.js(header=m.header, name=list(contract.MAGNETS), effort=[1e6, 1e6]))


def _empty_position(inj: Injector) -> None:
    inj.pub(contract.MEASUREMENT).publish(_copy(inj, inj.meas, position=[]))
    if inj.est is not None:
        inj.pub(contract.ESTIMATE).publish(_copy(inj, inj.est, position=[]))


def _non_utf8(inj: Injector) -> None:
    from ..transport import serialize

    for topic, m in ((contract.MEASUREMENT, inj.meas), (contract.ESTIMATE, inj.est), (contract.REFERENCE, inj.ref)):
        if m is None:
            continue
        data = bytearray(serialize(_copy(inj, m, frame="\x01\x02\x03")))
        i = data.find(b"\x01\x02\x03")
        data[i:i + 3] = b"\xff\xfe\xfd"
        inj.pub(topic).publish_raw(bytes(data))


_RNG = np.random.default_rng(12)


def _bad_cdr(inj: Injector) -> None:
    """A valid sample of each topic with 8 seeded random bytes after the encapsulation header overwritten
    (same length: Cyclone DDS refuses to write some corruptions, counted as ``refused``)."""
    from ..transport import TransportError, serialize

    for topic, m in ((contract.MEASUREMENT, inj.meas), (contract.ESTIMATE, inj.est), (contract.REFERENCE, inj.ref),
                     (contract.APPLIED, inj.meas), (contract.COMMAND, inj.meas)):
        if m is None:
            continue
        data = bytearray(serialize(m))
        for i, v in zip(_RNG.integers(4, len(data), 8).tolist(), _RNG.integers(0, 256, 8).tolist(), strict=True):
            data[i] = v
        try:
            inj.pub(topic).publish_raw(bytes(data))
            inj.counts["sent"] = inj.counts.get("sent", 0) + 1
        except TransportError:
            inj.counts["refused by the DDS writer"] = inj.counts.get("refused by the DDS writer", 0) + 1


def _reference_step(inj: Injector) -> None:
    from ..nodes.common import stamp_ns

    if inj.ref is None:
        return
    p = list(inj.ref.position)
    p[0] += 0.02
    p[1] += 0.02
    inj.pub(contract.REFERENCE).publish(_copy(inj, inj.ref, t_ns=stamp_ns(inj.meas) + DT_NS, position=p))


def _spike(mm: float) -> Callable[[Injector], None]:
    def act(inj: Injector) -> None:
        p = list(inj.meas.position)
        p[0] += mm * 1e-3
        inj.pub(contract.MEASUREMENT).publish(_copy(inj, inj.meas, position=p))
    return act


def _stale(inj: Injector) -> None:
    from ..nodes.common import stamp_ns

    if inj.est is not None:
        inj.pub(contract.ESTIMATE).publish(_copy(inj, inj.est, t_ns=stamp_ns(inj.est) - 100 * DT_NS))
    inj.pub(contract.MEASUREMENT).publish(_copy(inj, inj.meas, t_ns=stamp_ns(inj.meas) + 3600 * 10**9))


def _future_applied(inj: Injector) -> None:
    """One /dem/applied_voltage stamped 1 h ahead: what a corrupt stamp (bad-cdr) looks like to its readers."""
    from ..nodes.common import stamp_ns

    inj.pub(contract.APPLIED).publish(_copy(inj, inj.meas, t_ns=stamp_ns(inj.meas) + 3600 * 10**9))


@dataclass(frozen=True)
class FaultSpec:
    """One row of the catalogue: a message injection (``act``, ``n`` samples) or a SIGKILL of ``kill``
    (restarted after ``restart_after`` s; None: not restarted). ``allowed``: outcomes that pass."""

    name: str
    description: str
    act: Callable[[Injector], None] | None = None
    n: int = 1
    kill: str | None = None
    restart_after: float | None = None
    allowed: tuple[str, ...] = ("levitating",)
    composed: bool = True  # also run composed (a kill needs a process per node)
    min_duration: float = 0.0  # s: a restarted node needs seconds to start (imports, kernels, discovery)
    disk_kib: int = 0  # record onto a tmpfs of this size (KiB; root), the logs elsewhere: the disk fills mid-run
    # hardware rows (RIG_CATALOGUE: hw_driver and the emulated board, `dem-ros launch --hardware rig`)
    hardware: bool = False
    rig_fault: str | None = None  # a `dem-ros rig --fault` spec; {t}: the fault's time on the board's clock
    reports: tuple[str, ...] = ()  # one of these words in a WARN/ERROR status or log line after the fault
    counts: tuple[tuple[str, str, int], ...] = ()  # (driver | board | estimator, counter, at least): who counted it
    descent_bounded: bool = True  # a landing must stay within landing_speed (the emulator's truth)


_KILLED = ("levitating", "landed safely")
_RESTART_S = 15.0  # run length with a restart: a restarted node takes seconds to come up on a loaded host
CATALOGUE: tuple[FaultSpec, ...] = (
    FaultSpec("rogue-command", "1e6 V on /dem/command from a foreign writer, 50 samples", _rogue_command, 50),
    FaultSpec("empty-position", "/dem/measurement and /dem/state_estimate with an empty position, 10 samples",
              _empty_position, 10),
    FaultSpec("non-utf8-frame", "well-formed CDR with a non-UTF-8 frame_id on measurement, estimate, reference",
              _non_utf8, 10),
    FaultSpec("bad-cdr", "8 random bytes overwritten in valid samples of five topics, 20 samples", _bad_cdr, 20),
    FaultSpec("reference-step", "/dem/reference 20 mm off the stream (a foreign writer), 100 samples",
              _reference_step, 100),
    FaultSpec("spike-10mm", "one foreign /dem/measurement +10 mm at the plant's stamp", _spike(10.0), 1),
    FaultSpec("spike-50mm", "one foreign /dem/measurement +50 mm at the plant's stamp", _spike(50.0), 1),
    FaultSpec("stale-stamps", "estimates stamped 100 ms old and measurements +1 h, 20 samples", _stale, 20),
    FaultSpec("future-applied", "one foreign /dem/applied_voltage stamped +1 h (a corrupt stamp)", _future_applied, 1),
    FaultSpec("disk-full", "the bag on a 768 KiB tmpfs: the disk fills about 1.5 s into the run (S1, zstd)",
              disk_kib=768),
    FaultSpec("kill-controller", "SIGKILL the controller, restart after 0.1 s", kill="controller", restart_after=0.1,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-controller-long", "SIGKILL the controller, restart after 1 s (> hold_timeout)", kill="controller",
              restart_after=1.0, allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-estimator", "SIGKILL the estimator, restart after 0.1 s", kill="estimator", restart_after=0.1,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-estimator-long", "SIGKILL the estimator, restart after 1 s", kill="estimator", restart_after=1.0,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-reference", "SIGKILL the reference, restart after 0.1 s", kill="reference", restart_after=0.1,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-reference-long", "SIGKILL the reference, restart after 1 s", kill="reference", restart_after=1.0,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-recorder", "SIGKILL the recorder (not restarted)", kill="recorder", allowed=("levitating",),
              composed=False, min_duration=8.0),  # the reference reports it after 2.5 s of silence
)


def _estop(inj: Injector) -> None:
    """An e-stop on /dem/hw/estop (what `dem-ros hw estop` sends), from a foreign participant."""
    msg = inj.node.msg("std_msgs/msg/String")()
    msg.data = "dem-ros faults: e-stop"
    inj.pub(contract.HW_ESTOP).publish(msg)


# The rig rows: `dem-ros launch --hardware rig --compose` (UDP on loopback, the emulator free-running at 1 kHz,
# controller.command_delay=2), the fault at t = --at s of the experiment. What the design makes of each
# (hw_driver.trip_samples = 3, the board's SENSOR_BLIND_SAMPLES = 5, hold_timeout = link_timeout = 50 ms,
# bus_min = 100 V; the landing law needs R i = 113 V at the support, nominal):
_DRIVER_TRIP = ("driver", "trips", 1)
RIG_CATALOGUE: tuple[FaultSpec, ...] = (
    # 2 samples out of range: below the driver's trip (3) and the board's blind limit (5): held, ridden through
    FaultSpec("dropout-short", "gap sensor 1 reads 0 counts for 2 samples (dead): held, ridden through", hardware=True,
              rig_fault="dropout:1@{t}+0.0015", reports=("sensor_holds",),
              counts=(("driver", "sensor_holds", 2), ("board", "sensor_gaps", 2))),
    # 300 ms dead: the driver trips after 3 samples, the board after 5 lands with gap 1 from coil 1's flux
    FaultSpec("dropout-long",
              "gap sensor 1 reads 0 counts for 300 ms: the driver trips, the board lands on the flux gap",
              hardware=True, rig_fault="dropout:1@{t}+0.3", allowed=("landed safely",), reports=("gap sensor 1",),
              counts=(("driver", "sensor_holds", 3), _DRIVER_TRIP, ("board", "sensor_losses", 1))),
    # a plausible frozen reading: the board's flux check finds it contradicting coil 1's flux once the plate moves
    # (the unstable plate drifts from it within ~150 ms; before the check it reached the rail) and lands on
    # that flux; GAP0_IMPLAUSIBLE trips the driver
    FaultSpec("stuck", "gap sensor 1 repeats its reading for 1 s: the board's flux check lands on coil 1's flux",
              hardware=True, rig_fault="stuck:1@{t}+1", allowed=("landed safely",),
              reports=("GAP0_IMPLAUSIBLE",), counts=(_DRIVER_TRIP, ("board", "implausible", 1))),
    # one full-scale sample: flagged out of range, held one sample by driver and board
    FaultSpec("spike", "gap sensor 1 at full scale for one sample: held, ridden through", hardware=True,
              rig_fault="spike:1@{t}", reports=("sensor_holds",),
              counts=(("driver", "sensor_holds", 1), ("board", "sensor_gaps", 1))),
    # 10 % of the sensor frames fail their CRC for 0.5 s: each one dropped and counted, the board holds a sample
    FaultSpec("corrupt", "10 % of the board's frames with a flipped byte (CRC) for 0.5 s: counted, ridden through",
              hardware=True, rig_fault="corrupt@{t}+0.5:0.1", reports=("corrupt",), counts=(("driver", "corrupt", 1),)),
    # 20 ms silent: the board holds ~21 ms (< hold_timeout): ridden through
    FaultSpec("linkloss-20ms", "nothing sent or received for 20 ms: the board holds, ridden through", hardware=True,
              rig_fault="linkloss@{t}+0.02", reports=("lost",),
              counts=(("driver", "lost", 18), ("board", "hold_events", 1))),
    # 50 ms silent = hold_timeout: the board goes without a fresh command for the loss plus a round trip
    # (51-52 samples) and the driver without a command as long: both watchdogs are at their limit, so either
    # outcome is the design's (landing the usual one); never a failure
    FaultSpec("linkloss-50ms", "nothing sent or received for 50 ms (= hold_timeout): held, then most likely landed",
              hardware=True, rig_fault="linkloss@{t}+0.05", allowed=("levitating", "landed safely"),
              reports=("lost",), counts=(("driver", "lost", 45), ("board", "hold_events", 1))),
    # a 0.2 s dip to 95 V (< bus_min): the driver trips on BUS_UNDERVOLTAGE, the board lands; the bus is back
    # before the landing needs more than 95 V (the plate is held up to ~9 mm at 95 V)
    FaultSpec("sag", "bus sags to 95 V (< bus_min 100 V) for 0.2 s: the driver trips, the board lands", hardware=True,
              rig_fault="sag@{t}+0.2:95", allowed=("landed safely",), reports=("BUS_UNDERVOLTAGE",),
              counts=(("driver", "board: BUS_UNDERVOLTAGE", 3), _DRIVER_TRIP)),
    # 95 V to the end: below the 113 V the landing law needs at the support: the plate sinks faster than
    # landing_speed onto its support, away from the rail (docs/manual/safety.md's limit; the descent is reported)
    FaultSpec("sag-sustained", "bus at 95 V to the end: landed, the last mm faster than landing_speed (design limit)",
              hardware=True, rig_fault="sag@{t}:95", allowed=("landed safely",), reports=("BUS_UNDERVOLTAGE",),
              counts=(("driver", "board: BUS_UNDERVOLTAGE", 3), _DRIVER_TRIP), descent_bounded=False),
    # coil 1's bridge open to the end: its end falls onto the support (the current decays in ~7 ms, nothing can
    # bound that descent), the board lands the other end
    FaultSpec("coil", "coil driver 1 fails open (DRIVER0_FAULT) to the end: the driver trips, the board lands",
              hardware=True, rig_fault="coil:1@{t}", allowed=("landed safely",), reports=("DRIVER0_FAULT",),
              counts=(("driver", "board: DRIVER0_FAULT", 3), _DRIVER_TRIP), descent_bounded=False),
    FaultSpec("estop", "e-stop on /dem/hw/estop (as dem-ros hw estop): the driver latches it, the board lands",
              _estop, 3, hardware=True, allowed=("landed safely",), reports=("e-stop",),
              counts=(("driver", "estops", 1),)),
    # the controller alone is killed (in a process of its own beside the container, --apart controller);
    # the driver's command watchdog and the board's hold both end after 50 ms: LAND
    FaultSpec("kill-controller", "SIGKILL the controller (not restarted): the driver's watchdog, the board lands",
              kill="controller", hardware=True, composed=False, allowed=("landed safely",),
              reports=("command watchdog",), counts=(("driver", "watchdog", 1),)),
)


@dataclass
class Row:
    """One measured row (see the module docstring)."""

    fault: str
    processes: str
    outcome: str
    min_gap_mm: float | None
    max_error_um: float | None
    reported: str
    data_lost: str
    passed: bool
    detail: str = ""
    diagnostics: list[str] = field(default_factory=list)
    counted: str = ""  # hardware rows: the driver's, board's (or estimator's) counters of the fault
    counts: dict[str, float] = field(default_factory=dict)  # the same, by "driver corrupt", "emulator corrupt" ...
    descent_mm_s: float | None = None  # hardware rows: the plate's fastest true descent while the board landed it
    verdict: str = ""  # the run's own verdict (dem_ros.tools.verdict): a landing the row allows is a failed run


# -- one run -----------------------------------------------------------------------------------------------
def _kill_hook(spec: FaultSpec, inj: Injector) -> Callable[..., Collection[str]]:
    """SIGKILL ``spec.kill`` once the injector's clock passes ``at``; restart it ``restart_after`` s later."""
    name = spec.kill
    assert name is not None
    killed: list[float] = []
    restarted: list[bool] = []

    def supervise(_t: float | None, procs: dict[str, subprocess.Popen],
                  restart: Callable[[str], None]) -> Collection[str]:
        if not killed:
            if inj.t is None or inj.t < inj.at or name not in procs:
                return ()
            t_kill = inj.t  # the experiment time of the SIGKILL (the reap below can take 0.1 s on a loaded host)
            os.killpg(procs[name].pid, signal.SIGKILL)
            inj.killed_ns = time.time_ns()  # ROS time of the kill: the restarted node's 'ready' ends the outage
            procs[name].wait()
            killed.append(time.monotonic())
            inj.events.append(f"{name} killed at t = {t_kill:.3f} s")
        if spec.restart_after is None:
            return (name,)  # stays down
        if not restarted and time.monotonic() - killed[0] >= spec.restart_after:
            restart(name)
            restarted.append(True)
            inj.events.append(f"restarted at t = {inj.t:.3f} s")
        return () if restarted else (name,)
    return supervise


def _launch_args(scenario: str, duration: float, compose: bool, free_run: bool, bag_dir: Path, domain_id: int,
                 sets: list[str], hardware: str | None = None, apart: Sequence[str] = ()) -> LaunchOptions:
    from .launcher import LaunchOptions

    return LaunchOptions(scenario=scenario, duration=duration, bag_dir=str(bag_dir), domain_id=domain_id,
                         transport="dds", compose=compose, free_run=free_run, hardware=hardware, set=list(sets),
                         apart=list(apart))


def _log_lines(logs: dict[str, str], since_ns: int) -> list[tuple[str, str]]:
    """(node, line) of every WARN/ERROR line logged at or after ``since_ns`` (ROS time) in the run's node logs."""
    out: list[tuple[str, str]] = []
    for path in logs.values():
        try:
            text = Path(path).read_text(errors="replace")
        except OSError:
            continue
        for line in text.splitlines():
            m = _LEVEL.match(line)
            if m and float(line.split("] [", 1)[1].split("]", 1)[0]) * 1e9 >= since_ns:
                out.append((m.group(2), line))
    return out


def _log_levels(logs: dict[str, str], since_ns: int) -> dict[str, int]:
    """WARN/ERROR lines per node logged at or after ``since_ns`` (ROS time) in the run's node logs."""
    out: dict[str, int] = {}
    for node, _ in _log_lines(logs, since_ns):
        out[node] = out.get(node, 0) + 1
    return out


def _read_bag(bag: Path, measured: bool = False) -> dict[str, Any]:
    """What the judges read from a run's bag: truth, reference (and measurement) arrays, every /diagnostics
    status (log time, name, level, message, values), the last loop status and its epoch, truncation."""
    from ..bag import BagReader

    undecodable: dict[str, int] = {}

    def decoded(r: BagReader, topic: str, type_name: str) -> list[tuple[int, Any]]:
        """(log time, message) of every sample of ``topic`` that decodes; the others are counted."""
        from ..transport import TransportError, deserialize

        if topic not in r.topics:
            return []
        got = []
        for _, log_ns, _, data in r.raw_messages([topic]):
            try:
                got.append((log_ns, deserialize(type_name, bytes(data), transport="dds")))
            except TransportError:  # the strict decoder's CdrError (type, field, offset)
                undecodable[topic] = undecodable.get(topic, 0) + 1
        return got

    def arrays(msgs: list[tuple[int, Any]]) -> dict[str, np.ndarray] | None:
        from ..nodes.common import stamp_ns

        rows = [(stamp_ns(m), m.position[0], m.position[1]) for _, m in msgs if len(m.position) >= 2]
        if not rows:
            return None
        a = np.array(rows, dtype=float)
        return {"stamp_ns": a[:, 0].astype(np.int64), "position": a[:, 1:3]}

    with BagReader(bag) as r:
        truth = arrays(decoded(r, contract.TRUTH.name, contract.TRUTH.type))
        ref = arrays(decoded(r, contract.REFERENCE.name, contract.REFERENCE.type))
        meas = arrays(decoded(r, contract.MEASUREMENT.name, contract.MEASUREMENT.type)) if measured else None
        loop: dict[str, str] = {}
        epoch = None
        diags = []
        for log_ns, msg in decoded(r, contract.DIAGNOSTICS.name, contract.DIAGNOSTICS.type):
            for s in msg.status:
                vals = {kv.key: kv.value for kv in s.values}
                name = contract.status_name(s.name)
                if name in (contract.LOOP_STATUS, contract.HW_LOOP_STATUS):
                    loop = vals
                    if vals.get("epoch_ns", "").isdigit():
                        epoch = int(vals["epoch_ns"])
                level = contract.status_level(s)
                diags.append((log_ns, name, level, s.message, vals))
        truncated = r.truncated
    problems = [f"{n} recorded sample(s) of {topic} do not decode (the injected ones, recorded as sent)"
                for topic, n in undecodable.items()]
    return {"truth": truth, "ref": ref, "meas": meas, "loop": loop, "epoch": epoch, "diags": diags,
            "truncated": truncated, "problems": problems}


def _worst_levels(statuses: Iterable[tuple[str, int]]) -> list[str]:
    """'name WARN' / 'name ERROR' per status name at its worst level, for (name, level) pairs at WARN or above."""
    seen: dict[str, int] = {}
    for name, level in statuses:
        if level >= 1:
            seen[name] = max(seen.get(name, 0), level)
    return [f"{n} {'WARN' if lv == 1 else 'ERROR'}" for n, lv in sorted(seen.items())]


def _routine_warn(reported: str) -> bool:
    """Whether a 'name LEVEL' of :func:`_worst_levels` (perhaps with " (live)") is a WARN that a lockstep run on a
    loaded machine has without a fault: the plant's loop status (it waited), a topic's status (its rate fell)."""
    text = reported.split(" (live)")[0]
    name, _, level = text.rpartition(" ")
    return level == "WARN" and (name == contract.LOOP_STATUS or name.endswith(contract.TOPIC_STATUS_SUFFIX))


def _levels_after(diags: list[tuple], t_f: int) -> list[str]:
    """'name LEVEL' of every status at WARN or ERROR from 1 s before the fault (the once-a-second reports
    cover the second of the fault), the worst level per name."""
    return _worst_levels((name, level) for log_ns, name, level, *_ in diags if log_ns >= t_f - 10**9)


def _judge(bag: Path, t_fault_s: float, cfg: dict) -> dict[str, Any]:
    """Outcome, min gap, diagnostics and bag problems of a recorded run."""
    b = _read_bag(bag)
    out: dict[str, Any] = {"diagnostics": [], "problems": list(b["problems"])}
    truth, ref, loop, epoch, truncated = b["truth"], b["ref"], b["loop"], b["epoch"], b["truncated"]
    t_f = (epoch or 0) + round(t_fault_s * 1e9)
    out["fault_ns"] = t_f
    out["diagnostics"] = _levels_after(b["diags"], t_f)
    pc = cfg["plant_sim"]
    if truth is None:
        out.update(outcome="failed", min_gap_mm=None, detail="no plant truth recorded")
        return out
    after = truth["stamp_ns"] >= t_f
    g = truth["position"][:, :2]
    gmin = float(np.nanmin(g[after])) if after.any() else float(np.nanmin(g))
    out["min_gap_mm"] = round(gmin * 1e3, 3)
    mode = loop.get("board_mode", "")
    failed = loop.get("failed", "False") == "True" or gmin <= pc["gap_min"]
    landed = mode in ("LAND", "LANDED") or loop.get("landing", "False") == "True"
    end_err = float("inf")
    if ref is not None:
        ts, i_t, i_r = np.intersect1d(truth["stamp_ns"], ref["stamp_ns"], return_indices=True)
        if ts.size:
            end_err = float(np.max(np.abs(g[i_t[-1]] - ref["position"][i_r[-1], :2])))
            win = ts >= t_f
            if win.any():  # the largest tracking error e = true gap - y_d from the fault on
                out["max_error_um"] = round(float(np.max(np.abs(g[i_t[win]] - ref["position"][i_r[win], :2]))) * 1e6, 1)
    if failed:
        out["outcome"] = "failed"
        out["detail"] = loop.get("fault", "") or f"min gap {gmin * 1e3:.3f} mm"
    elif landed:
        # safe: the board landed it before the plate came nearer the rail than its own trip gap
        out["outcome"] = "landed safely" if gmin >= pc["trip_gap_min"] else "failed"
        out["detail"] = loop.get("landing_reason", "") + ("" if gmin >= pc["trip_gap_min"] else
                                                          f"; within {gmin * 1e3:.3f} mm of the rail first")
    elif end_err < 1e-3:
        out["outcome"] = "levitating"
    else:
        out["outcome"] = "failed"
        out["detail"] = f"{end_err * 1e3:.2f} mm off the reference at the end"
    _bag_problems(bag, cfg, truncated, out)
    return out


def _bag_problems(bag: Path, cfg: dict, truncated: Any, out: dict[str, Any]) -> None:
    """What the bag says about itself (RunMetrics' problems, truncation) into ``out["problems"]``."""
    from ..bag import BagError
    from .runmetrics import load_run

    try:
        m, _ = load_run(bag)
        out["problems"] += list(m.problems)
        out["recorded_s"] = m.samples * cfg["plant_sim"]["dt"]  # experiment time the bag covers from t = 0
    except BagError as exc:  # the bag layer's own error (one line): reported as the data lost
        out["problems"].append(f"bag unreadable: {exc}")
    if truncated is not None and not any("truncated" in p for p in out["problems"]):
        out["problems"].append(f"bag truncated ({truncated.reason})")


def _rig_log(path: Path) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The emulated board's ``RIG {json}`` status lines and its summary (None: it wrote none) from its log."""
    statuses: list[dict[str, Any]] = []
    summary = None
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return statuses, summary
    for line in lines:
        if not line.startswith("RIG "):
            continue
        try:
            d = json.loads(line[4:])
        except ValueError:
            continue
        if d.get("event") == "status":
            statuses.append(d)
        elif d.get("event") == "summary":
            summary = d
    return statuses, summary


def _number(v: Any) -> float:
    """A counter as a number: a /diagnostics value string, an int, or a text (non-empty: 1)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    try:
        return float(v)
    except (TypeError, ValueError):
        return 1.0 if v not in (None, "", "False", "0") else 0.0


def _counted(spec: FaultSpec, sources: dict[str, dict[str, Any]]) -> tuple[bool, str, dict[str, float]]:
    """(every counter of ``spec.counts`` reached its minimum, 'driver sensor_holds 2, board ...', the values)."""
    ok, said, got = True, [], {}
    for where, key, least in spec.counts:
        v = _number(sources.get(where, {}).get(key, 0))
        ok = ok and v >= least
        got[f"{where} {key}"] = v
        said.append(f"{where} {key} {v:g}" + ("" if v >= least else f" (< {least})"))
    return ok, ", ".join(said), got


_AT_T = re.compile(r" at t = (-?[0-9.]+) s")


def _judge_hw(bag: Path, t_fault_s: float, cfg: dict, spec: FaultSpec, rig: dict[str, Any] | None,
              rig_statuses: list[dict[str, Any]]) -> dict[str, Any]:
    """Outcome of a hardware row: the board's landing from the driver's loop status in the bag, the plate's
    truth from the emulator (smallest gap since the release, fastest descent while the board landed it,
    rail contact), the end error from the recorded measurement (a rig has no truth topic)."""
    b = _read_bag(bag, measured=True)
    out: dict[str, Any] = {"diagnostics": [], "problems": list(b["problems"])}
    ref, meas, loop = b["ref"], b["meas"], b["loop"]
    t_f = (b["epoch"] or 0) + round(t_fault_s * 1e9)
    out["fault_ns"] = t_f
    out["diagnostics"] = _levels_after(b["diags"], t_f)
    out["messages"] = [(name, msg) for log_ns, name, level, msg, _ in b["diags"] if log_ns >= t_f and level >= 1]
    last: dict[str, dict[str, str]] = {}  # each status's last values (the estimator's counters)
    for _, name, _, _, vals in b["diags"]:
        last[name] = vals
    out["statuses"], out["loop"] = last, loop
    pc = cfg["plant_sim"]
    _bag_problems(bag, cfg, b["truncated"], out)
    end_err = float("inf")
    if ref is not None and meas is not None:
        ts, i_m, i_r = np.intersect1d(meas["stamp_ns"], ref["stamp_ns"], return_indices=True)
        if ts.size:
            g = meas["position"]
            end_err = float(np.max(np.abs(g[i_m[-1]] - ref["position"][i_r[-1], :2])))
            win = ts >= t_f
            if win.any():  # the largest measured error (gap - y_d) from the fault on
                out["max_error_um"] = round(float(np.max(np.abs(g[i_m[win]] - ref["position"][i_r[win], :2]))) * 1e6, 1)
    if rig is None:
        out.update(outcome="failed", min_gap_mm=None, detail="the emulated board wrote no summary (rig.log)")
        return out
    gmin = rig.get("min_gap_mm")
    out["min_gap_mm"] = gmin
    descent = float(rig.get("land_speed_max_mm_s") or 0.0)
    bound = pc["landing_speed"] * 1e3
    truth = (f"true: fastest descent {descent:.1f} mm/s (landing_speed {bound:g}"
             + ("" if spec.descent_bounded else ", not bounded for this fault") + ")")
    reason = loop.get("landing_reason", "")
    down = loop.get("landing", "False") == "True" and not reason.startswith("end of the run")
    driver_failed = loop.get("failed", "False") == "True"
    fault_modes = [st["t_s"] for st in rig_statuses if st.get("mode") == "FAULT"]
    if gmin is None:
        out["outcome"] = "failed"
        out["detail"] = f"the board never released the plate (board {rig.get('mode')}: {rig.get('reason', '')})"
    elif rig.get("failed") or gmin * 1e-3 <= pc["gap_min"]:
        out["outcome"] = "failed"
        out["detail"] = f"rail contact: {rig.get('failed') or f'true gap {gmin:.3f} mm'}"
    elif rig.get("mode") == "FAULT" or fault_modes:
        out["outcome"] = "failed"
        out["detail"] = f"board FAULT (0 V: the plate dropped onto its support): {rig.get('reason', '')}"
    elif down or driver_failed:
        why = reason if down else f"driver fault at t = {loop.get('fail_time_s', '?')} s: {loop.get('fault', '')}"
        m = _AT_T.search(why)
        landed_at = float(m.group(1)) if m else None
        out["landed_at_s"] = landed_at
        unsafe = []
        if gmin < pc["trip_gap_min"] * 1e3:
            unsafe.append(f"within {gmin:.3f} mm of the rail first")
        if spec.descent_bounded and descent > bound:
            unsafe.append(f"descent {descent:.1f} mm/s > landing_speed {bound:g} mm/s")
        out["outcome"] = "failed" if unsafe else "landed safely"
        out["detail"] = "; ".join([why, truth, *unsafe])
        if landed_at is not None and landed_at < t_fault_s - 0.005:
            out["early"] = f"the board landed at t = {landed_at:.3f} s, before the fault: not this fault's landing"
    elif end_err < 1e-3:
        out["outcome"] = "levitating"
    else:
        out["outcome"] = "failed"
        out["detail"] = f"{end_err * 1e3:.2f} mm off the reference at the end (measured)"
    return out


def _apart(spec: FaultSpec) -> tuple[str, ...]:
    """The rig rows' killed node runs in a process of its own beside the container (``--apart``), the rest
    composed: the rig does not hold with a process per node on a 2-core host (docs/manual/faults.md)."""
    return (spec.kill,) if spec.hardware and spec.kill is not None else ()


def _how(spec: FaultSpec, compose: bool) -> str:
    """The row's processes as the table and the progress lines say them."""
    apart = _apart(spec)
    return f"composed, {', '.join(apart)} apart" if apart else "composed" if compose else "per process"


def run_row(spec: FaultSpec, *, compose: bool, scenario: str, duration: float, at: float, free_run: bool,
            workdir: Path, domain_id: int, sets: list[str]) -> Row:
    """Launch the graph, inject ``spec`` at ``at`` s, judge the bag (a disk row: on a small tmpfs)."""
    how = _how(spec, compose)
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    workdir.mkdir(parents=True, exist_ok=True)
    if spec.hardware:
        return _run_hw_row(spec, how, compose=compose, scenario=scenario, duration=duration, at=at, workdir=workdir,
                           domain_id=domain_id, sets=sets)
    disk = workdir / "disk" if spec.disk_kib else None
    if disk is not None:
        disk.mkdir(exist_ok=True)
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={spec.disk_kib}k", "tmpfs", str(disk)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            return Row(spec.name, how, "not run", None, None, "", "", False,
                       f"cannot mount a {spec.disk_kib} KiB tmpfs (needs root): {r.stderr.strip()}")
    try:
        return _run_row(spec, how, compose=compose, scenario=scenario, duration=duration, at=at, free_run=free_run,
                        workdir=workdir, disk=disk, domain_id=domain_id, sets=sets)
    finally:
        if disk is not None:
            subprocess.run(["umount", "-l", str(disk)], check=False)


def run_events(info: dict[str, Any], logdir: Path | None) -> list[dict[str, Any]]:
    """The run's run-state events: from the launch facts, else from the file the launcher keeps beside the logs
    (a run whose bag could not be summarised)."""
    from .launcher import RUN_STATE_FILE

    if info.get("events"):
        return list(info["events"])
    try:
        text = (logdir / RUN_STATE_FILE).read_text() if logdir is not None else ""
    except OSError:
        return []
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def _plant_end(info: dict[str, Any]) -> str:
    """The plant's own last word, its "finished" run-state event: "finished 4 s", "landed safely at ...",
    "plant failure ..." ("": none came)."""
    ends = [e for e in info.get("events") or [] if e.get("event") == "finished" and e.get("node") == "plant_sim"]
    return str(ends[-1].get("message", "")) if ends else ""


def _outage_s(info: dict[str, Any], name: str, killed_ns: int | None) -> float | None:
    """Seconds from the SIGKILL of ``name`` to the "ready" event of its restarted process, or None."""
    if killed_ns is None:
        return None
    ready = [int(e["time_ns"]) for e in info.get("events") or []
             if e.get("event") == "ready" and e.get("node") == name and int(e.get("time_ns", 0)) > killed_ns]
    return (ready[0] - killed_ns) * 1e-9 if ready else None


def _lost(info: dict[str, Any], problems: list[str]) -> list[str]:
    """What a run lost: the recorder's drops, what the bag says about itself, a summary that could not be made
    (a node's refusal of a foreign writer qualifies the run, it loses nothing: the ``reported`` column has it)."""
    from .runmetrics import is_refusal

    problems = [p for p in problems if not is_refusal(p)]
    dropped = sum(v.get("dropped", 0) for v in (info.get("recorder") or {}).values())
    lost = [f"{dropped} dropped", *problems] if dropped else list(problems)
    if info.get("summary_error"):
        lost.append(f"dem-ros launch could not summarise the bag: {info['summary_error']}")
    return lost


def _launch_injected(args: LaunchOptions, spec: FaultSpec, inj: Injector,
                     logs_dir: Path | None = None) -> dict[str, Any] | str:
    """``dem-ros launch`` with the injector running and the row's kill hook: the launch facts (with the run's
    verdict), or why the run did not start or was cut short (the injector is closed either way)."""
    from ..bag import BagError
    from .launcher import GraphError, launch

    hook = _kill_hook(spec, inj) if spec.kill else None
    try:
        metrics, info = launch(args, quiet=True, supervise=hook, logs_dir=logs_dir)
        if info.get("cut_short"):
            return f"run cut short: {info['cut_short']}"
        return info | {"verdict": metrics.verdict, "verdict_reasons": metrics.verdict_reasons}
    except GraphError as exc:
        return f"run cut short: {exc}"
    except BagError as exc:  # the run ended, but its summary could not read the bag: judge it here
        return {"recorder": None, "summary_error": str(exc)}
    finally:
        inj.close()


def _run_row(spec: FaultSpec, how: str, *, compose: bool, scenario: str, duration: float, at: float, free_run: bool,
             workdir: Path, disk: Path | None, domain_id: int, sets: list[str]) -> Row:
    args = _launch_args(scenario, duration, compose, free_run, disk or workdir, domain_id, sets)
    inj = Injector(_n_times(spec.n, spec.act) if spec.act is not None else None, at)
    logdir = workdir / "logs" if disk is not None else None
    info = _launch_injected(args, spec, inj, logdir)
    if isinstance(info, str):
        return Row(spec.name, how, "failed", None, None, "", "", False, info)
    root = disk or workdir
    bags = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.endswith("_logs"))
    bag = Path(info["bag"]) if info.get("bag") else bags[-1]
    from .launcher import _config_from_args

    cfg, _, _ = _config_from_args(args)
    j = _judge(bag, 0.0 if disk is not None else at, cfg)  # a disk fills when it fills: every report counts
    logs = json.loads((bag / "summary.json").read_text()).get("logs", {}) if (bag / "summary.json").exists() else {}
    logdir = logdir or bag.parent / (bag.name + "_logs")
    logs = {p.stem: str(p) for p in logdir.glob("*.log")} if logdir.is_dir() else logs
    info["events"] = run_events(info, logdir)
    end = _plant_end(info)
    if disk is not None and j["outcome"] == "levitating" and not end.startswith("finished"):
        # the bag stops where the disk filled: the plant's own last word says how the run ended
        j["outcome"] = "landed safely" if end.startswith("landed") else "failed"
        j["detail"] = f"the plant: {end or 'no last word from it'}"
    levels = _log_levels(logs, j["fault_ns"] - 10**9)
    exits = info.get("exits") or []  # node processes the launcher saw die (reported on its stderr at once)
    # heard live but not in the bag (a full disk stops the recording before the recorder's own ERROR)
    live = [d for d in inj.live_levels((0.0 if disk is not None else at) - 1.0) if d not in j["diagnostics"]]
    j["diagnostics"] += [f"{d} (live)" for d in live]
    reported = ", ".join(j["diagnostics"]) or "no diagnostics"
    reported += "; log: " + (", ".join(f"{n} {c}" for n, c in sorted(levels.items())) or "nothing")
    if exits:
        reported += "; launch: " + ", ".join(f"{e['node']} exited ({e['code']})" for e in exits)
    rec = info.get("recorder") or {}
    lost = _lost(info, j["problems"])
    if spec.kill == "recorder" and not rec:
        lost.append("recorder counters lost with the process")
    for e in exits:  # the launcher saw a node die: the recorder's death costs the rest of the recording
        if e["node"] == "recorder" and "recorded_s" in j:
            lost.insert(0, f"recording lost from t = {j['recorded_s']:.3f} s (recorder killed)")
    data_lost = "; ".join(lost) or "none"
    # the plant's loop status is at WARN whenever it waited for a command or held (lockstep on a loaded
    # machine: most runs), and so is a topic's status whose rate fell 10 % short over its window; they count as
    # a report of the fault only at ERROR (a landing, a failure; a topic silent for a whole window)
    told = [d for d in j["diagnostics"] if not _routine_warn(d)]
    ok = j["outcome"] in spec.allowed and (bool(told) or bool(levels))
    sent = [f"{v} {k}" for k, v in inj.counts.items()]
    if spec.kill and spec.restart_after is not None:  # what the outage was, against the board's hold
        down = _outage_s(info, spec.kill, inj.killed_ns)
        hold = (f"lockstep_timeout {cfg['plant_sim']['lockstep_timeout']:g} s" if cfg["plant_sim"]["lockstep"]
                else f"hold_timeout {cfg['plant_sim']['hold_timeout'] * 1e3:g} ms")
        sent.append(f"down {down:.1f} s (SIGKILL to the restarted node's 'ready'; {hold})" if down is not None
                    else f"the restarted node was not ready again before the run ended ({hold})")
    detail = "; ".join([*inj.events, *sent, j.get("detail", "")]).strip("; ")
    return Row(spec.name, how, j["outcome"], j["min_gap_mm"], j.get("max_error_um"), reported, data_lost, ok, detail,
               j["diagnostics"], verdict=_verdict_text(info))


HW_SETS = ("controller.command_delay=2",)  # docs/results.md's hardware runs: a loaded host keeps the loop in time


def _run_hw_row(spec: FaultSpec, how: str, *, compose: bool, scenario: str, duration: float, at: float,
                workdir: Path, domain_id: int, sets: list[str]) -> Row:
    """``dem-ros launch --hardware rig``: the rig fault (board time: ``at`` + the driver's pre-roll after the
    release, i.e. t = ``at`` of the experiment within a sample), an injection or a kill at t = ``at``; judged
    from the bag, the node logs and the emulator's own figures (rig.log)."""
    from .launcher import _config_from_args

    apart = _apart(spec)
    compose = compose or bool(apart)
    args = _launch_args(scenario, duration, compose, False, workdir, domain_id, [*HW_SETS, *sets], hardware="rig",
                        apart=apart)
    cfg, _, _ = _config_from_args(args)
    if spec.rig_fault:
        args.fault = [spec.rig_fault.format(t=f"{at + cfg['hw_driver']['preroll']:g}")]
    inj = Injector(_n_times(spec.n, spec.act) if spec.act is not None else None, at, extra=(contract.HW_ESTOP,))
    info = _launch_injected(args, spec, inj)
    if isinstance(info, str):
        return Row(spec.name, how, "failed", None, None, "", "", False, info)
    bags = sorted(p for p in workdir.iterdir() if p.is_dir() and not p.name.endswith("_logs"))
    if not info.get("bag") and not bags:
        return Row(spec.name, how, "failed", None, None, "", "", False, "no bag was recorded")
    bag = Path(info["bag"]) if info.get("bag") else bags[-1]
    logdir = bag.parent / (bag.name + "_logs")
    statuses, rig = _rig_log(logdir / "rig.log")
    rig = rig or info.get("rig")
    j = _judge_hw(bag, at, cfg, spec, rig, statuses)
    logs = {p.stem: str(p) for p in logdir.glob("*.log") if p.stem != "rig"}
    lines = _log_lines(logs, j["fault_ns"])
    levels: dict[str, int] = {}
    for node, _ in lines:
        levels[node] = levels.get(node, 0) + 1
    said = [*j["messages"], *((f"{node} log", line) for node, line in lines)]
    heard = [who for who, text in said if any(k.lower() in text.lower() for k in spec.reports)]
    exits = info.get("exits") or []
    reported = ", ".join(j["diagnostics"]) or "no diagnostics"
    reported += "; log: " + (", ".join(f"{n} {c}" for n, c in sorted(levels.items())) or "nothing")
    if exits:
        reported += "; launch: " + ", ".join(f"{e['node']} exited ({e['code']})" for e in exits)
    reported += f"; '{spec.reports[0]}' " + (f"in {', '.join(sorted(set(heard)))}" if heard else "NOT reported")
    sources = {"driver": j.get("loop", {}), "board": {**(rig or {}), **((rig or {}).get("supervisor") or {})},
               "estimator": j["statuses"].get(contract.ESTIMATOR_STATUS, {})}
    counted_ok, counted, counts = _counted(spec, sources)
    hits = [f"{f['kind']} acted on {f['hits']} samples" for f in (rig or {}).get("faults", [])]
    if hits:
        counted += "; emulator: " + ", ".join(hits)
    for f in (rig or {}).get("faults", []):
        counts[f"emulator {f['kind']}"] = float(f["hits"])
    lost = _lost(info, j["problems"])
    early = j.get("early", "")
    ok = j["outcome"] in spec.allowed and bool(heard) and counted_ok and not early
    sent = [f"{v} {k}" for k, v in inj.counts.items()]
    if spec.act is not None:
        sent.insert(0, f"{inj.injected} sent from t = {at:g} s")
    detail = "; ".join(x for x in [early, *inj.events, *sent, j.get("detail", "")] if x)
    return Row(spec.name, how, j["outcome"], j["min_gap_mm"], j.get("max_error_um"), reported,
               "; ".join(lost) or "none", ok, detail, j["diagnostics"], counted, counts,
               (rig or {}).get("land_speed_max_mm_s"), _verdict_text(info))


def _verdict_text(info: dict[str, Any]) -> str:
    """The run's verdict in a row: ``failed: landed before the planned end ...`` ("" when launch gave none)."""
    v = info.get("verdict", "")
    reasons = info.get("verdict_reasons") or []
    return v + (f": {'; '.join(reasons)}" if reasons and v else "")


# -- the command -------------------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", action="append", default=[], metavar="NAME",
                   help="run only these rows (repeatable): " + ", ".join(f.name for f in CATALOGUE)
                   + "; with --hardware rig: " + ", ".join(f.name for f in RIG_CATALOGUE))
    p.add_argument("--hardware", choices=("rig",), default=None,
                   help="'rig': the hardware rows instead, hw_driver and the emulated board (dem-ros launch --hardware "
                        "rig, UDP on loopback, controller.command_delay=2; rig faults, an e-stop, a killed controller)")
    p.add_argument("--processes", choices=("per-process", "composed", "both"), default=None,
                   help="the graph as a process per node, composed in one process, or both (default: both; with "
                        "--hardware rig each row once, composed; a killed controller in a process of its own "
                        "beside the container)")
    p.add_argument("--scenario", default="S1")
    p.add_argument("--duration", type=float, default=4.0, help="seconds of each run (default 4)")
    p.add_argument("--at", type=float, default=1.5, help="inject at this experiment time [s] (default 1.5)")
    p.add_argument("--free-run", action="store_true", help="free-running plant (hardware-like timing)")
    p.add_argument("--set", action="append", default=[], metavar="GROUP.NAME=VALUE", help="parameter override")
    p.add_argument("--bag-dir", default=None, help="keep the runs' bags here (default: a temporary directory)")
    p.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID of the runs (default: from the pid)")
    p.add_argument("--json", default=None, help="write the rows as JSON")


def _table(rows: list[Row]) -> str:
    hw = any(r.counted for r in rows)  # hardware rows: who counted the fault
    head = ("fault", "processes", "outcome", "min gap [mm]", "max error [um]", "reported",
            *(("counted",) if hw else ()), "data lost", "pass")
    body = [(r.fault, r.processes, r.outcome + (f" ({r.detail})" if r.detail else ""),
             "-" if r.min_gap_mm is None else f"{r.min_gap_mm:.3f}",
             "-" if r.max_error_um is None else f"{r.max_error_um:.1f}", r.reported, *((r.counted,) if hw else ()),
             r.data_lost, "yes" if r.passed else "NO") for r in rows]
    w = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
    lines = ["| " + " | ".join(h.ljust(w[i]) for i, h in enumerate(head)) + " |",
             "|" + "|".join("-" * (x + 2) for x in w) + "|"]
    lines += ["| " + " | ".join(c.ljust(w[i]) for i, c in enumerate(b)) + " |" for b in body]
    return "\n".join(lines)


def _write(args: argparse.Namespace, rows: list[Row]) -> None:
    write_json(args.json, {"rows": [asdict(r) for r in rows], "scenario": args.scenario, "at_s": args.at,
                           "duration_s": args.duration, "free_run": args.free_run, "hardware": args.hardware,
                           "sets": ([*HW_SETS] if args.hardware else []) + list(args.set)})


def _plan(specs: list[FaultSpec], processes: str | None, hardware: bool) -> list[tuple[FaultSpec, bool]]:
    """(row, composed) in the order they run: every row per process, then composed (--processes both); the
    rig's default runs each row once, composed unless it kills a node (its own process)."""
    if hardware and processes is None:
        return [(f, f.composed) for f in specs]
    modes = {"per-process": (False,), "composed": (True,), "both": (False, True)}[processes or "both"]
    return [(f, compose) for compose in modes for f in specs if f.composed or not compose]


def cmd_faults(args: argparse.Namespace) -> int:
    catalogue = RIG_CATALOGUE if args.hardware else CATALOGUE
    names = {f.name for f in catalogue}
    bad = [n for n in args.only if n not in names]
    if bad:
        raise UsageError(f"--only: unknown row(s) {', '.join(bad)}; "
                         f"rows{' (--hardware rig)' if args.hardware else ''}: "
                         f"{', '.join(sorted(names))}")
    specs = [f for f in catalogue if not args.only or f.name in args.only]
    work = Path(args.bag_dir) if args.bag_dir else Path(tempfile.mkdtemp(prefix="dem_ros_faults_"))
    domain = args.domain_id if args.domain_id is not None else 1 + os.getpid() % 100
    rows: list[Row] = []
    for spec, compose in _plan(specs, args.processes, bool(args.hardware)):
        print(f"dem-ros faults: {spec.name} ({_how(spec, compose)}): {spec.description}", file=sys.stderr, flush=True)
        row = run_row(spec, compose=compose, scenario=args.scenario, duration=max(args.duration, spec.min_duration),
                      at=args.at, free_run=args.free_run,
                      workdir=work / spec.name / ("composed" if compose else "processes"), domain_id=domain,
                      sets=args.set)
        print(f"  -> {row.outcome}, min gap {row.min_gap_mm} mm, {'pass' if row.passed else 'FAIL'}",
              file=sys.stderr, flush=True)
        rows.append(row)
        if args.json:  # after every row: a long catalogue run keeps what it measured
            _write(args, rows)
    print(_table(rows))
    failed = [r.fault for r in rows if not r.passed]
    if failed:
        print(f"dem-ros faults: {len(failed)} of {len(rows)} row(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0
