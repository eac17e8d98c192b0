"""The in-memory transport: node logic under test, without middleware or wall clock.

A :class:`MemoryBus` stands for the graph of one process: its nodes
(:class:`MemoryNode`, honouring :class:`~dem_ros.transport.api.Node`) publish
into one FIFO queue that :meth:`MemoryBus.spin_once` delivers, in publish order
and never re-entrantly (as the DDS executor's intra-process path does: the
message object itself, not a copy; CDR bytes for raw subscriptions). Time is a
manual clock: ``now_ns()`` is :attr:`MemoryBus.now_ns`, and timers fire only
when :meth:`MemoryBus.advance` moves the clock past their deadlines, so a test
controls exactly what a node sees and when. Services are called synchronously
with :meth:`MemoryBus.call`. Message classes are the DDS transport's IDL
structs (plain dataclasses; no participant is created).

Sources: every publisher has a GID (16 bytes, numbered in creation order); a
sourced subscription gets ``(msg, gid)``, ``b""`` for :meth:`MemoryBus.publish`
(a stimulus from outside the graph has no writer), and
:meth:`MemoryNode.publisher_gids` answers from the bus's publishers.

Parameters are declared and validated as on the other transports (ROS
arguments, params files, :class:`~dem_ros.transport.parameters.ParameterStore`);
``/parameter_events`` is not published.

    bus = MemoryBus()
    node = bus.node("controller", ["--ros-args", "-p", "k1:=60"])
    ControllerNode(node)
    bus.publish(contract.ESTIMATE, msg)   # from outside the graph
    bus.spin_once()                       # deliver
    bus.advance(0.001)                    # run the timers due in the next millisecond
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..contract import Topic
from .api import (
    GID_SIZE,
    CallbackGuard,
    OnChange,
    RawCallback,
    ServiceCallback,
    SourcedCallback,
    TransportError,
    node_fqn,
)
from .lifecycle import LifecycleInterface, LifecycleMachine, event_topic
from .logger import NodeLogger
from .parameters import ParameterStore
from .rosargs import initial_parameters, parse_ros_args

__all__ = ["MemoryBus", "MemoryNode", "MemoryPublisher", "MemoryTimer"]

#: the clock's start: 2023-11-14T22:13:20Z, an epoch-like stamp (ns)
START_NS = 1_700_000_000_000_000_000


@dataclass
class _Subscription:
    node: MemoryNode
    callback: Callable[[Any], object]
    raw: bool
    sourced: bool = False  # the callback takes (msg, writer gid)


class MemoryTimer:
    """A periodic callback on the bus's manual clock (absolute deadlines, like the DDS timer)."""

    def __init__(self, node: MemoryNode, period_s: float, callback: Callable[[], object]):
        if not period_s > 0:
            raise ValueError(f"timer period must be positive, got {period_s!r} s")
        self.node = node
        self.period_ns = round(period_s * 1e9)
        self.callback = callback
        self.next_ns = node.bus.now_ns + self.period_ns
        self.fired = 0
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class MemoryPublisher:
    """Publishes into the bus's queue; ``subscription_count`` counts the topic's subscriptions."""

    def __init__(self, bus: MemoryBus, name: str, type_name: str, node: MemoryNode | None = None):
        self._bus = bus
        self.topic = name
        self.type_name = type_name
        bus.writers.append((name, node, self))
        self.gid = len(bus.writers).to_bytes(GID_SIZE, "big")  # this writer's GID

    def publish(self, msg: Any) -> None:
        self._bus._enqueue(self.topic, msg, None, gid=self.gid)

    def publish_raw(self, data: bytes) -> None:
        self._bus._enqueue(self.topic, None, bytes(data), self.type_name, gid=self.gid)

    @property
    def subscription_count(self) -> int:
        return len(self._bus.subscriptions.get(self.topic, ()))


