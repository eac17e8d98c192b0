"""The rclpy node: ROS 2's own client library, with the project's messages, codec and executor.

A dem_ros node on rclpy is an ``rclpy.node.Node`` (so rclpy serves the parameter services that
``ros2 param`` reaches, publishes ``/rosout`` and ``/parameter_events``, and parses
``--ros-args``) whose topics carry serialized samples: publishers write the CDR bytes of the
project's message classes (:mod:`dem_ros.transport.dds.msgs`, encoded by
:mod:`~dem_ros.transport.dds.fastcdr`) with ``publish_raw``, and subscriptions are raw ones
whose samples :class:`~.executor.RclpyExecutor` takes with their writer's GID. So node code
gets the same message classes on both transports, and the rosidl Python classes are used
only for their type support (resolved with importlib: ``sensor_msgs.msg.JointState``).

Parameters are declared from the schema with a ParameterDescriptor (description,
FloatingPointRange/IntegerRange, read_only), and one ``add_on_set_parameters_callback``
validates every change against the whole group (``SCHEMA.merged``) and then asks the node's
``on_change``. Start values are computed by :func:`dem_ros.transport.rosargs.initial_parameters`
(the same code as the DDS transport) and declared with ``ignore_override=True``, so a bad
params file fails with the ConfigError message in both transports.

Sources: :meth:`RclpyNode.subscribe_with_source` hands each sample's writer GID (rcl's
``rmw_message_info_t.publisher_gid``, see :mod:`.take`) to the callback; intra-process, the
publisher's own GID.

Only importable where ``import rclpy`` works.
"""

from __future__ import annotations

import contextlib
import importlib
import time
from collections.abc import Callable, Mapping
from typing import Any

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ...contract import QoS, Topic
from ...core.params import SCHEMA
from .. import paramvalue as pv
from ..api import (
    CallbackGuard,
    OnChange,
    RawCallback,
    ServiceCallback,
    SourcedCallback,
    TransportError,
    gid16,
    node_fqn,
)
from ..dds import fastcdr, msgs
from ..lifecycle import LifecycleInterface, LifecycleMachine, event_topic
from ..logger import NodeLogger
from ..loop import LocalSubscription, LoopTimer, SourcedLocalSubscription, deliver_local
from ..parameters import ParameterStore
from ..rosargs import initial_parameters, parse_ros_args
from .executor import RclpyExecutor
from .take import publisher_gid

__all__ = ["RclpyNode", "RclpyPublisher", "ros_type", "to_qos_profile"]

#: how often an intra-process publisher re-reads its count of subscribers outside the container (ns)
_REMOTE_CHECK_NS = 100_000_000
#: rcl's /rosout QoS (Jazzy: reliable, transient local, depth 1000)
_QOS_ROSOUT = QoS(reliable=True, transient_local=True, depth=1000)


def ros_type(type_name: str) -> Any:
    """The rosidl Python class of ``pkg/msg/Name`` or ``pkg/srv/Name`` (``import pkg.msg``), without
    rosidl_runtime_py."""
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action"):
        raise TransportError(f"{type_name!r} is not a ROS type name such as sensor_msgs/msg/JointState")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.{parts[1]}"), parts[2])
    except (ImportError, AttributeError) as exc:
        raise TransportError(f"ROS type {type_name} is not installed ({exc})") from None


