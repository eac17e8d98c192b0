"""The node interface dem_ros nodes are written against.

Three implementations honour it: :mod:`dem_ros.transport.dds` (Cyclone DDS,
no ROS install), :mod:`dem_ros.transport.rclpy` (rclpy nodes)
and :mod:`dem_ros.transport.memory` (one process, no middleware: node logic
under test). Node logic only uses what is declared here; if a node needs to
look behind these Protocols, the Protocol is missing a member.

Callbacks (subscriptions, timers, services) never end the process: an
exception is caught per callback by a :class:`CallbackGuard`, counted under
the callback's name (``subscription /dem/command``, ``timer 0.001 s``,
``service /controller/arm``), and logged once per name with its traceback.
Nodes report the counts (:attr:`Node.callback_errors`) on /diagnostics.

Sources. Every transport tells which writer sent a sample (:meth:`Node.subscribe_with_source`) and which
writers the ROS graph attributes to a named node on a topic (:meth:`Node.publisher_gids`), as GIDs: the
16-byte DDS GUID of the writer (participant prefix + entity id; what ``ros2 topic info -v`` prints as
the "Endpoint GID", without the zero padding of 24-byte GIDs before Jazzy; :func:`gid16`). On the dds
transport they come from the sample's ``publication_handle`` and from the DCPSPublication built-in
topic joined with ``ros_discovery_info``; on the memory transport from the bus's publishers. Without
DDS-Security (the PyPI cyclonedds wheel has none) a GID is not authenticated: any process on the
domain can claim one. A lock on GIDs separates this graph's writers from strays (a second controller,
a test publisher, a replayed bag), it does not stop a forger.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from ..contract import Topic

if TYPE_CHECKING:
    from .lifecycle import LifecycleMachine

__all__ = [
    "GID_SIZE",
    "SERVICE_TYPES",
    "Callback",
    "CallbackGuard",
    "Logger",
    "Node",
    "OnChange",
    "Publisher",
    "RawCallback",
    "ServiceCallback",
    "SourcedCallback",
    "Timer",
    "TransportError",
    "gid16",
    "node_fqn",
]

#: the ROS service types every transport serves and calls (request fields -> response fields):
#: ``std_srvs/srv/Trigger`` () -> (success: bool, message: str);
#: ``std_srvs/srv/SetBool`` (data: bool) -> (success: bool, message: str).
SERVICE_TYPES = ("std_srvs/srv/Trigger", "std_srvs/srv/SetBool")


class TransportError(RuntimeError):
    """The middleware cannot be set up or used as asked; the message says why."""


#: ``on_change(new_values) -> None | reason``; a string rejects the change.
OnChange = Callable[[Mapping[str, Any]], "str | None"]
#: ``callback(data)``: serialized CDR bytes including the 4-byte encapsulation header (return value ignored).
RawCallback = Callable[[bytes], object]
#: ``callback(msg)`` (return value ignored)
Callback = Callable[[Any], object]
#: ``callback(msg, writer_gid)``: a message and the :data:`GID_SIZE`-byte GID of the writer that sent it
#: (``b""`` when the transport cannot tell: then no writer lock can accept it)
SourcedCallback = Callable[[Any, bytes], object]
#: bytes of a GID as dem_ros compares them: the DDS GUID (12-byte participant prefix + 4-byte entity id)
GID_SIZE = 16


def gid16(gid: Any) -> bytes:
    """A GID as :data:`GID_SIZE` bytes: the DDS GUID of a ROS GID of any distro (24 bytes zero-padded
    before Jazzy, 16 since), of an ``rmw_gid_t``-like sequence of ints, or of bytes."""
    return bytes(bytearray(gid)[:GID_SIZE])


def node_fqn(name: str, namespace: str) -> str:
    """The fully qualified name of node ``name`` seen from a node in ``namespace``: ``/ns/name`` as
    given, a relative name joins the namespace (as ROS resolves names)."""
    if name.startswith("/"):
        return name
    return namespace.rstrip("/") + "/" + name


#: ``callback(request, response) -> response`` (as rclpy): fill ``response`` and return it.
ServiceCallback = Callable[[Any, Any], Any]


@runtime_checkable
class Publisher(Protocol):
    def publish(self, msg: Any) -> None:
        """Send one message (an instance of ``node.msg(topic.type)``)."""

    def publish_raw(self, data: bytes) -> None:
        """Send serialized CDR (encapsulation header included), e.g. a sample read from a bag."""

    @property
    def subscription_count(self) -> int:
        """Subscriptions matched to this publisher now (remote and in-process)."""


@runtime_checkable
class Timer(Protocol):
    def cancel(self) -> None:
        """Stop calling the callback."""


@runtime_checkable
class Logger(Protocol):
    def info(self, msg: str) -> None: ...
    def warn(self, msg: str) -> None: ...
    def error(self, msg: str) -> None: ...


@runtime_checkable
class Node(Protocol):
    """A ROS 2 node: topics, timers, services, parameters, time and logging.

    Callbacks and timers run on the thread that calls :meth:`spin` /
    :meth:`spin_once`, one at a time (like rclpy's SingleThreadedExecutor).
    """

    name: str
    namespace: str
    logger: Logger
    transport: str  # "dds", "rclpy" or "memory"

    @property
    def fully_qualified_name(self) -> str:
        """``/namespace/name``."""

    @property
    def intra_process(self) -> bool:
        """True when messages between the nodes of this process are handed over as objects
        (no serialisation); a subscriber then must not modify what it receives."""

    @property
    def is_shutdown(self) -> bool:
        """True once :meth:`shutdown` ran (or the middleware shut the node down)."""

    @property
    def callback_errors(self) -> Mapping[str, int]:
        """Exceptions raised by this node's callbacks so far, per callback name."""

    def publisher(self, topic: Topic) -> Publisher:
        """Publisher with the topic's contract QoS."""

    def subscribe(self, topic: Topic, callback: Callback) -> None:
        """Call ``callback(msg)`` for every message on ``topic``."""

    def subscribe_raw(self, topic: Topic, callback: RawCallback) -> None:
        """Call ``callback(cdr_bytes)`` (encapsulation header included, what rosbag2 stores)."""

    def subscribe_with_source(self, topic: Topic, callback: SourcedCallback) -> None:
        """Call ``callback(msg, writer_gid)`` for every message on ``topic``: the message and the
        GID (:func:`gid16`) of the writer that sent it, also for a publisher of the same process."""

    def publisher_gids(self, topic: Topic, node: str) -> frozenset[bytes]:
        """The GIDs (:func:`gid16`) of the writers on ``topic`` (remapped as this node's) that the ROS
        graph attributes to the node ``node`` (``/ns/name``, or a name relative to this node's
        namespace, :func:`node_fqn`), as discovered now; empty while none is known."""

    def timer(self, period_s: float, callback: Callable[[], object]) -> Timer:
        """Call ``callback()`` every ``period_s`` seconds."""

    def service(self, name: str, srv_type: str, callback: ServiceCallback) -> None:
        """Serve ``name`` (relative to the node, e.g. ``"arm"`` -> ``/ns/node/arm``) of type
        ``srv_type`` (one of :data:`SERVICE_TYPES`); ``callback(request, response) -> response``."""

    def serve_lifecycle(self, machine: LifecycleMachine) -> None:
        """Serve ``machine`` as the standard managed-node interface that ``ros2 lifecycle`` reaches (rcl_lifecycle's
        names and lifecycle_msgs types, :class:`~.lifecycle.LifecycleInterface`): ``~/get_state``,
        ``~/change_state`` (answered when the transition ends: later for a DEFERRED one, the executor running
        meanwhile), ``~/get_available_states``, ``~/get_available_transitions``, ``~/get_transition_graph``, and
        each step on ``~/transition_event``. Once per node."""

    def now_ns(self) -> int:
        """ROS time (= system clock) in nanoseconds since the Unix epoch."""

    def declare_parameters(self, group: str, on_change: OnChange | None = None) -> dict[str, Any]:
        """Declare ``SCHEMA.groups[group]`` as ROS parameters; return the validated start values."""

    @property
    def parameters(self) -> dict[str, Any]:
        """Current parameter values (a copy)."""

    def set_parameters(self, changes: Mapping[str, Any]) -> str | None:
        """Apply ``changes`` atomically, as an external client would; ``None`` or the rejection reason."""

    def msg(self, type_name: str) -> type:
        """The message class for ``pkg/msg/Name``."""

    def spin(self) -> None:
        """Dispatch callbacks until :meth:`shutdown`."""

    def spin_once(self, timeout_s: float = 0.1) -> None:
        """Dispatch what is ready, waiting at most ``timeout_s`` for something to arrive."""

    def shutdown(self) -> None:
        """Stop spinning and release the middleware; idempotent."""


class CallbackGuard:
    """Runs a node's callbacks so that an exception in one never ends the process.

    :meth:`wrap` returns the callback guarded: an exception is caught, counted
    in :attr:`errors` under ``what`` and logged (with its traceback) the first
    time for that ``what`` only, so a callback failing at 1 kHz cannot flood the
    log. ``KeyboardInterrupt`` and ``SystemExit`` pass through.
    """

    def __init__(self, logger: Callable[[], Logger | None]):
        self._logger = logger
        self.errors: dict[str, int] = {}

    def failed(self, what: str, exc: BaseException) -> None:
        """Count (and, the first time for ``what``, log) an exception raised by callback ``what``."""
        n = self.errors.get(what, 0) + 1
        self.errors[what] = n
        if n == 1:
            log = self._logger()
            text = (f"callback for {what} raised {type(exc).__name__}: {exc} (the node keeps running; "
                    f"further errors of this callback are counted, not logged)\n"
                    + "".join(traceback.format_exception(exc)).rstrip())
            if log is not None:
                log.error(text)

    def wrap(self, what: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        failed = self.failed

        def guarded(*args: Any) -> Any:
            try:
                return fn(*args)
            except Exception as exc:
                failed(what, exc)
                return None

        guarded.__wrapped__ = fn  # type: ignore[attr-defined]
        return guarded

    def answer(self, what: str, callback: Callable[[Any, Any], Any], req: Any, rep: Any) -> Any:
        """Run a Trigger/SetBool service ``callback(req, rep)`` and return the response to send.

        An exception answers ``success = False`` with the exception as the message (counted and
        logged once like any callback error); a callback that returns None answers ``rep``.
        """
        try:
            out = callback(req, rep)
        except Exception as exc:
            self.failed(what, exc)
            rep.success = False
            rep.message = f"{type(exc).__name__}: {exc}"
            return rep
        return rep if out is None else out
