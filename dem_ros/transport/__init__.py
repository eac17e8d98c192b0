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
    ``"rclpy"``  rclpy nodes (ROS 2 Jazzy sourced, or ``pip install -e '.[ros]'``) with the
                 project's messages, CDR codec and executor (:mod:`dem_ros.transport.rclpy`);
    ``"dds"``    Cyclone DDS from PyPI, wire-compatible with rmw_cyclonedds
                 (topics, services, ``ros_discovery_info``), no ROS install;
    ``"auto"``   rclpy if ``import rclpy`` works, else dds (docs/manual/transports.md: which
                 transport with which ROS 2 install).
    (:mod:`dem_ros.transport.memory`: one process, no middleware, a manual
    clock; for unit tests of node logic, made with ``MemoryBus().node(name)``.)

Messages: assign Python lists (``array.tolist()``) to sequence fields; the DDS
classes do not take numpy arrays. Environment for the dds transport:
``DEM_ROS_TRANSPORT`` (what ``auto`` means), ``ROS_DOMAIN_ID`` (0..101), ``DEM_ROS_DISTRO`` (jazzy | humble | iron, sets
the GID size and type hashes), ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (default
LOCALHOST), ``ROS_STATIC_PEERS``, ``CYCLONEDDS_URI``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any

from ..core.params import ConfigError
from .api import (
    SERVICE_TYPES,
    Logger,
    Node,
    OnChange,
    Publisher,
    RawCallback,
    ServiceCallback,
    Timer,
    TransportError,
)

__all__ = [
    "SERVICE_TYPES",
    "TRANSPORTS",
    "ConfigError",
    "Logger",
    "Node",
    "OnChange",
    "Publisher",
    "RawCallback",
    "ServiceCallback",
    "Timer",
    "TransportError",
    "deserialize",
    "make_node",
    "param_get",
    "param_list",
    "param_set",
    "rclpy_available",
    "run_node",
    "run_nodes",
    "serialize",
    "set_bool",
    "trigger",
]

TRANSPORTS = ("auto", "rclpy", "dds")
#: the GIL switch interval of node processes (Python's default is 5 ms)
SWITCH_INTERVAL_S = 1e-4


def rclpy_available() -> bool:
    """True when ``import rclpy`` works (a ROS 2 environment is sourced, or the ``ros`` extra is installed)."""
    try:
        import rclpy  # noqa: F401
    except Exception:
        return False
    return True


def _pick(transport: str) -> str:
    """``auto`` -> ``DEM_ROS_TRANSPORT`` if set (``dem-ros node --transport`` sets it), else rclpy if
    importable, else dds."""
    if transport not in TRANSPORTS:
        raise TransportError(f"transport {transport!r} is not one of {', '.join(TRANSPORTS)}")
    if transport == "auto":
        env = os.environ.get("DEM_ROS_TRANSPORT", "auto")
        if env not in TRANSPORTS:
            raise TransportError(f"DEM_ROS_TRANSPORT={env!r} is not one of {', '.join(TRANSPORTS)}")
        if env != "auto":
            return env
        return "rclpy" if rclpy_available() else "dds"
    return transport


