"""The node interface of dem_ros and its two implementations.

Node logic is written once against :class:`~dem_ros.transport.api.Node`::

    from dem_ros import contract
    from dem_ros.transport import make_node, run_node

    def setup(node):
        params = node.declare_parameters("controller", on_change=lambda v: None)
        pub = node.publisher(contract.COMMAND)
        JointState = node.msg("sensor_msgs/msg/JointState")
        node.subscribe(contract.ESTIMATE, lambda m: ...)
        node.timer(params["dt"], lambda: pub.publish(JointState(...)))

    def main(args=None):
        return run_node("controller", setup, args=args)

Transports:
    ``"rclpy"``  thin wrapper over rclpy (needs a sourced ROS 2 Humble/Jazzy);
    ``"dds"``    Cyclone DDS from PyPI, wire-compatible with rmw_cyclonedds
                 (topics, services, ``ros_discovery_info``), no ROS install;
    ``"auto"``   rclpy if ``import rclpy`` works, else dds.

Messages: assign Python lists (``array.tolist()``) to sequence fields; the DDS
classes do not take numpy arrays. Environment for the dds transport:
``ROS_DOMAIN_ID`` (0..101), ``DEM_ROS_DISTRO`` (jazzy | humble | iron, sets the
GID size and type hashes), ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (default
LOCALHOST), ``ROS_STATIC_PEERS``, ``CYCLONEDDS_URI``.
"""

from __future__ import annotations

import gc
import signal
import sys
from typing import Any, Callable, Sequence

from ..core.params import ConfigError
from .api import Logger, Node, OnChange, Publisher, RawCallback, TransportError

__all__ = [
    "Node",
    "Publisher",
    "Logger",
    "OnChange",
    "RawCallback",
    "TransportError",
    "ConfigError",
    "TRANSPORTS",
    "rclpy_available",
    "make_node",
    "run_node",
    "serialize",
    "deserialize",
    "param_set",
    "param_get",
    "param_list",
]

TRANSPORTS = ("auto", "rclpy", "dds")


def rclpy_available() -> bool:
    """True when ``import rclpy`` works (a ROS 2 environment is sourced)."""
    try:
        import rclpy  # noqa: F401
    except Exception:
        return False
    return True


def _pick(transport: str) -> str:
    if transport not in TRANSPORTS:
        raise TransportError(f"transport {transport!r} is not one of {', '.join(TRANSPORTS)}")
    if transport == "auto":
        return "rclpy" if rclpy_available() else "dds"
    return transport


def make_node(name: str, *, transport: str = "auto", args: Sequence[str] | None = None) -> Node:
    """Create node ``name`` on the chosen transport.

    Args:
        name: node name (``-r __node:=x`` in ``args`` overrides it).
        transport: ``"auto"``, ``"rclpy"`` or ``"dds"``.
        args: command-line arguments (default ``sys.argv[1:]``); the part after
            ``--ros-args`` is parsed as rcl does (``--params-file``, ``-p``, ``-r __node:=``, ``-r __ns:=``).

    Raises:
        TransportError: unknown transport, rclpy missing, bad ROS_DOMAIN_ID, DDS failure.
        ConfigError: bad ROS arguments or params file.
    """
    kind = _pick(transport)
    if args is None:  # like rclpy: the process's own command line
        args = sys.argv[1:]
    if kind == "rclpy":
        if not rclpy_available():
            raise TransportError("transport 'rclpy' needs a sourced ROS 2 (import rclpy failed); use 'dds'")
        from .rclpy_node import RclpyNode

        return RclpyNode(name, list(args) if args is not None else None)  # type: ignore[return-value]
    from .dds.node import DdsNode

    return DdsNode(name, list(args) if args is not None else None)  # type: ignore[return-value]


