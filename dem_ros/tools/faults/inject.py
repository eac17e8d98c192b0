"""The injections of ``dem-ros faults``: :class:`Injector`, a foreign participant on the graph's domain, the
message injections the catalogue's rows name (:mod:`.catalogue`), and the hook that kills a node."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Collection
from typing import TYPE_CHECKING, Any

import numpy as np

from ... import contract
from .judge import RosoutRecord, _worst_levels, rosout_record

if TYPE_CHECKING:
    from .spec import FaultSpec

__all__ = ["INJECTOR_NODE", "Injector"]

#: the injector's node name (its own /rosout records are never a report of the fault)
INJECTOR_NODE = "dem_ros_faults"
DT_NS = 1_000_000


class Injector:
    """A foreign participant on the graph's domain: follows the experiment clock, injects messages.

    ``t`` is the experiment time [s] of the newest ``/dem/measurement`` (None before t = 0). The
    injection (``act(self)``) runs on this object's thread, once per received sample from ``at`` s
    until it returns False. ``/diagnostics`` and ``/rosout`` are heard live too (WARN and above): what
    the bag cannot keep (a full disk stops the recording) is seen here.
    """

    def __init__(self, act: Callable[[Injector], bool] | None, at: float, extra: tuple[contract.Topic, ...] = ()):
        from ...transport import make_node

        self.node = make_node(INJECTOR_NODE, transport="dds", args=[])
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
        # the nodes' log records at WARN or above (this node's own excepted: they are not the graph's)
        self.rosout: list[RosoutRecord] = []
        self.node.subscribe(contract.ROSOUT, self._on_rosout)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, name="dem-ros-faults", daemon=True)
        self.thread.start()

    def pub(self, topic: contract.Topic) -> Any:
        if topic.name not in self.pubs:
            self.pubs[topic.name] = self.node.publisher(topic)
        return self.pubs[topic.name]

    def _on_meas(self, m: Any) -> None:
        from ...nodes.common import stamp_ns

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

    def _on_rosout(self, m: Any) -> None:
        rec = rosout_record(m)
        if rec is not None and rec.name != INJECTOR_NODE:
            self.rosout.append(rec)

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
    from ...nodes.common import stamp_ns

    h = inj.js().header
    t = stamp_ns(m) if t_ns is None else t_ns
    h.stamp.sec, h.stamp.nanosec = t // 1_000_000_000, t % 1_000_000_000
    h.frame_id = m.header.frame_id if frame is None else frame
    return inj.js(header=h, name=list(m.name), position=list(m.position) if position is None else list(position),
                  velocity=list(m.velocity), effort=list(m.effort))


def _n_times(n: int, fn: Callable[[Injector], None]) -> Callable[[Injector], bool]:
    def act(inj: Injector) -> bool:
        from ...transport import TransportError

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
    from ...transport import serialize

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
    from ...transport import TransportError, serialize

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
    from ...nodes.common import stamp_ns

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
    from ...nodes.common import stamp_ns

    if inj.est is not None:
        inj.pub(contract.ESTIMATE).publish(_copy(inj, inj.est, t_ns=stamp_ns(inj.est) - 100 * DT_NS))
    inj.pub(contract.MEASUREMENT).publish(_copy(inj, inj.meas, t_ns=stamp_ns(inj.meas) + 3600 * 10**9))


def _future_applied(inj: Injector) -> None:
    """One /dem/applied_voltage stamped 1 h ahead: what a corrupt stamp (bad-cdr) looks like to its readers."""
    from ...nodes.common import stamp_ns

    inj.pub(contract.APPLIED).publish(_copy(inj, inj.meas, t_ns=stamp_ns(inj.meas) + 3600 * 10**9))


def _estop(inj: Injector) -> None:
    """An e-stop on /dem/hw/estop (what `dem-ros hw estop` sends), from a foreign participant."""
    msg = inj.node.msg("std_msgs/msg/String")()
    msg.data = "dem-ros faults: e-stop"
    inj.pub(contract.HW_ESTOP).publish(msg)


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