def make_node(name: str, *, transport: str = "auto", args: Sequence[str] | None = None,
              executor: Any = None, composed: bool = False) -> Node:
    """Create node ``name`` on the chosen transport.

    Args:
        name: node name (``-r __node:=x`` in ``args`` overrides it).
        transport: ``"auto"``, ``"rclpy"`` or ``"dds"``.
        args: command-line arguments (default ``sys.argv[1:]``); the part after
            ``--ros-args`` is parsed as rcl does (``--params-file``, ``-p``, ``-r __node:=``, ``-r __ns:=``).
        executor: the transport's executor to share with other nodes of the process
            (see :func:`run_nodes`); by default the node has its own.
        composed: the node is one of several in this process: a global ``-p`` it
            does not declare is left to the others instead of being an error.

    Raises:
        TransportError: unknown transport, rclpy missing, bad ROS_DOMAIN_ID, DDS failure.
        ConfigError: bad ROS arguments or params file.
    """
    kind = _pick(transport)
    if args is None:  # like rclpy: the process's own command line
        args = sys.argv[1:]
    if kind == "rclpy":
        if not rclpy_available():
            raise TransportError("transport 'rclpy' needs rclpy (import rclpy failed): source a ROS 2 Jazzy, "
                                 "or pip install -e '.[ros]'; or use 'dds'")
        from .rclpy import RclpyNode

        return RclpyNode(name, list(args), executor=executor, ignore_undeclared=composed)  # type: ignore[return-value]
    from .dds.node import DdsNode

    return DdsNode(name, list(args), executor=executor, ignore_undeclared=composed)  # type: ignore[return-value]


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
    return run_nodes([(name, setup)], args=args, transport=transport, intra_process=False)


def _check_composable(args: Sequence[str], names: Sequence[str]) -> None:
    """Several nodes share the process's ROS arguments: refuse what cannot apply to all of them."""
    from ..core.params import SCHEMA
    from .rosargs import parse_ros_args

    ra = parse_ros_args(list(args))
    if ra.node_name:
        raise ConfigError(f"-r __node:={ra.node_name} would give all {len(names)} nodes of this process the same name")
    declared = {p.name for g in names if g in SCHEMA.groups for p in SCHEMA.groups[g]}
    unknown = sorted({n for node, n, _ in ra.params if node is None and n not in declared})
    if unknown:
        raise ConfigError(f"-p {', '.join(unknown)}: not a parameter of any node of this process ({', '.join(names)})")


def run_nodes(
    nodes: Sequence[tuple[str, Callable[[Node], Any]]],
    *,
    args: Sequence[str] | None = None,
    transport: str = "auto",
    intra_process: bool = True,
    stop_with: str | None = None,
    background: Sequence[str] = (),
) -> int:
    """Run several nodes in this process on one executor (a component container).

    Each ``(name, setup)`` gets its own node (own name, parameters and
    services) created with the process's ``args`` and set up in order; then one
    thread spins them all. With ``intra_process`` (the default), topics between these nodes
    are delivered in memory (see :mod:`dem_ros.transport.loop`; both transports) and reach the
    middleware only for remote subscribers. ``stop_with``: when that node
    shuts itself down (e.g. the plant at the end of its run), all do.
    ``background``: nodes whose callbacks run after all the others' in each round
    (the recorder: best-effort, never ahead of the loop's chain; see
    :meth:`~dem_ros.transport.loop.LoopExecutor.set_background`).
    Errors and signals are handled as in :func:`run_node`.
    """
    made: list[Node] = []
    previous: dict[signal.Signals, Any] = {}
    names = [n for n, _ in nodes]
    if args is None:
        args = sys.argv[1:]
    executor: Any = None

    def stop(signum: int, frame: Any) -> None:
        if not made:
            raise KeyboardInterrupt
        for n in made:
            n.shutdown()  # the spin returns within its bounded wait

    try:
        kind = _pick(transport)
        composed = len(nodes) > 1
        if composed:
            _check_composable(args, names)
        if kind == "dds" and (composed or intra_process):
            from .dds.executor import DdsExecutor
            from .dds.node import Participant

            executor = DdsExecutor(Participant.get(), intra_process=intra_process)
        elif kind == "rclpy":
            from .rclpy import RclpyExecutor

            executor = RclpyExecutor(list(args), intra_process=intra_process and composed)
        # SIGINT (what ros2 launch sends) and SIGTERM: every node shuts down, the spin returns, exit 0
        # (the rclpy context is initialised without rclpy's own signal handlers)
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread: the caller handles signals
                previous[sig] = signal.signal(sig, stop)
        for name, setup in nodes:
            node = make_node(name, transport=kind, args=args, executor=executor, composed=composed)
            made.append(node)
            if name in background and executor is not None:
                executor.set_background(node)
            try:
                setup(node)
            except Exception:
                if node.is_shutdown:
                    return 0  # stopped (Ctrl-C / SIGTERM) while setting up: not an error
                raise
            from ..runstate import announce

            announce("ready", name)  # set up (subscriptions made): to the launcher, not by log text
        # Set-up is done: freeze what it allocated (out of the collector's reach), then the
        # process's real-time settings (SCHED_FIFO, mlockall, timer slack; see dem_ros.realtime).
        from ..realtime import enter_loop

        enter_loop()
        # Helper threads (the bag writer) must hand the GIL back to the executor thread quickly:
        # with Python's default 5 ms switch interval a waking 1 kHz loop can wait 5 ms for it.
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        _spin(made, names.index(stop_with) if stop_with in names else None)
        return 0
    except (ConfigError, TransportError) as exc:
        sys.stderr.write(f"error: {'+'.join(names)}: {exc}\n")
        return 2
    except KeyboardInterrupt:
        return 0
    except Exception as exc:
        if type(exc).__name__ == "ExternalShutdownException":  # rclpy after Ctrl-C
            return 0
        raise
    finally:
        # the loop is over: the shutdown work (a bag to finalise) must not hold a CPU at real-time priority
        from ..realtime import leave_loop

        leave_loop()
        for n in made:
            with contextlib.suppress(Exception):
                n.shutdown()
        for sig, handler in previous.items():
            with contextlib.suppress(ValueError, TypeError):
                signal.signal(sig, handler)