class MemoryNode:
    """A node on a :class:`MemoryBus` (make it with :meth:`MemoryBus.node`)."""

    transport = "memory"

    def __init__(self, bus: MemoryBus, name: str, args: Sequence[str] | None = None, *,
                 ignore_undeclared: bool = False):
        self.bus = bus
        self._ros_args = parse_ros_args(list(args or []))
        self._given_name = name  # node-targeted ROS arguments name this one
        self.name = self._ros_args.name_for(name)
        self.namespace = self._ros_args.namespace_for(name)
        self._ignore_undeclared = ignore_undeclared
        self.logger = NodeLogger(lambda: self.fully_qualified_name,
                                 sink=lambda level, name, text, _t: bus.log.append((level, name, text)),
                                 echo=lambda: bus.echo)
        self._guard = CallbackGuard(lambda: self.logger)
        self._params: ParameterStore | None = None
        self._shutdown = False

    @property
    def fully_qualified_name(self) -> str:
        return self.namespace.rstrip("/") + "/" + self.name

    @property
    def intra_process(self) -> bool:
        return True

    @property
    def is_shutdown(self) -> bool:
        return self._shutdown

    @property
    def callback_errors(self) -> dict[str, int]:
        return dict(self._guard.errors)

    def resolve(self, topic_name: str) -> str:
        return self._ros_args.resolve(topic_name, self.namespace, self._given_name)

    def publisher(self, topic: Topic) -> MemoryPublisher:
        return MemoryPublisher(self.bus, self.resolve(topic.name), topic.type, self)

    def _subscribe(self, topic: Topic, callback: Callable[[Any], object], raw: bool) -> None:
        name = self.resolve(topic.name)
        sub = _Subscription(self, self._guard.wrap(f"subscription {name}", callback), raw)
        self.bus.subscriptions.setdefault(name, []).append(sub)

    def subscribe(self, topic: Topic, callback: Callable[[Any], object]) -> None:
        self._subscribe(topic, callback, raw=False)

    def subscribe_raw(self, topic: Topic, callback: RawCallback) -> None:
        self._subscribe(topic, callback, raw=True)

    def subscribe_with_source(self, topic: Topic, callback: SourcedCallback) -> None:
        name = self.resolve(topic.name)
        sub = _Subscription(self, self._guard.wrap(f"subscription {name}", lambda pair: callback(*pair)), False, True)
        self.bus.subscriptions.setdefault(name, []).append(sub)

    def publisher_gids(self, topic: Topic, node: str) -> frozenset[bytes]:
        name, fqn = self.resolve(topic.name), node_fqn(node, self.namespace)
        return frozenset(p.gid for t, n, p in self.bus.writers
                         if t == name and n is not None and n.fully_qualified_name == fqn and not n.is_shutdown)
    def timer(self, period_s: float, callback: Callable[[], object]) -> MemoryTimer:
        t = MemoryTimer(self, period_s, self._guard.wrap(f"timer {period_s:g} s", callback))
        self.bus.timers.append(t)
        return t

    def service(self, name: str, srv_type: str, callback: ServiceCallback) -> None:
        from .dds.srvs import service_classes

        full = self.fully_qualified_name.rstrip("/") + "/" + name.strip("/")
        if full in self.bus.services:
            raise TransportError(f"service {full} already exists")
        self.bus.services[full] = (srv_type, service_classes(srv_type), callback, self)

    def serve_lifecycle(self, machine: LifecycleMachine) -> None:
        """The managed-node services on the bus (:meth:`MemoryBus.call`) with the dds IDL types; a DEFERRED
        ``~/change_state`` returns its response at once with ``success`` False, set when the transition ends."""
        from .dds import lifecycle_msgs as lm

        iface = LifecycleInterface(machine, State=lm.State, Transition=lm.Transition,
                                   TransitionDescription=lm.TransitionDescription, TransitionEvent=lm.TransitionEvent,
                                   log=self.logger.warn)
        events = self.publisher(event_topic(self.fully_qualified_name))
        machine.listeners.append(lambda e: events.publish(iface.event(e)))
        def change_state(req: Any, rep: Any) -> Any:
            iface.change_state(req, rep, lambda: None)
            return rep

        for srv, srv_type in lm.SERVICES.items():
            self.service(srv, srv_type, change_state if srv == "change_state" else getattr(iface, srv))

    def now_ns(self) -> int:
        return self.bus.now_ns

    def msg(self, type_name: str) -> type:
        from .dds.msgs import message_class

        return message_class(type_name)

    def declare_parameters(self, group: str, on_change: OnChange | None = None) -> dict[str, Any]:
        if self._params is not None:
            raise TransportError(f"{self.fully_qualified_name}: parameters already declared "
                                 f"(group {self._params.group!r})")
        values = initial_parameters(group, self._ros_args, self.name, strict=not self._ignore_undeclared)
        self._params = ParameterStore(group, values, on_change)
        return dict(values)

    @property
    def parameters(self) -> dict[str, Any]:
        return self._params.values if self._params is not None else {}

    def set_parameters(self, changes: Mapping[str, Any]) -> str | None:
        if self._params is None:
            return "no parameters declared"
        return self._params.set(changes, self.fully_qualified_name)

    def spin_once(self, timeout_s: float = 0.0) -> None:
        """Deliver what is queued and run the timers due now (the clock does not move)."""
        self.bus.spin_once()

    def spin(self) -> None:
        """Run simulated time forward, timer deadline by timer deadline, until this node shuts down
        (or nothing is left that could ever run)."""
        while not self._shutdown and self.bus.step():
            pass

    def shutdown(self) -> None:
        self._shutdown = True


