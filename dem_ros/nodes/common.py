"""Message <-> array conversion, loop statistics and the per-node ``/diagnostics`` reporter shared by
the nodes (no control math)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ..contract import FRAME, MAGNETS, inputs_status
from .diagnostics import DiagnosedPublisher, FrequencyStatus, TimeStampStatus, TopicDiagnostic

__all__ = [
    "ERROR",
    "OK",
    "PLANT_SOURCES",
    "SHAPES",
    "WARN",
    "Binding",
    "CommandSource",
    "Diagnostics",
    "Inputs",
    "JointStates",
    "LatencyStats",
    "all_finite",
    "clipped",
    "diag_array",
    "diag_status",
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


def diag_status(cls_status: type, cls_kv: type, name: str, level: int, message: str, values: Mapping[str, Any],
                hardware_id: str = "") -> Any:
    """diagnostic_msgs/DiagnosticStatus of key/value pairs (``str()`` of each value)."""
    st = cls_status()
    st.level = bytes([level]) if isinstance(getattr(st, "level", b""), bytes) else level
    st.name = name
    st.message = message
    st.hardware_id = hardware_id
    kvs = []
    for k, v in values.items():
        kv = cls_kv()
        kv.key = str(k)
        kv.value = str(v)
        kvs.append(kv)
    st.values = kvs
    return st


def diag_array(cls_array: type, cls_status: type, cls_kv: type, t_ns: int, name: str, level: int, message: str,
               values: Mapping[str, Any], hardware_id: str = "") -> Any:
    """diagnostic_msgs/DiagnosticArray with one status of key/value pairs (``hardware_id``: empty for software,
    as diagnostic_updater has it for a node without hardware; a driver's: its device)."""
    arr = cls_array()
    set_stamp(arr, t_ns)
    arr.status = [diag_status(cls_status, cls_kv, name, level, message, values, hardware_id)]
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
      or a callback's exception count increased: the message names the counters and their increase since the previous
      report. A node that recovers goes back to OK; the counters keep the history.

    ``name`` is the status name, ``"<node>: <task>"`` as diagnostic_updater names a node's tasks (the names are
    in :mod:`dem_ros.contract`; default ``"<node>: status"``). ``hardware_id``: empty for a software node
    (diagnostic_updater's for a node without a device); a driver's is its device's identity, known once the
    device answered: set :attr:`hardware_id` then (every later report carries it).

    Topics: :meth:`diagnosed` wraps a publisher of a topic with a nominal rate so that each message ticks its
    ``"<node>: <topic> topic status"`` (frequency and timestamp, diagnostic_updater's keys:
    :mod:`dem_ros.nodes.diagnostics`). :meth:`report` publishes them once a second with the node's status (the
    node's timer, or the node's own once-a-second call when ``timer`` is False); :meth:`publish` (an event, a
    fault) sends the node's status alone.
    """

    def __init__(self, node: Any, name: str | None = None, *, warn_on: Sequence[str] = (),
                 values: Callable[[], Mapping[str, Any]] | None = None, period_s: float = 1.0,
                 timer: bool = True, hardware_id: str = ""):
        from ..contract import DIAGNOSTICS

        self.node = node
        self.name = name or f"{node.name}: status"
        self.hardware_id = hardware_id
        self.topics: list[TopicDiagnostic] = []
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
        self.period_ns = round(period_s * 1e9)  # the reports' period (the node's own calls' when timer is False)
        self.timer = node.timer(period_s, self.report) if timer else None

    def diagnosed(self, topic: Any, publisher: Any = None, *, clock: Callable[[], int] | None = None,
                  tolerance: float = 0.1, window_size: int = 5, min_delay_s: float = -1.0,
                  max_delay_s: float = 5.0) -> DiagnosedPublisher:
        """``publisher`` (default: the node's new publisher of ``topic``, a :class:`dem_ros.contract.Topic`) with
        the status ``"<node>: <topic> topic status"``: each message published ticks it with its stamp and the
        time of ``clock`` (default the node's ``now_ns``; a thread that outlives the node: ``time.time_ns``).
        The frequency's target is the topic's ``rate_hz``; ``tolerance``, ``window_size`` (reports) and the
        acceptable stamp delays [s] are diagnostic_updater's defaults."""
        if not topic.rate_hz:
            raise ValueError(f"{topic.name} has no nominal rate to diagnose")
        rate = float(topic.rate_hz)
        td = TopicDiagnostic(topic.name, FrequencyStatus(rate, rate, tolerance=tolerance, window_size=window_size),
                             TimeStampStatus(min_delay_s, max_delay_s))
        self.topics.append(td)
        return DiagnosedPublisher(publisher if publisher is not None else self.node.publisher(topic), td,
                                  clock or self.node.now_ns)

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

    def publish(self, level: int | None = None, message: str = "", values: Mapping[str, Any] | None = None, *,
                topics: bool = False) -> None:
        """Publish a report now: with the standing condition, or with ``level`` and ``message`` in its place
        (an event such as a landing, reported at once; a latched fault and grown counters still count);
        ``values`` are published first, then the counters and ``values()`` not among them. ``topics``: with the
        topics' statuses (:meth:`report`)."""
        lv, msg, vals = self.status(None if level is None else (int(level), message))
        if values is not None:
            vals = {**values, **{k: v for k, v in vals.items() if k not in values}}
        self.reports += 1
        now = self.node.now_ns()
        arr = diag_array(*self._cls, now, self.name, lv, msg, vals, self.hardware_id)
        if topics:
            statuses = list(arr.status)
            for td in self.topics:
                if td.ready(now, self.period_ns // 2):  # a window of half a period at least
                    t_level, t_message, t_values = td.run(now)
                    statuses.append(diag_status(self._cls[1], self._cls[2], f"{self.node.name}: {td.name}", t_level,
                                                t_message, t_values, self.hardware_id))
            arr.status = statuses
        self._pub.publish(arr)

    def report(self, level: int | None = None, message: str = "", values: Mapping[str, Any] | None = None) -> None:
        """The once-a-second report: the node's status as :meth:`publish` sends it, and in the same array the
        status of every :meth:`diagnosed` topic first published at least half a period ago (its window moves on
        by one report)."""
        self.publish(level, message, values, topics=True)


def _writer(gid: bytes) -> str:
    """A writer's GID as the log and /diagnostics name it."""
    return gid.hex() if gid else "(a writer the transport cannot tell)"


def _counts_of(field: str, *allowed: int) -> Callable[[Any], str | None]:
    """A check that ``msg.<field>`` has one of the ``allowed`` element counts."""

    def check(msg: Any) -> str | None:
        n = len(getattr(msg, field))
        return None if n in allowed else f"{n} values in {field}, expected {' or '.join(map(str, allowed))}"

    return check


def _all_of(*checks: Callable[[Any], str | None]) -> Callable[[Any], str | None]:
    def check(msg: Any) -> str | None:
        for c in checks:
            reason = c(msg)
            if reason:
                return reason
        return None

    return check


#: the shape of every loop input (element counts of the contract, :mod:`dem_ros.contract`): a sample of another
#: shape from the bound writer is malformed (rejected and counted)
SHAPES: dict[str, Callable[[Any], str | None]] = {
    "/dem/measurement": _all_of(_counts_of("position", 2), _counts_of("velocity", 0, 2), _counts_of("effort", 2)),
    "/dem/applied_voltage": _counts_of("effort", 2),
    "/dem/state_estimate": _all_of(_counts_of("position", 2), _counts_of("velocity", 0, 2), _counts_of("effort", 2)),
    "/dem/reference": _counts_of("position", 10),
    "/dem/command": _counts_of("effort", 2),
}
#: the nodes that write the plant's streams (/dem/measurement, /dem/applied_voltage): the simulator or the driver
PLANT_SOURCES = ("plant_sim", "hw_driver")


class Binding:
    """One loop input bound to one writer (made by :meth:`Inputs.bind`; docs/manual/trust.md).

    Samples reach ``callback(msg)`` only from the bound writer (by GID, :meth:`~dem_ros.transport.api.Node.
    subscribe_with_source`) and only when they have the contract's shape (:data:`SHAPES`; else ``malformed``).
    The bound writer is the first writer to send that the ROS graph attributes to one of the ``sources`` node
    names (:meth:`~dem_ros.transport.api.Node.publisher_gids`):

    * a writer the graph does not attribute yet, while nothing is bound (a node whose graph information trails its
      first samples: discovery came late), is *held*: its latest sample is kept and delivered the moment the graph
      attributes the writer to the source (looked up after 2, 4, 8, 16 ms, then every ``retry_max_s``, from its
      samples and from the :class:`Inputs` timer, so a lockstep loop waiting for that one sample gets it), at
      most ``attribute_s``; then it is refused;
    * any other writer while one is bound, a second writer with the source's node name included, is refused:
      every sample counted (``refused``), logged once per writer (WARN) and reported (ERROR on /diagnostics,
      naming its GID);
    * two writers of the source at once with nothing bound (an impersonator there before the run): the first of
      them to send is bound and the others refused (a warning at once; ERROR on /diagnostics while none is bound;
      an impersonator that sends first wins: only DDS-Security tells them apart);
    * the bound writer gone from the graph (the node left, or its participant's lease ran out): unbound, and the
      next single writer of the source is bound (``rebinds``): the defined path of a restarted node.
    """

    def __init__(self, inputs: Inputs, topic: Any, sources: tuple[str, ...], callback: Callable[[Any], object],
                 check: Callable[[Any], str | None] | None):
        self.inputs = inputs
        self.node = inputs.node
        self.topic = topic
        self.sources = sources
        self.callback = callback
        self.check = check
        self.key = topic.name.rsplit("/", 1)[-1]  # /dem/command -> command: its /diagnostics keys
        self.bound = b""  # the bound writer's GID (b"": none)
        self.writers: frozenset[bytes] = frozenset()  # the sources' live writers, as last looked up
        self.ambiguous = False  # two or more writers of the sources with nothing bound
        self._next_ns = 0  # the next look-up is due (node clock, ns)
        self._wait_ns = inputs.retry_ns  # the wait after it
        self.pending: dict[bytes, list[Any]] = {}  # unattributed writer -> [first seen (ns), latest sample, held]
        self.refused_writers: dict[bytes, str] = {}  # writer -> why (at most 64 remembered)
        self.accepted = self.held = self.released = self.refused = self.malformed = self.rebinds = self.lookups = 0
        self.last_refused = b""  # the GID of the writer refused last
        self.node.subscribe_with_source(topic, self.on_sample)

    @property
    def source_text(self) -> str:
        return " or ".join(repr(s) for s in self.sources)

    @property
    def matched(self) -> bool:
        """A writer is bound, or writers of the source are on the graph (looked up now when due)."""
        if not self.bound:
            self.resolve(self.node.now_ns())
        return bool(self.bound or self.writers)

    def values(self) -> dict[str, Any]:
        """This input's keys on /diagnostics (``<key>_writer``, ``_refused``, ``_malformed``, ...)."""
        k = self.key
        return {f"{k}_writer": self.bound.hex(), f"{k}_refused": self.refused,
                f"{k}_refused_writers": len(self.refused_writers), f"{k}_malformed": self.malformed,
                f"{k}_held": self.held, f"{k}_late": self.released, f"{k}_rebinds": self.rebinds}

    # -- samples ----------------------------------------------------------------------------------------
    def on_sample(self, msg: Any, gid: bytes) -> None:
        if gid == self.bound and gid:
            self._deliver(msg)
            return
        now = self.node.now_ns()
        if not gid:
            self._refuse(gid, "the transport cannot tell which writer sent it", 1)
            return
        if gid in self.refused_writers:
            self.resolve(now)  # when due: the bound writer may be gone and this one the source's next
            if gid == self.bound:
                self._deliver(msg)
                return
            if self.bound or gid not in self.writers:
                self._refuse(gid, self.refused_writers[gid], 1)
                return
            del self.refused_writers[gid]  # nothing bound and the graph names it the source's: it may be bound
        if self.bound:
            # a new writer beside the bound one: the graph is looked up at once (the bound writer may have left:
            # a restart); while the bound one lives, the new one is refused, whatever its node name
            self._wait_ns = self.inputs.retry_ns
            self.resolve(now, force=True)
            if gid == self.bound:
                self._deliver(msg)
                return
            if self.bound:
                self._refuse(gid, self._why(gid), 1)
                return
        # nothing bound: the writer may be the source's, its graph information not here yet: held
        p = self.pending.get(gid)
        if p is None:
            self.pending[gid] = [now, msg, 1]
            self._wait_ns = self.inputs.retry_ns
            self.held += 1
            self.resolve(now, force=True)
        else:
            p[1] = msg
            p[2] += 1
            self.held += 1
            self.resolve(now)

    def _deliver(self, msg: Any) -> None:
        reason = self.check(msg) if self.check is not None else None
        if reason:
            self.malformed += 1
            if worth_logging(self.malformed):
                self.node.logger.warn(f"{self.topic.name}: malformed sample from the bound writer rejected: {reason}"
                                      f" ({self.malformed} so far)")
            return
        self.accepted += 1
        self.callback(msg)

    def _why(self, gid: bytes) -> str:
        if gid in self.writers:
            return f"a second writer of {self.source_text} (the bound one is {self.bound.hex()})"
        return f"not the bound writer of {self.source_text} ({self.bound.hex() or 'none bound'})"

    def _refuse(self, gid: bytes, why: str, n: int) -> None:
        self.refused += n
        self.last_refused = gid
        if len(self.inputs.refused_now) < 16:
            self.inputs.refused_now.setdefault((self.topic.name, gid), why)
        if gid not in self.refused_writers:
            if len(self.refused_writers) >= 64:
                self.refused_writers.pop(next(iter(self.refused_writers)))  # the oldest
            self.refused_writers[gid] = why
            self.node.logger.warn(f"{self.topic.name} from writer {_writer(gid)} refused: {why} (further samples are"
                                  " counted)")

    # -- the graph --------------------------------------------------------------------------------------
    def _bind(self, gid: bytes, now: int) -> None:
        self.bound = gid
        self.refused_writers.pop(gid, None)
        self.node.logger.info(f"{self.topic.name}: bound to writer {gid.hex()} of {self.source_text}")
        held = self.pending.pop(gid, None)
        if held is not None:
            if held[0] < now:
                self.released += 1  # held until the graph named its writer
            self._deliver(held[1])  # the latest sample it sent before it was bound

    def resolve(self, now: int, force: bool = False) -> None:
        """Look the sources' writers up when due (or ``force``) and bind, re-bind or refuse accordingly."""
        if not force and now < self._next_ns:
            return
        inp = self.inputs
        self.lookups += 1
        live: frozenset[bytes] = frozenset()
        for s in self.sources:
            live = live | self.node.publisher_gids(self.topic, s)
        self.writers = live
        if self.bound and self.bound not in live:
            self.node.logger.warn(f"{self.topic.name}: the bound writer {self.bound.hex()} of {self.source_text} is "
                                  "gone: the next writer of the source is bound")
            self.bound = b""
            self.rebinds += 1
            self._wait_ns = inp.retry_ns
        if not self.bound:
            # the first writer of the source to send is bound (a writer of the source's name that is there but
            # silent, e.g. an idle script started before the graph, does not take the input); several writers with
            # the source's name: a warning at once (ERROR on /diagnostics while none is bound)
            if len(live) > 1 and not self.ambiguous:
                self.ambiguous = True
                self.node.logger.warn(f"{self.topic.name}: {len(live)} writers of {self.source_text} "
                                      f"({', '.join(g.hex() for g in sorted(live))}): the first to send is bound")
            first = next((g for g in self.pending if g in live), None)
            if first is not None:
                self._bind(first, now)
        for gid, (first, _msg, n) in list(self.pending.items()):
            if self.bound:
                del self.pending[gid]
                self._refuse(gid, self._why(gid), n)
            elif now - first > inp.attribute_ns:
                del self.pending[gid]
                self._refuse(gid, f"no writer of {self.source_text} after {inp.attribute_ns / 1e9:g} s", n)
        cap = inp.retry_max_ns if self.pending else inp.waiting_ns if not self.bound else inp.refresh_ns
        self._next_ns = now + min(self._wait_ns, cap)
        self._wait_ns = min(2 * self._wait_ns, cap)


class Inputs:
    """The loop inputs of one node, each bound to its writer (:class:`Binding`): the one mechanism every node
    uses for ``/dem/measurement``, ``/dem/applied_voltage``, ``/dem/state_estimate``, ``/dem/reference`` and
    ``/dem/command`` (docs/manual/trust.md).

    A timer every ``period_s`` looks up what is due (unbound inputs, held writers; a bound writer's liveness
    every ``refresh_s``). The node's ``<node>: inputs`` status on /diagnostics (every second): ERROR while
    writers are refused (the message names each one's GID and why; ``refused`` counts every refused sample, the
    figure a run's verdict reads), ERROR while two writers of one source leave an input unbound, WARN after a
    malformed sample, else OK; the values hold each input's counts (:meth:`Binding.values`).
    """

    def __init__(self, node: Any, *, period_s: float = 0.005, retry_s: float = 0.002, retry_max_s: float = 0.02,
                 waiting_s: float = 0.1, refresh_s: float = 0.5, attribute_s: float = 2.0):
        self.node = node
        self.retry_ns = round(retry_s * 1e9)
        self.retry_max_ns = round(retry_max_s * 1e9)
        self.waiting_ns = round(waiting_s * 1e9)
        self.refresh_ns = round(refresh_s * 1e9)
        self.attribute_ns = round(attribute_s * 1e9)
        self.bindings: list[Binding] = []
        self.refused_now: dict[tuple[str, bytes], str] = {}  # (topic, writer) -> why: refusals since the last report
        self.diag = Diagnostics(node, inputs_status(node.name), warn_on=("malformed",), values=self.values,
                                timer=False)
        node.timer(period_s, self.tick)
        node.timer(1.0, self.report)

    def bind(self, topic: Any, sources: str | Sequence[str], callback: Callable[[Any], object], *,
             check: Callable[[Any], str | None] | None = None) -> Binding:
        """Deliver ``topic`` to ``callback(msg)`` from the one writer of ``sources`` (node names), samples of
        the contract's shape only (``check``: default :data:`SHAPES`)."""
        b = Binding(self, topic, (sources,) if isinstance(sources, str) else tuple(sources), callback,
                    check or SHAPES.get(topic.name))
        self.bindings.append(b)
        return b

    def tick(self) -> None:
        now = self.node.now_ns()
        for b in self.bindings:
            b.resolve(now)

    def values(self) -> dict[str, Any]:
        out: dict[str, Any] = {"refused": sum(b.refused for b in self.bindings),
                               "malformed": sum(b.malformed for b in self.bindings)}
        for b in self.bindings:
            out.update(b.values())
        return out

    def report(self) -> None:
        """Publish the ``<node>: inputs`` status (once a second)."""
        seen, self.refused_now = self.refused_now, {}
        ambiguous = [b for b in self.bindings if b.ambiguous and not b.bound and len(b.writers) > 1]
        if seen:
            self.diag.set_condition(ERROR, "; ".join(f"refused {t} writer {_writer(g)}: {why}"
                                                     for (t, g), why in list(seen.items())[:4]))
        elif ambiguous:
            self.diag.set_condition(ERROR, "; ".join(f"{b.topic.name}: {len(b.writers)} writers of {b.source_text},"
                                                     " none bound" for b in ambiguous))
        else:
            waiting = [b.topic.name for b in self.bindings if not b.bound]
            self.diag.set_condition(OK, f"waiting for the writer of {', '.join(waiting)}" if waiting else "")
        self.diag.publish()


class CommandSource:
    """The command source lock of a node that drives the coils (``plant_sim``, ``hw_driver``): ``/dem/command``
    bound (:class:`Binding`) to the writer of the node ``source`` (``command_source``), delivered to
    ``callback(msg)``. :attr:`matched`: a writer is bound (a run must not start before)."""

    def __init__(self, node: Any, source: str, callback: Callable[[Any], object], *, inputs: Inputs | None = None):
        from ..contract import COMMAND

        self.source = source
        self.inputs = inputs or Inputs(node)
        self.binding = self.inputs.bind(COMMAND, source, callback)

    @property
    def matched(self) -> bool:
        return self.binding.matched

    @property
    def foreign(self) -> int:
        """Commands refused (from writers not bound, and held ones never attributed to the source)."""
        return self.binding.refused

    def values(self) -> dict[str, Any]:
        """For the loop status: ``command_source``, ``command_writer`` (the bound GID), ``commands_foreign``
        (refused), ``commands_late`` (held until discovery attributed their writer, then applied),
        ``commands_malformed``."""
        b = self.binding
        return {"command_source": self.source, "command_writer": b.bound.hex(), "commands_foreign": b.refused,
                "commands_late": b.released, "commands_malformed": b.malformed}