def _spin(nodes: list[Node], stop_index: int | None) -> None:
    """Spin the nodes (one executor) until all are shut down, or the ``stop_index`` one is."""
    while True:
        live = [n for n in nodes if not n.is_shutdown]
        if not live or (stop_index is not None and nodes[stop_index].is_shutdown):
            return
        live[0].spin_once(0.2)  # bounded, so Python signal handlers run promptly


def serialize(msg: Any) -> bytes:
    """ROS 2 CDR bytes of ``msg`` including the 4-byte encapsulation header (what rosbag2 stores).

    Works for the DDS message classes and for rclpy messages.
    """
    if hasattr(msg, "__idl__"):
        from .dds.fastcdr import encoder

        enc = encoder(type(msg))
        return enc(msg) if enc is not None else bytes(msg.serialize())
    from rclpy.serialization import serialize_message

    return bytes(serialize_message(msg))


def deserialize(type_name: str, data: bytes, *, transport: str = "auto") -> Any:
    """Message of ROS type ``type_name`` from CDR bytes (with encapsulation header): an instance of
    the project's message class, which node code gets on every transport (``transport`` is checked,
    nothing more)."""
    _pick(transport)
    from .dds.fastcdr import decoder
    from .dds.msgs import message_class

    return decoder(message_class(type_name))(bytes(data))


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


def trigger(node_name: str, service: str, *, domain_id: int | None = None, timeout_s: float = 2.0) -> tuple[bool, str]:
    """Call the ``std_srvs/srv/Trigger`` service ``<node>/<service>`` over DDS: (success, message).

    TransportError when the node cannot be reached within ``timeout_s``.
    """
    from .dds.client import trigger as _trigger

    return _trigger(node_name, service, domain_id=domain_id, timeout_s=timeout_s)


def set_bool(node_name: str, service: str, value: bool, *, domain_id: int | None = None,
             timeout_s: float = 2.0) -> tuple[bool, str]:
    """Call the ``std_srvs/srv/SetBool`` service ``<node>/<service>`` over DDS: (success, message)."""
    from .dds.client import set_bool as _set_bool

    return _set_bool(node_name, service, value, domain_id=domain_id, timeout_s=timeout_s)
