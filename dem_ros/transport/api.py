"""The node interface dem_ros nodes are written against.

Two implementations honour it: :mod:`dem_ros.transport.dds` (Cyclone DDS,
no ROS install) and :mod:`dem_ros.transport.rclpy_node` (a thin rclpy
wrapper). Node logic only uses what is declared here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol, runtime_checkable

from ..contract import Topic

__all__ = [
    "Logger",
    "Node",
    "OnChange",
    "Publisher",
    "RawCallback",
    "TransportError",
]


class TransportError(RuntimeError):
    """The middleware cannot be set up or used as asked; the message says why."""


#: ``on_change(new_values) -> None | reason``; a string rejects the change.
OnChange = Callable[[Mapping[str, Any]], "str | None"]
#: ``callback(data)``: serialized CDR bytes including the 4-byte encapsulation header.
RawCallback = Callable[[bytes], None]


@runtime_checkable
class Publisher(Protocol):
    def publish(self, msg: Any) -> None:
        """Send one message (an instance of ``node.msg(topic.type)``)."""


@runtime_checkable
class Logger(Protocol):
    def info(self, msg: str) -> None: ...
    def warn(self, msg: str) -> None: ...
    def error(self, msg: str) -> None: ...


@runtime_checkable
class Node(Protocol):
    """A ROS 2 node: topics, timers, parameters, time and logging.

    Callbacks and timers run on the thread that calls :meth:`spin` /
    :meth:`spin_once`, one at a time (like rclpy's SingleThreadedExecutor).
    """

    name: str
    namespace: str
    logger: Logger
    transport: str  # "dds" or "rclpy"

    @property
    def fully_qualified_name(self) -> str:
        """``/namespace/name``."""

    def publisher(self, topic: Topic) -> Publisher:
        """Publisher with the topic's contract QoS."""

    def subscribe(self, topic: Topic, callback: Callable[[Any], None]) -> None:
        """Call ``callback(msg)`` for every message on ``topic``."""

    def subscribe_raw(self, topic: Topic, callback: RawCallback) -> None:
        """Call ``callback(cdr_bytes)`` (encapsulation header included, what rosbag2 stores)."""

    def timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """Call ``callback()`` every ``period_s`` seconds."""

    def now_ns(self) -> int:
        """ROS time (= system clock) in nanoseconds since the Unix epoch."""

    def declare_parameters(self, group: str, on_change: OnChange | None = None) -> dict[str, Any]:
        """Declare ``SCHEMA.groups[group]`` as ROS parameters; return the validated start values."""

    def msg(self, type_name: str) -> type:
        """The message class for ``pkg/msg/Name``."""

    def spin(self) -> None:
        """Dispatch callbacks until :meth:`shutdown`."""

    def spin_once(self, timeout_s: float = 0.1) -> None:
        """Dispatch what is ready, waiting at most ``timeout_s`` for something to arrive."""

    def shutdown(self) -> None:
        """Stop spinning and release the middleware; idempotent."""