def to_qos_profile(q: QoS) -> QoSProfile:
    """contract.QoS -> rclpy QoSProfile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=q.depth,
        reliability=ReliabilityPolicy.RELIABLE if q.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if q.transient_local else DurabilityPolicy.VOLATILE,
    )


def _ignore(_msg: Any) -> None:
    """rclpy wants a callback per subscription; the executor takes the samples itself."""


class RclpyPublisher:
    """Publishes the CDR of the project's message classes through an rclpy publisher (``publish_raw``).

    With ``local`` (inside a container, see :mod:`dem_ros.transport.loop`) a message goes to the
    subscriptions of the same executor through its queue, and to the middleware only while a
    subscriber outside the container is matched.
    """

    def __init__(self, pub: Any, cls: type, local: list[LocalSubscription] | None = None, queue: Any = None,
                 gid: bytes = b""):
        self._pub = pub
        self._raw = pub.handle.publish_raw
        self._cls = cls
        self._encode = fastcdr.encoder(cls)
        self._local = local
        self._queue = queue
        self.gid = gid
        self._remote = 0
        self._remote_checked = 0

    def _cdr(self, msg: Any) -> bytes:
        if type(msg) is self._cls:
            return self._encode(msg) if self._encode is not None else bytes(msg.serialize())  # type: ignore[attr-defined]
        from rclpy.serialization import serialize_message  # a rosidl message (e.g. a stock node's)

        return bytes(serialize_message(msg))

    def _remote_subscribers(self) -> int:
        now = time.monotonic_ns()
        if now >= self._remote_checked:
            self._remote_checked = now + _REMOTE_CHECK_NS
            self._remote = int(self._pub.get_subscription_count()) - len(self._local or ())
        return self._remote

    def publish(self, msg: Any) -> None:
        local = self._local
        if local is None:
            self._raw(self._cdr(msg))
            return
        data = deliver_local(local, self._queue, msg, self.gid, self._cdr)
        if self._remote_subscribers() > 0:
            self._raw(data if data is not None else self._cdr(msg))

    def publish_raw(self, data: bytes) -> None:
        """Send serialized CDR (with encapsulation header) as it is, e.g. a sample from a bag."""
        self._raw(bytes(data))

    @property
    def subscription_count(self) -> int:
        """Matched subscriptions (those of the same container included: they match through rcl too)."""
        return int(self._pub.get_subscription_count())


class RclpyNode:
    """A dem_ros node backed by ``rclpy.node.Node`` and a :class:`~.executor.RclpyExecutor`."""

    transport = "rclpy"

    def __init__(self, name: str, args: list[str] | None = None, *, executor: RclpyExecutor | None = None,
                 ignore_undeclared: bool = False):
        argv = list(args) if args is not None else []
        self._ignore_undeclared = ignore_undeclared
        self._ros_args = parse_ros_args(argv)  # ConfigError on bad --ros-args / missing file
        self._ex = executor if executor is not None else RclpyExecutor(argv)
        self._own_ex = executor is None
        try:
            # rcl's rosout is off: the node logs through NodeLogger and its own /rosout writer (see _rosout)
            self._node = rclpy.create_node(name, enable_rosout=False)
        except Exception as exc:  # an invalid node name, a context shut down meanwhile
            raise TransportError(f"cannot create rclpy node {name!r}: {exc}") from None
        self.name = self._node.get_name()
        self.namespace = self._node.get_namespace()
        # Not rclpy's logger: on the 1 kHz path a node's first lines (the loop's start, a board hold) cost
        # 8-30 ms each and every further line ~0.5 ms (rclpy finds its caller with inspect, rcutils
        # formats, rcl_logging_spdlog writes the log file); the transport's logger writes one stderr line
        # in rcutils' console format and publishes the record on /rosout (rcl_interfaces/msg/Log) itself.
        self.logger = NodeLogger(lambda: self.logger_name)
        self._rosout_pub = RclpyPublisher(
            self._node.create_publisher(ros_type("rcl_interfaces/msg/Log"), "/rosout", to_qos_profile(_QOS_ROSOUT)),
            msgs.Log)
        self.logger.sink = self._rosout
        self._ex.add_node(self)
        self._shutdown = False
        self._destroyed = False
        self._params: ParameterStore | None = None
        self._guard = CallbackGuard(lambda: self.logger)
        #: services whose callback ``(request, response, send)`` answers later (serve_lifecycle's change_state)
        self._deferred_services: dict[Any, Callable[[Any, Any, Callable[[], None]], None]] = {}

    @property
    def fully_qualified_name(self) -> str:
        return str(self._node.get_fully_qualified_name())

    @property
    def logger_name(self) -> str:
        """rcl's logger name of the node (``ns.name``)."""
        return self.fully_qualified_name.lstrip("/").replace("/", ".")

    def _rosout(self, level: str, name: str, text: str, t_ns: int) -> None:
        """One log record on /rosout, as rcl publishes it."""
        self._rosout_pub.publish(msgs.Log(
            stamp=msgs.Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), level=NodeLogger.LEVELS[level],
            name=name, msg=text, file="", function="", line=0))

    @property
    def ros_node(self) -> Any:
        """The underlying ``rclpy.node.Node`` (escape hatch; keep node logic transport-neutral)."""
        return self._node

    @property
    def intra_process(self) -> bool:
        """True when topics between nodes of this node's executor bypass the middleware (composition)."""
        return self._ex.intra_process

    @property
    def callback_errors(self) -> dict[str, int]:
        """Exceptions raised by this node's callbacks so far, per callback name (a copy)."""
        return dict(self._guard.errors)

    # -- topics ------------------------------------------------------------------------
    def _resolve(self, topic: Topic) -> str:
        return str(self._node.resolve_topic_name(topic.name))

    def publisher(self, topic: Topic) -> RclpyPublisher:
        resolved = self._resolve(topic)
        pub = self._node.create_publisher(ros_type(topic.type), topic.name, to_qos_profile(topic.qos.for_writer()))
        gid = publisher_gid(int(pub.handle.pointer))
        cls = msgs.message_class(topic.type)
        if self._ex.intra_process:
            self._ex.local_writers.add(gid)
            return RclpyPublisher(pub, cls, self._ex.local_subscriptions(resolved), self._ex.queue, gid)
        return RclpyPublisher(pub, cls, gid=gid)

    def _subscribe(self, topic: Topic, handler: Callable[[bytes, bytes], object],
                   local: LocalSubscription | None) -> None:
        """A raw rclpy subscription whose samples go to ``handler(cdr, writer_gid)``; inside a
        container also ``local`` (and the rcl copies of the container's publishers' samples are dropped)."""
        resolved = self._resolve(topic)
        what = f"subscription {resolved}"
        ex = self._ex
        guarded = self._guard.wrap(what, handler)
        if local is not None and ex.intra_process:
            ex.local_subscriptions(resolved).append(local)
            is_local = ex.is_local

            def remote_only(data: bytes, gid: bytes) -> None:
                if not is_local(gid):
                    guarded(data, gid)

            deliver = remote_only
        else:
            deliver = guarded
        sub = self._node.create_subscription(ros_type(topic.type), topic.name, _ignore, to_qos_profile(topic.qos),
                                             raw=True)
        ex.add_subscription(sub, deliver, self)

    def subscribe(self, topic: Topic, callback: Callable[[Any], object]) -> None:
        decode = fastcdr.decoder(msgs.message_class(topic.type))
        what = f"subscription {self._resolve(topic)}"
        self._subscribe(topic, lambda data, gid: callback(decode(data)),
                        LocalSubscription(self, self._guard.wrap(what, callback), False))

    def subscribe_raw(self, topic: Topic, callback: RawCallback) -> None:
        """The serialized CDR as the middleware delivered it, no decode (what rosbag2 stores)."""
        what = f"subscription {self._resolve(topic)}"
        self._subscribe(topic, lambda data, gid: callback(data),
                        LocalSubscription(self, self._guard.wrap(what, callback), True))

    def subscribe_with_source(self, topic: Topic, callback: SourcedCallback) -> None:
        """``callback(msg, writer_gid)``: the GID rcl gives with each sample (intra-process: the
        publisher's own)."""
        decode = fastcdr.decoder(msgs.message_class(topic.type))
        what = f"subscription {self._resolve(topic)}"
        self._subscribe(topic, lambda data, gid: callback(decode(data), gid),
                        SourcedLocalSubscription(self, self._guard.wrap(what, lambda pair: callback(*pair)), False))

    def publisher_gids(self, topic: Topic, node: str) -> frozenset[bytes]:
        """GIDs of ``node``'s writers on ``topic`` from ``get_publishers_info_by_topic``."""
        fqn = node_fqn(node, self.namespace)
        return frozenset(gid16(i.endpoint_gid) for i in self._node.get_publishers_info_by_topic(self._resolve(topic))
                         if node_fqn(i.node_name, i.node_namespace) == fqn)

    def timer(self, period_s: float, callback: Callable[[], object]) -> LoopTimer:
        t = LoopTimer(period_s, self._guard.wrap(f"timer {period_s:g} s", callback), self)
        self._ex.add_timer(t)
        return t

    # -- services ----------------------------------------------------------------------
    def service(self, name: str, srv_type: str, callback: ServiceCallback) -> None:
        """Serve ``<node>/<name>`` with rclpy; an exception in ``callback`` answers ``success = False``."""
        what = f"service {self.fully_qualified_name.rstrip('/')}/{name.strip('/')}"
        guard = self._guard

        def handle(req: Any, rep: Any) -> Any:
            return guard.answer(what, callback, req, rep)

        self._node.create_service(ros_type(srv_type), "~/" + name.strip("/"), handle)

    def serve_lifecycle(self, machine: LifecycleMachine) -> None:
        """The managed-node services and ``~/transition_event`` with rclpy's lifecycle_msgs types, answered from
        ``machine``; ``~/change_state``'s response is sent when the transition ends.

        Not ``rclpy.lifecycle.LifecycleNode``: its ``~/change_state`` runs the transition callback to its end
        inside the service callback (rcl_lifecycle's machine has no transition that ends later), so a deactivate
        that waits for the board's LANDED would hold this executor, and with it the driver's command forwarding
        and timers, for the seconds of a landing; and its machine can only be moved by a callback's result,
        not by a fault outside one (:meth:`LifecycleMachine.error`). The services, names, types and answers are
        rcl_lifecycle's (the graph and labels are checked against rclpy.lifecycle's in tests/transport), so
        ``ros2 lifecycle`` cannot tell.
        """
        import lifecycle_msgs.msg as lm
        import lifecycle_msgs.srv as ls

        iface = LifecycleInterface(machine, State=lm.State, Transition=lm.Transition,
                                   TransitionDescription=lm.TransitionDescription,
                                   TransitionEvent=lm.TransitionEvent, log=self.logger.warn)
        topic = event_topic(self.fully_qualified_name)
        events = self._node.create_publisher(lm.TransitionEvent, topic.name, to_qos_profile(topic.qos))
        machine.listeners.append(lambda e: events.publish(iface.event(e)))
        types = {"get_state": ls.GetState, "change_state": ls.ChangeState,
                 "get_available_states": ls.GetAvailableStates, "get_available_transitions": ls.GetAvailableTransitions,
                 "get_transition_graph": ls.GetAvailableTransitions}
        for name, srv_type in types.items():
            if name == "change_state":
                srv = self._node.create_service(srv_type, "~/" + name, _ignore)
                self._deferred_services[srv] = iface.change_state
            else:
                self._node.create_service(srv_type, "~/" + name, getattr(iface, name))

    def serve_requests(self) -> None:
        """Answer the requests waiting at this node's services (rclpy's parameter services included); a
        deferred service's callback (``~/change_state``) gets a ``send()`` that answers its request later."""
        for srv in self._node.services:
            while True:
                try:
                    got = srv.handle.service_take_request(srv.srv_type.Request)
                except Exception:  # destroyed meanwhile
                    break
                if got is None or got[1] is None:
                    break
                request, header = got
                try:
                    response = srv.srv_type.Response()
                    later = self._deferred_services.get(srv)
                    if later is not None:
                        later(request, response, self._sender(srv, response, header))
                    else:
                        srv.send_response(srv.callback(request, response), header)
                except Exception as exc:
                    self._guard.failed(f"service {srv.srv_name}", exc)

    def _sender(self, srv: Any, response: Any, header: Any) -> Callable[[], None]:
        def send() -> None:
            if not self._destroyed:
                srv.send_response(response, header)

        return send

    @property
    def has_pending_replies(self) -> bool:
        return False

    def flush_replies(self) -> None:
        """rcl sends replies at once."""

    def now_ns(self) -> int:
        return time.time_ns()

    def msg(self, type_name: str) -> type:
        """The project's message class (the same on both transports)."""
        return msgs.message_class(type_name)

    # -- parameters ------------------------------------------------------------------
    def declare_parameters(self, group: str, on_change: OnChange | None = None) -> dict[str, Any]:
        if self._params is not None:
            raise TransportError(f"{self.fully_qualified_name}: parameters already declared "
                                 f"(group {self._params.group!r})")
        values = initial_parameters(group, self._ros_args, self.name, strict=not self._ignore_undeclared)
        for spec in SCHEMA.groups[group]:
            descriptor = pv.describe(spec, ParameterDescriptor, FloatingPointRange, IntegerRange)
            self._node.declare_parameter(spec.name, values[spec.name], descriptor, ignore_override=True)
        self._params = ParameterStore(group, values, on_change)
        # registered after declaring: rclpy runs on-set callbacks on declaration too
        self._node.add_on_set_parameters_callback(self._on_set)
        if hasattr(self._node, "add_pre_set_parameters_callback"):  # rclpy >= Iron (Jazzy): before the type check
            self._node.add_pre_set_parameters_callback(self._integers_as_doubles)
        return dict(values)

    @property
    def parameters(self) -> dict[str, Any]:
        return self._params.values if self._params is not None else {}

    def set_parameters(self, changes: Mapping[str, Any]) -> str | None:
        """Apply ``changes`` atomically through rclpy; ``None`` or the rejection reason."""
        from rclpy.parameter import Parameter

        result = self._node.set_parameters_atomically([Parameter(k, value=v) for k, v in changes.items()])
        return None if result.successful else str(result.reason)

    def _integers_as_doubles(self, params: list[Any]) -> list[Any]:
        """``ros2 param set /controller w 60`` sends an INTEGER: a double parameter takes it as 60.0.

        rclpy would reject it ("expected DOUBLE got INTEGER") before our on-set callback runs;
        the DDS transport accepts it the same way (the schema coerces int -> float).
        """
        from rclpy.parameter import Parameter

        store = self._params
        out = []
        for p in params:
            spec = store.specs.get(p.name) if store is not None else None
            if spec is not None and spec.type is float and p.type_ == Parameter.Type.INTEGER:
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            out.append(p)
        return out

    def _on_set(self, params: list[Any]) -> SetParametersResult:
        store = self._params
        assert store is not None
        mine = {p.name: p.value for p in params if p.name in store}
        if not mine:
            return SetParametersResult(successful=True)
        reason = store.set(mine, self.fully_qualified_name)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    # -- dispatch ----------------------------------------------------------------------
    def spin_once(self, timeout_s: float | None = 0.1) -> None:
        """Wait for data, a timer deadline or ``timeout_s``; then run what is ready (on this node's executor)."""
        if not self._shutdown:
            self._ex.spin_once(timeout_s)

    def spin(self) -> None:
        """Dispatch until :meth:`shutdown` (waits are bounded so signals are handled)."""
        while not self._shutdown:
            self._ex.spin_once(None)

    def shutdown(self) -> None:
        """Stop spinning, leave the executor, destroy the rclpy node (the context with the last one); idempotent."""
        if self._shutdown:
            return
        self._shutdown = True
        self._ex.wake()
        # entities go once no spin_once runs (deferred when called from a callback or a signal handler)
        self._ex.remove_node(self, self._destroy)

    def _destroy(self) -> None:
        if self._destroyed:
            return
        self._destroyed = True
        with contextlib.suppress(Exception):  # the context may be gone (shut down by the user's code)
            self._node.destroy_node()
        if self._ex.stopped:
            self._ex.close()

    @property
    def is_shutdown(self) -> bool:
        return self._shutdown
