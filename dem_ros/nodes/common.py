"""Message <-> array conversion, loop statistics and the per-node ``/diagnostics`` reporter shared by
the nodes (no control math)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ..contract import FRAME, MAGNETS

__all__ = [
    "ERROR",
    "OK",
    "WARN",
    "CommandSource",
    "Diagnostics",
    "JointStates",
    "LatencyStats",
    "all_finite",
    "clipped",
    "diag_array",
    "joint_state",
    "meas_array",
    "meas_into",
    "named_vector",
    "set_stamp",
    "stamp_ns",
]

#: ``diagnostic_msgs/DiagnosticStatus`` levels
OK, WARN, ERROR = 0, 1, 2

_isfinite = math.isfinite
_EMPTY: list[float] = []  # shared by messages without that field; never modified


def worth_logging(n: int) -> bool:
    """Whether the n-th occurrence of a repeated problem is logged: the 1st, 10th, 100th, 1000th, then every
    10 000th (a stream of bad samples at 1 kHz must not flood the log, nor go silent)."""
    return n in (1, 10, 100, 1000) or n % 10000 == 0


def all_finite(values) -> bool:
    """True when every element of a short vector (list, tuple or ndarray) is finite (~10x cheaper than
    np.all(np.isfinite()) on 6 values; an ndarray is converted with one ``tolist()`` call first, 3x
    cheaper than iterating its numpy scalars)."""
    if type(values) is np.ndarray:
        values = values.tolist()
    return all(map(_isfinite, values))


def clipped(values, limit: float) -> list[float]:
    """Each element limited to [-limit, limit], as Python floats (NaN stays NaN)."""
    if type(values) is np.ndarray:
        return [min(max(v, -limit), limit) for v in values.tolist()]
    return [min(max(float(v), -limit), limit) for v in values]


def stamp_ns(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def set_stamp(msg: Any, t_ns: int) -> None:
    msg.header.stamp.sec = int(t_ns // 1_000_000_000)
    msg.header.stamp.nanosec = int(t_ns % 1_000_000_000)


def joint_state(cls: type, t_ns: int, position=(), velocity=(), effort=(), names: Sequence[str] = MAGNETS,
                frame: str = FRAME) -> Any:
    """A per-magnet JointState (gaps [m], rates [m/s], currents [A] or voltages [V] in effort)."""
    m = cls()
    set_stamp(m, t_ns)
    m.header.frame_id = frame
    m.name = list(names)
    m.position = [float(v) for v in position]
    m.velocity = [float(v) for v in velocity]
    m.effort = [float(v) for v in effort]
    return m


class JointStates:
    """Builds the JointState messages of the 1 kHz loop at the least cost (~1 us each, ~2x less
    than :func:`joint_state`).

    The stamp is computed once per sample: :meth:`header` makes one ``std_msgs/Header``
    (stamp t [ns], frame) that every message of that sample shares, and :meth:`make` takes
    ``name`` as a list made once per publisher and the values as lists of Python floats
    (``ndarray.tolist()``: one call, no per-element conversion). Nothing is copied: published
    messages are immutable by the transport's contract (intra-process subscribers and the
    recorder hold them), so shared headers and name lists are never modified. Works for the
    DDS transport's classes and for rclpy's alike (both take keyword fields).
    """

    __slots__ = ("Header", "Time", "cls")

    def __init__(self, cls: type):
        probe = cls()
        self.cls = cls
        self.Header = type(probe.header)
        self.Time = type(probe.header.stamp)

    def header(self, t_ns: int, frame: str = FRAME) -> Any:
        """The header of the sample stamped ``t_ns`` (ns) in ``frame``."""
        return self.Header(stamp=self.Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame)

    def make(self, header: Any, names: list[str], position: list[float] = _EMPTY, velocity: list[float] = _EMPTY,
             effort: list[float] = _EMPTY) -> Any:
        """A JointState: gaps [m] in ``position``, rates [m/s] in ``velocity``, currents [A] or
        voltages [V] in ``effort`` (or a named vector in ``position``, contract convention)."""
        return self.cls(header=header, name=names, position=position, velocity=velocity, effort=effort)


def named_vector(cls: type, t_ns: int, names: Sequence[str], values, frame: str = FRAME) -> Any:
    """A named vector carried in JointState.position (contract convention)."""
    return joint_state(cls, t_ns, position=values, names=names, frame=frame)


def meas_array(msg: Any) -> tuple[np.ndarray, bool]:
    """[d1, d1', d2, d2', i1, i2] from a measurement/estimate JointState; (array, velocity measured)."""
    p = msg.position
    v = msg.velocity
    e = msg.effort
    has_v = len(v) >= 2
    z = np.array([p[0], v[0] if has_v else 0.0, p[1], v[1] if has_v else 0.0, e[0], e[1]], dtype=float)
    return z, has_v


def meas_into(msg: Any, out: np.ndarray) -> bool:
    """Fill ``out`` (6,) with [d1, d1', d2, d2', i1, i2] from a measurement/estimate JointState
    (m, m/s, A; rates 0 when not measured), without allocating; True when rates were measured."""
    p = msg.position
    v = msg.velocity
    e = msg.effort
    has_v = len(v) >= 2
    out[0] = p[0]
    out[2] = p[1]
    out[1] = v[0] if has_v else 0.0
    out[3] = v[1] if has_v else 0.0
    out[4] = e[0]
    out[5] = e[1]
    return has_v


class LatencyStats:
    """Streaming latencies (ns) as a histogram: constant memory, and a summary that costs the same
    after one second or one day (the 1 kHz loop calls it every second).

    Percentiles are resolved to ``bin_ns`` (1 us) up to ``bins * bin_ns`` (20 ms); beyond that the
    exact maximum is reported. Negative values count in the first bin.
    """

    def __init__(self, bin_ns: int = 1000, bins: int = 20_000):
        self.bin_ns = int(bin_ns)
        self.hist = np.zeros(bins + 1, dtype=np.int64)  # the last bin: everything beyond
        self._last = bins
        self.n = 0
        self.max_ns = 0

    def add(self, ns: int) -> None:
        i = ns // self.bin_ns
        self.hist[self._last if i > self._last else (i if i > 0 else 0)] += 1
        self.n += 1
        if ns > self.max_ns:
            self.max_ns = ns

    def percentiles_us(self, ps) -> list[float]:
        """The ``ps``-th percentiles (0..100) in us: the centre of the bin holding each rank."""
        if self.n == 0:
            return [math.nan for _ in ps]
        ranks = [max(1, math.ceil(p / 100.0 * self.n)) for p in ps]
        idx = np.searchsorted(np.cumsum(self.hist), ranks)
        return [self.max_ns / 1e3 if i >= self._last else min((i + 0.5) * self.bin_ns, self.max_ns) / 1e3
                for i in idx.tolist()]

    def summary_us(self) -> dict[str, float]:
        p50, p99 = self.percentiles_us((50, 99))
        return {"p50": p50, "p99": p99, "max": self.max_ns / 1e3 if self.n else math.nan}


def diag_array(cls_array: type, cls_status: type, cls_kv: type, t_ns: int, name: str, level: int, message: str, values: dict) -> Any:
    """diagnostic_msgs/DiagnosticArray with one status of key/value pairs."""
    arr = cls_array()
    set_stamp(arr, t_ns)
    st = cls_status()
    st.level = bytes([level]) if isinstance(getattr(st, "level", b""), bytes) else level
    st.name = name
    st.message = message
    st.hardware_id = "dem"
    kvs = []
    for k, v in values.items():
        kv = cls_kv()
        kv.key = str(k)
        kv.value = str(v)
        kvs.append(kv)
    st.values = kvs
    arr.status = [st]
    return arr


class Diagnostics:
    """One node's status on ``/diagnostics``: its counters, every ``period_s`` (1 Hz) and at once on a fault.

    The one way a node reports its health (``nodes/*`` all use it). The node keeps its counts in
    :attr:`counters` (name -> int / float / str / bool; :meth:`count` increments one); each report
    publishes them as key/values, with the transport's per-callback exception counts
    (``callback_errors``) and, when given, the values of ``values()``.

    Level of a report, the worst of:

    * ``ERROR`` while a fault is latched: :meth:`fault` logs the reason once (ERROR), publishes at once
      and keeps the node at ERROR until :meth:`clear_fault` (a fault is never reported only once);
    * the node's own condition, :meth:`set_condition` (e.g. ``WARN`` "converging"; back with ``OK``);
    * ``WARN`` for the report after any counter named in ``warn_on`` (in :attr:`counters` or ``values()``)
      or a callback's exception count increased: the message names the counters and their increase since the previous report. A node
      that recovers goes back to OK; the counters keep the history.

    ``name`` is the status name (default: the node's name); ``hardware_id`` is ``"dem"``.
    """

    def __init__(self, node: Any, name: str | None = None, *, warn_on: Sequence[str] = (),
                 values: Callable[[], Mapping[str, Any]] | None = None, period_s: float = 1.0,
                 timer: bool = True):
        from ..contract import DIAGNOSTICS

        self.node = node
        self.name = name or node.name
        self.counters: dict[str, Any] = {}
        self.warn_on = tuple(warn_on)
        self.values = values
        self._pub = node.publisher(DIAGNOSTICS)
        self._cls = (node.msg("diagnostic_msgs/msg/DiagnosticArray"), node.msg("diagnostic_msgs/msg/DiagnosticStatus"),
                     node.msg("diagnostic_msgs/msg/KeyValue"))
        self._fault: str | None = None
        self._condition: tuple[int, str] = (OK, "")
        self._seen: dict[str, Any] = {}  # the warn_on counters and callback errors at the previous report
        self.reports = 0
        self.timer = node.timer(period_s, self.publish) if timer else None

    def count(self, key: str, n: int = 1) -> int:
        """Add ``n`` to counter ``key`` (created at 0); its new value."""
        v = self.counters.get(key, 0) + n
        self.counters[key] = v
        return v

    @property
    def faulted(self) -> str | None:
        """The latched fault's reason, None when there is none."""
        return self._fault

    def fault(self, reason: str) -> None:
        """Latch ERROR with ``reason``: logged (once per latch) and published at once."""
        if self._fault is None:
            self._fault = reason
            self.node.logger.error(f"fault: {reason}")
            self.publish()

    def clear_fault(self) -> None:
        """Release the latched fault (an explicit reset, e.g. a re-arm); logged."""
        if self._fault is not None:
            self.node.logger.info(f"fault cleared: {self._fault}")
            self._fault = None

    def set_condition(self, level: int, message: str = "") -> None:
        """The node's standing condition (OK / WARN / ERROR and why) until it sets another."""
        self._condition = (int(level), message)

    def _increases(self, values: Mapping[str, Any], errors: Mapping[str, int]) -> list[str]:
        now = {k: values.get(k, 0) for k in self.warn_on}
        now.update({f"callback errors: {k}": v for k, v in errors.items()})
        out = []
        for k, v in now.items():
            d = v - self._seen.get(k, 0)
            if isinstance(d, (int, float)) and d > 0:
                out.append(f"{k} +{d:g}")
        self._seen = now
        return out

    def status(self, condition: tuple[int, str] | None = None) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) of a report now, with ``condition`` (level, message) in place of the
        standing one when given (moves the WARN window: one report's worth)."""
        errors = self.node.callback_errors
        values: dict[str, Any] = dict(self.values()) if self.values is not None else {}
        values.update(self.counters)
        if errors:
            values["callback_errors"] = sum(errors.values())
        grew = self._increases(values, errors)
        level, message = condition if condition is not None else self._condition
        if self._fault is not None:
            level, message = ERROR, self._fault
        if grew and level < WARN:
            level = WARN
        if grew:
            message = "; ".join(m for m in (message, ", ".join(grew)) if m)
        return level, message or "ok", values

    def publish(self, level: int | None = None, message: str = "", values: Mapping[str, Any] | None = None) -> None:
        """Publish a report now: with the standing condition, or with ``level`` and ``message`` in its place
        (an event such as a landing, reported at once; a latched fault and grown counters still count);
        ``values`` are published first, then the counters and ``values()`` not among them."""
        lv, msg, vals = self.status(None if level is None else (int(level), message))
        if values is not None:
            vals = {**values, **{k: v for k, v in vals.items() if k not in values}}
        self.reports += 1
        self._pub.publish(diag_array(*self._cls, self.node.now_ns(), self.name, lv, msg, vals))


class CommandSource:
    """The command source lock of a node that drives the coils (``plant_sim``, ``hw_driver``).

    ``/dem/command`` counts only from the writers that the ROS graph attributes to the node ``source``
    (``command_source``: a name in the node's namespace or ``/ns/name``), recognised by each sample's
    writer GID (:meth:`~dem_ros.transport.api.Node.subscribe_with_source`). :meth:`accepts` answers for
    one sample. A writer not in the source's last looked-up set is looked up on its sample (a restarted
    controller's graph information can trail its first samples by a few ms, and its commands must count
    from the first sample after it arrives: the board holds only ``hold_timeout``, 50 ms, before it
    lands); a writer found foreign is looked up again after ``retry_s``, then after twice as long each
    time, up to ``refresh_s`` (a writer whose graph information trails its samples by D is accepted
    within about 2 D; a foreign 1 kHz writer costs about 10 look-ups in its first 100 ms, then one per
    ``refresh_s``: a look-up reads the graph, far too dear to repeat at 1 kHz; at most 64 are remembered). Every foreign sample is counted
    (``commands_foreign``); the log says it once per writer. :attr:`matched` tells whether the
    source's writer is on the graph (a run must not start before).

    What it protects against: a second controller, a test or replay publisher, a stray tool on the
    same domain. What it does not: without DDS-Security (the PyPI cyclonedds wheel has none) any
    process can forge a GID or announce itself under the source's name.
    """

    def __init__(self, node: Any, source: str, *, refresh_s: float = 0.1, retry_s: float = 0.002,
                 topic: Any = None):
        from ..contract import COMMAND

        self.node = node
        self.source = source
        self.topic = topic or COMMAND
        self.refresh_s = float(refresh_s)  # :attr:`matched`: look-ups while the source has no writer
        self.retry_s = float(retry_s)
        # writer found foreign -> (monotonic time to look it up again, the wait after that look-up fails)
        self._rejected: dict[bytes, tuple[float, float]] = {}
        self.gids: frozenset[bytes] = frozenset()  # the source's writers on the topic, as last looked up
        self.checked = -math.inf  # monotonic time of the last look-up (s)
        self.foreign = 0
        self._logged: set[bytes] = set()  # foreign writers already logged (at most 64)

    def values(self) -> dict[str, Any]:
        """For /diagnostics: ``command_source``, ``command_writers`` (the source's), ``commands_foreign``."""
        return {"command_source": self.source, "command_writers": len(self.gids), "commands_foreign": self.foreign}

    def _lookup(self) -> frozenset[bytes]:
        self.checked = time.monotonic()
        self.gids = self.node.publisher_gids(self.topic, self.source)
        return self.gids

    @property
    def matched(self) -> bool:
        """The source has a writer on the topic (looked up at most every ``refresh_s`` while it has none)."""
        if not self.gids and time.monotonic() - self.checked >= self.refresh_s:
            self._lookup()
        return bool(self.gids)

    def accepts(self, gid: bytes) -> bool:
        """True for a sample of the source's writers; another writer's is counted (and logged once)."""
        if gid in self.gids:
            return True
        now = time.monotonic()
        due, wait = self._rejected.get(gid, (-math.inf, self.retry_s))
        if now >= due:
            if gid in self._lookup():
                self._rejected.pop(gid, None)
                return True
            if gid not in self._rejected and len(self._rejected) >= 64:
                self._rejected.pop(next(iter(self._rejected)))  # the oldest
            self._rejected[gid] = (now + wait, min(2.0 * wait, max(self.refresh_s, self.retry_s)))
        self.foreign += 1
        if gid not in self._logged and len(self._logged) < 64:
            self._logged.add(gid)
            self.node.logger.warn(f"{self.topic.name} from writer {gid.hex() or '(unknown)'}, not {self.source!r}'s:"
                                  " dropped (further samples are counted)")
        return False