class MemoryBus:
    """The in-memory graph: queue, subscriptions, timers, services, clock and log of its nodes.

    Attributes:
        now_ns: the manual clock, ROS time (ns); moved by :meth:`advance` / :meth:`step`.
        log: every line logged by the nodes, ``(level, node, text)``.
        echo: also write log lines to stderr.
    """

    def __init__(self, start_ns: int = START_NS, *, echo: bool = False):
        self.now_ns = int(start_ns)
        self.queue: deque[tuple[_Subscription, Any]] = deque()
        self.subscriptions: dict[str, list[_Subscription]] = {}
        self.timers: list[MemoryTimer] = []
        self.services: dict[str, tuple[str, tuple[type, type], ServiceCallback, MemoryNode]] = {}
        self.log: list[tuple[str, str, str]] = []
        self.echo = echo
        #: every publisher made on the bus: (topic, its node, publisher); a shut-down node's have left the graph
        self.writers: list[tuple[str, MemoryNode | None, MemoryPublisher]] = []

    def node(self, name: str, args: Sequence[str] | None = None, *, ignore_undeclared: bool = False) -> MemoryNode:
        """A new node on this bus (``args``: ROS arguments, e.g. ``["--ros-args", "-p", "k1:=60"]``)."""
        return MemoryNode(self, name, args, ignore_undeclared=ignore_undeclared)

    # -- messages ------------------------------------------------------------------------
    def _enqueue(self, topic: str, msg: Any, data: bytes | None, type_name: str | None = None,
                 gid: bytes = b"") -> None:
        subs = self.subscriptions.get(topic)
        if not subs:
            return
        if data is None and any(s.raw for s in subs):
            from . import serialize

            data = serialize(msg)
        if msg is None and any(not s.raw for s in subs):
            from . import deserialize

            assert type_name is not None
            msg = deserialize(type_name, data or b"", transport="dds")
        for s in subs:
            self.queue.append((s, data if s.raw else (msg, gid) if s.sourced else msg))

    def publish(self, topic: Topic, msg: Any) -> None:
        """Publish ``msg`` on ``topic`` from outside the nodes (a test's stimulus)."""
        self._enqueue(topic.name, msg, None)

    def msg(self, type_name: str) -> type:
        from .dds.msgs import message_class

        return message_class(type_name)

    def spin_once(self) -> int:
        """Run the timers due now, then deliver every queued message, including those the callbacks
        publish meanwhile (FIFO); return the number of callbacks run."""
        n = self._fire_due()
        while self.queue:
            sub, arg = self.queue.popleft()
            if not sub.node.is_shutdown:
                sub.callback(arg)
                n += 1
        return n

    def _fire_due(self) -> int:
        n = 0
        for t in list(self.timers):
            if t.cancelled or t.node.is_shutdown:
                continue
            while t.next_ns <= self.now_ns:
                t.next_ns += t.period_ns
                t.fired += 1
                t.callback()
                n += 1
                while self.queue:
                    sub, arg = self.queue.popleft()
                    if not sub.node.is_shutdown:
                        sub.callback(arg)
        return n

    def next_deadline(self) -> int | None:
        """The earliest deadline of a live timer (ns), None if there is none."""
        due = [t.next_ns for t in self.timers if not t.cancelled and not t.node.is_shutdown]
        return min(due) if due else None

    def step(self) -> bool:
        """Move the clock to the next timer deadline and run what is due; False if no timer is left."""
        self.spin_once()
        nxt = self.next_deadline()
        if nxt is None:
            return False
        self.now_ns = max(self.now_ns, nxt)
        self.spin_once()
        return True

    def advance(self, seconds: float) -> None:
        """Run the graph for ``seconds`` of simulated time: every timer deadline in between, in order."""
        end = self.now_ns + round(seconds * 1e9)
        self.spin_once()
        while True:
            nxt = self.next_deadline()
            if nxt is None or nxt > end:
                break
            self.now_ns = max(self.now_ns, nxt)
            self.spin_once()
        self.now_ns = end
        self.spin_once()

    # -- services ------------------------------------------------------------------------
    def call(self, service: str, **fields: Any) -> Any:
        """Call ``service`` (its full name, e.g. ``/hw_driver/arm``) with request ``fields``; the response.

        A callback that raises answers ``success = False`` with the exception (counted and logged
        once, as on the other transports). Queued messages are delivered before and after.
        """
        if service not in self.services:
            raise TransportError(f"no service {service}; known: {', '.join(sorted(self.services)) or 'none'}")
        _srv_type, (req_cls, rep_cls), callback, node = self.services[service]
        self.spin_once()
        req, rep = req_cls(**fields), rep_cls()
        out = node._guard.answer(f"service {service}", callback, req, rep)
        self.spin_once()
        return out