def run_node(
    name: str,
    setup: Callable[[Node], Any],
    *,
    args: Sequence[str] | None = None,
    transport: str = "auto",
) -> int:
    """Create a node, call ``setup(node)``, spin until SIGINT/SIGTERM, shut down cleanly.

    Configuration and middleware errors print one ``error: ...`` line and give
    exit code 2 (no traceback); Ctrl-C gives 0. Use as ``sys.exit(run_node(...))``
    or return it from ``main()``.
    """
    node: Node | None = None
    previous: dict[int, Any] = {}

    def stop(signum: int, frame: Any) -> None:
        if node is not None:
            node.shutdown()  # spin() returns within its bounded wait
        else:
            raise KeyboardInterrupt

    try:
        node = make_node(name, transport=transport, args=args)
        # rclpy handles SIGINT itself (shuts its context down); we add SIGTERM
        sigs = (signal.SIGTERM,) if node.transport == "rclpy" else (signal.SIGINT, signal.SIGTERM)
        for sig in sigs:
            try:
                previous[sig] = signal.signal(sig, stop)
            except ValueError:  # not the main thread: the caller handles signals
                pass
        try:
            setup(node)
        except Exception:
            if getattr(node, "is_shutdown", False) or getattr(node, "_node", True) is None:
                return 0  # stopped (Ctrl-C / SIGTERM) while setting up: not an error
            raise
        # Everything allocated so far (numba, the middleware, the node) lives for the whole run:
        # move it out of the collector's reach. A full collection over it takes ~100 ms, which a
        # 1 kHz loop cannot absorb; afterwards collections only scan what the loop allocates.
        gc.collect()
        gc.freeze()
        node.spin()
        return 0
    except (ConfigError, TransportError) as exc:
        sys.stderr.write(f"error: {name}: {exc}\n")
        return 2
    except KeyboardInterrupt:
        return 0
    except Exception as exc:
        if type(exc).__name__ == "ExternalShutdownException":  # rclpy after Ctrl-C
            return 0
        raise
    finally:
        if node is not None:
            try:
                node.shutdown()
            except Exception:
                pass
        for sig, handler in previous.items():
            try:
                signal.signal(sig, handler)
            except (ValueError, TypeError):
                pass


def serialize(msg: Any) -> bytes:
    """ROS 2 CDR bytes of ``msg`` including the 4-byte encapsulation header (what rosbag2 stores).

    Works for the DDS message classes and for rclpy messages.
    """
    if hasattr(msg, "__idl__"):
        from .dds.fastcdr import ENCODERS

        enc = ENCODERS.get(type(msg))
        return enc(msg) if enc is not None else bytes(msg.serialize())
    from rclpy.serialization import serialize_message

    return bytes(serialize_message(msg))


def deserialize(type_name: str, data: bytes, *, transport: str = "auto") -> Any:
    """Message of ROS type ``type_name`` from CDR bytes (with encapsulation header)."""
    if _pick(transport) == "rclpy":
        from rclpy.serialization import deserialize_message
        from rosidl_runtime_py.utilities import get_message

        return deserialize_message(bytes(data), get_message(type_name))
    from .dds.fastcdr import DECODERS
    from .dds.msgs import message_class

    cls = message_class(type_name)
    return DECODERS.get(cls, cls.deserialize)(bytes(data))


def param_set(node_name: str, name: str, value: Any, *, domain_id: int | None = None,
              timeout_s: float = 2.0) -> tuple[bool, str]:
    """Set parameter ``name`` of node ``node_name`` over the DDS parameter services.

    Returns ``(True, "")`` or ``(False, reason)`` (the node's rejection reason,
    or why it could not be reached). ``value`` may be a Python value or a
    YAML string (``"60"``, ``"true"``).
    """
    from .dds.client import param_set as _set

    return _set(node_name, name, value, domain_id=domain_id, timeout_s=timeout_s)


def param_get(node_name: str, name: str, *, domain_id: int | None = None, timeout_s: float = 2.0) -> Any:
    """Value of parameter ``name`` of ``node_name``; TransportError if unreachable or unknown."""
    from .dds.client import param_get as _get

    return _get(node_name, name, domain_id=domain_id, timeout_s=timeout_s)


def param_list(node_name: str, *, domain_id: int | None = None, timeout_s: float = 2.0) -> list[str]:
    """Parameter names of ``node_name``."""
    from .dds.client import param_list as _list

    return _list(node_name, domain_id=domain_id, timeout_s=timeout_s)
