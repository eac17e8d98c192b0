"""The rclpy implementation of the dem_ros node interface (ROS 2 Humble and Jazzy).

A thin wrapper: rclpy publishers/subscriptions/timers with the contract QoS,
parameters declared from the schema with a ParameterDescriptor (description,
FloatingPointRange/IntegerRange, read_only), and one
``add_on_set_parameters_callback`` that validates every change against the
whole group (``SCHEMA.merged``) and then asks the node's ``on_change``.
rclpy itself serves the parameter services, publishes ``/parameter_events``
and ``/rosout``, and parses ``--ros-args`` (remaps, params files).

Start values are computed by :func:`dem_ros.transport.rosargs.initial_parameters`
(the same code as the DDS transport) and declared with ``ignore_override=True``,
so a bad params file fails with the ConfigError message in both transports.

Sources: rclpy (Jazzy) hands a subscription callback a ``MessageInfo`` with time stamps and
sequence numbers but no publisher GID, so :meth:`RclpyNode.subscribe_with_source` can only attribute
a sample when exactly one writer is matched (``get_publisher_count``) and the graph
(``get_publishers_info_by_topic``, re-read when that count changes and at least every
``_GRAPH_REFRESH_NS``) lists exactly one: then its GID, otherwise ``b""`` (a source lock drops it).

Only importable where ``import rclpy`` works.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosidl_runtime_py.utilities import get_message

from ..contract import QoS, Topic
from ..core.params import SCHEMA
from . import paramvalue as pv
from .api import CallbackGuard, OnChange, RawCallback, ServiceCallback, SourcedCallback, TransportError, gid16, node_fqn
from .parameters import ParameterStore
from .rosargs import initial_parameters, parse_ros_args

__all__ = ["RclpyNode", "RclpyPublisher", "to_qos_profile"]

#: a sourced subscription re-reads the topic's writers at least this often (ns)
_GRAPH_REFRESH_NS = 100_000_000


def to_qos_profile(q: QoS) -> QoSProfile:
    """contract.QoS -> rclpy QoSProfile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=q.depth,
        reliability=ReliabilityPolicy.RELIABLE if q.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if q.transient_local else DurabilityPolicy.VOLATILE,
    )


class _Logger:
    def __init__(self, logger: Any):
        self._l = logger

    def info(self, msg: str) -> None:
        self._l.info(msg)

    def warn(self, msg: str) -> None:
        self._l.warning(msg)

    warning = warn

    def error(self, msg: str) -> None:
        self._l.error(msg)


class RclpyPublisher:
    """An rclpy publisher seen through the :class:`~dem_ros.transport.api.Publisher` Protocol."""

    def __init__(self, pub: Any):
        self._pub = pub

    def publish(self, msg: Any) -> None:
        self._pub.publish(msg)

    def publish_raw(self, data: bytes) -> None:
        """rclpy publishes serialized bytes as they are."""
        self._pub.publish(bytes(data))

    @property
    def subscription_count(self) -> int:
        return int(self._pub.get_subscription_count())


def shared_executor(args: list[str] | None = None) -> Any:
    """One SingleThreadedExecutor for several nodes of this process (rclpy initialised here)."""
    if not rclpy.ok():
        try:
            rclpy.init(args=[sys.argv[0] if sys.argv else "dem_ros", *(args or [])])
        except Exception as exc:
            raise TransportError(f"rclpy.init failed: {exc}") from None
    return SingleThreadedExecutor()


class RclpyNode:
    """A dem_ros node backed by ``rclpy.node.Node`` and a SingleThreadedExecutor."""

    transport = "rclpy"

    def __init__(self, name: str, args: list[str] | None = None, *, executor: Any = None,
                 ignore_undeclared: bool = False):
        argv = list(args) if args is not None else []
        self._ignore_undeclared = ignore_undeclared
        self._ros_args = parse_ros_args(argv)  # ConfigError on bad --ros-args / missing file
        self._owns_context = not rclpy.ok()
        if self._owns_context:
            try:
                rclpy.init(args=[sys.argv[0] if sys.argv else "dem_ros", *argv])
            except Exception as exc:  # rclpy's RCLError on arguments rcl cannot parse
                raise TransportError(f"rclpy.init failed: {exc}") from None
        self._node = rclpy.create_node(name)
        self.name = self._node.get_name()
        self.namespace = self._node.get_namespace()
        self.logger = _Logger(self._node.get_logger())
        self._executor = executor if executor is not None else SingleThreadedExecutor()
        self._executor.add_node(self._node)
        self._shutdown = False
        self._params: ParameterStore | None = None
        self._guard = CallbackGuard(lambda: self.logger)

    @property
    def fully_qualified_name(self) -> str:
        return str(self._node.get_fully_qualified_name())

    @property
    def ros_node(self) -> Any:
        """The underlying ``rclpy.node.Node`` (escape hatch; keep node logic transport-neutral)."""
        return self._node

    @property
    def intra_process(self) -> bool:
        """rclpy delivers through the middleware, serialised, even within one process."""
        return False

    @property
    def callback_errors(self) -> dict[str, int]:
        """Exceptions raised by this node's callbacks so far, per callback name (a copy)."""
        return dict(self._guard.errors)

    def publisher(self, topic: Topic) -> RclpyPublisher:
        return RclpyPublisher(self._node.create_publisher(get_message(topic.type), topic.name, to_qos_profile(topic.qos.for_writer())))

    def subscribe(self, topic: Topic, callback: Callable[[Any], object]) -> None:
        self._node.create_subscription(get_message(topic.type), topic.name,
                                       self._guard.wrap(f"subscription {topic.name}", callback),
                                       to_qos_profile(topic.qos))

    def subscribe_raw(self, topic: Topic, callback: RawCallback) -> None:
        """rclpy hands over the serialized CDR (``raw=True``), no decode."""
        self._node.create_subscription(
            get_message(topic.type), topic.name, self._guard.wrap(f"subscription {topic.name}", callback),
            to_qos_profile(topic.qos), raw=True
        )

    def subscribe_with_source(self, topic: Topic, callback: SourcedCallback) -> None:
        """``callback(msg, gid)``: the GID only while one writer is matched and the graph lists one
        (rclpy's MessageInfo carries no publisher GID), else ``b""`` (tests/transport/test_rclpy_node.py, run on Jazzy)."""
        node = self._node
        state: dict[str, Any] = {"count": -1, "gid": b"", "next": 0}
        box: list[Any] = []

        def source() -> bytes:
            count = box[0].get_publisher_count()
            now = time.monotonic_ns()
            if count != state["count"] or now >= state["next"]:
                infos = node.get_publishers_info_by_topic(box[0].topic_name)
                state.update(count=count, next=now + _GRAPH_REFRESH_NS,
                             gid=gid16(infos[0].endpoint_gid) if len(infos) == 1 else b"")
            return state["gid"] if count == 1 else b""

        box.append(node.create_subscription(
            get_message(topic.type), topic.name,
            self._guard.wrap(f"subscription {topic.name}", lambda msg: callback(msg, source())),
            to_qos_profile(topic.qos)))

    def publisher_gids(self, topic: Topic, node: str) -> frozenset[bytes]:
        """GIDs of ``node``'s writers on ``topic`` from ``get_publishers_info_by_topic``."""
        fqn = node_fqn(node, self.namespace)
        name = self._node.resolve_topic_name(topic.name)
        return frozenset(gid16(i.endpoint_gid) for i in self._node.get_publishers_info_by_topic(name)
                         if node_fqn(i.node_name, i.node_namespace) == fqn)

    def timer(self, period_s: float, callback: Callable[[], object]) -> Any:
        return self._node.create_timer(period_s, self._guard.wrap(f"timer {period_s:g} s", callback))

    def service(self, name: str, srv_type: str, callback: ServiceCallback) -> None:
        """Serve ``<node>/<name>`` with rclpy; an exception in ``callback`` answers ``success = False``."""
        from rosidl_runtime_py.utilities import get_service

        what = f"service {self.fully_qualified_name.rstrip('/')}/{name.strip('/')}"
        guard = self._guard

        def handle(req: Any, rep: Any) -> Any:
            return guard.answer(what, callback, req, rep)

        self._node.create_service(get_service(srv_type), "~/" + name.strip("/"), handle)

    def now_ns(self) -> int:
        return int(self._node.get_clock().now().nanoseconds)

    def msg(self, type_name: str) -> type:
        cls: type = get_message(type_name)
        return cls

    # -- parameters ------------------------------------------------------------------
    def declare_parameters(self, group: str, on_change: OnChange | None = None) -> dict[str, Any]:
        if self._params is not None:
            raise TransportError(f"{self.fully_qualified_name}: parameters already declared (group {self._params.group!r})")
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
        try:
            self._executor.spin_once(timeout_sec=timeout_s)
        except ExternalShutdownException:
            self._shutdown = True

    def spin(self) -> None:
        """Spin in bounded steps so Python signal handlers (SIGTERM) run promptly."""
        while not self._shutdown and rclpy.ok():
            self.spin_once(0.2)

    def shutdown(self) -> None:
        if self._shutdown and self._node is None:
            return
        self._shutdown = True
        node = self._node
        try:
            self._executor.remove_node(node)
            node.destroy_node()
        except Exception:
            pass
        if self._owns_context:
            try:
                rclpy.try_shutdown()
            except AttributeError:  # very old rclpy
                if rclpy.ok():
                    rclpy.shutdown()
            except Exception:
                pass
        self._node = None

    @property
    def is_shutdown(self) -> bool:
        return self._shutdown
