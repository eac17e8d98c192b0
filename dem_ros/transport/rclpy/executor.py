"""The rclpy transport's executor: the shared executor core on one rcl wait set.

:class:`RclpyExecutor` is :class:`~dem_ros.transport.loop.LoopExecutor` (rate-monotonic timers,
intra-process delivery inside a container, background nodes) waiting on an rcl wait set made
with rclpy's low-level API (``_rclpy.WaitSet``) that holds every subscription of its nodes
and one guard condition (:meth:`wake`). It takes each ready subscription's samples serialized,
with their writer's GID (:mod:`.take`), and hands them to the node's handler, which decodes
them with the project's CDR codec. rclpy's ``SingleThreadedExecutor`` is not used: its
per-wait rebuild of every entity and its coroutine tasks cost milliseconds per round here.

Services (the parameter services rclpy serves for each node, the type description service,
the nodes' Trigger/SetBool services) are not in the wait set: their requests are taken every
:data:`SERVICE_POLL_NS` at the end of a round and answered on the executor's thread, so a
``ros2 param set`` is answered within that period plus one round, and the 1 kHz rounds do
not re-add tens of service handles to the wait set.

Inside a container (``intra_process``) the rcl endpoints are ordinary ones (rclpy cannot ask
for ``ignore_local_publications``): a publisher writes to the middleware only while a
subscriber outside the container is matched, and a subscription of the container drops the
samples of the container's publishers (by their GIDs), which it already got through the
executor's queue; rclpy's own writers of the process (``/parameter_events``, ``/rosout``) come
through rcl as from any other process.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions

from ..api import TransportError
from ..loop import LoopExecutor, Member
from .take import SerializedTake

__all__ = ["SERVICE_POLL_NS", "RclpyExecutor", "fastdds_transport", "init_context"]

#: how often the executor takes service requests (ns)
SERVICE_POLL_NS = 10_000_000
#: variables by which a user configures Fast DDS (then :func:`fastdds_transport` leaves it alone)
_FASTDDS_CONFIG = ("FASTDDS_BUILTIN_TRANSPORTS", "FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE",
                   "RMW_FASTRTPS_USE_QOS_FROM_XML")


def fastdds_transport(env: dict[str, str] | os._Environ[str] = os.environ) -> None:
    """Fast DDS on UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``) unless the user configures Fast DDS
    (that variable, a profiles file) or picks another RMW.

    Fast DDS's default shared-memory transport gave the 1 kHz chain between processes tails of 50-125 ms;
    over UDP, with the real-time settings, the same 3-process chain held p99 < 1 ms (docs/manual/transports.md).
    With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (what ``dem-ros launch`` sets by default) rmw_fastrtps
    configures the transports itself (UDP on 127.0.0.1 and shared memory) and this variable has no effect.
    """
    rmw = env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if rmw != "rmw_fastrtps_cpp" or any(k in env for k in _FASTDDS_CONFIG):
        return
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"


def init_context(args: list[str] | None = None) -> bool:
    """Initialise rclpy's default context (if not yet) without its signal handlers: SIGINT and
    SIGTERM stay Python's (``run_nodes`` shuts the nodes down cleanly on them). True when this
    call initialised it."""
    if rclpy.ok():
        return False
    fastdds_transport()
    try:
        rclpy.init(args=[sys.argv[0] if sys.argv else "dem_ros", *(args or [])],
                   signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rclpy's RCLError on arguments rcl cannot parse
        raise TransportError(f"rclpy.init failed: {exc}") from None
    return True


class RclpyExecutor(LoopExecutor):
    """Dispatches the rcl subscriptions, services, timers and intra-process queue of its nodes."""

    def __init__(self, args: list[str] | None = None, *, intra_process: bool = False):
        super().__init__(intra_process=intra_process)
        self._owns_context = init_context(args)
        self.context = rclpy.get_default_context()
        self._guard = _rclpy.GuardCondition(self.context.handle)
        self._taker = SerializedTake()
        #: (rclpy Subscription, rcl pointer, handler(cdr, gid), node)
        self.subscriptions: list[tuple[Any, int, Callable[[bytes, bytes], None], Member]] = []
        self._ws: Any = None  # rebuilt when the subscriptions change
        self._next_services = 0
        self._ready: list[int] | None = None  # the subscriptions the last wait found ready (None: all)
        #: GIDs of the writers that deliver within this executor (their samples also come through rcl)
        self.local_writers: set[bytes] = set()

    def add_subscription(self, sub: Any, handler: Callable[[bytes, bytes], None], node: Member) -> None:
        self.subscriptions.append((sub, int(sub.handle.pointer), handler, node))
        self._ws = None

    def _forget_endpoints(self, node: Member) -> None:
        self.subscriptions = [s for s in self.subscriptions if s[3] is not node]
        self._ws = None

    def wake(self) -> None:
        with contextlib.suppress(Exception):
            self._guard.trigger_guard_condition()

    def _wait(self, timeout_ns: int) -> bool:
        now = time.monotonic_ns()
        poll = self._next_services - now
        if poll <= 0:
            self._ready = None
            return True  # the services are due: _take polls them (and every subscription)
        ws = self._ws
        if ws is None:
            ws = self._ws = _rclpy.WaitSet(len(self.subscriptions), 1, 0, 0, 0, 0, self.context.handle)
        ws.clear_entities()
        for sub, _, _, _ in self.subscriptions:
            ws.add_subscription(sub.handle)
        ws.add_guard_condition(self._guard)
        ws.wait(min(timeout_ns, poll))
        self._ready = ws.get_ready_entities("subscription")
        return bool(self._ready) or bool(ws.get_ready_entities("guard_condition"))

    def _take(self) -> None:
        """Every sample waiting in a subscription, in the order the subscriptions were made; then,
        when due, the services' requests."""
        take = self._taker.take
        ready = self._ready
        for _, ptr, handler, node in self.subscriptions:
            if ready is not None and ptr not in ready:
                continue
            while True:
                got = take(ptr)
                if got is None:
                    break
                if not node.is_shutdown:
                    handler(*got)
        now = time.monotonic_ns()
        if now >= self._next_services:
            self._next_services = now + SERVICE_POLL_NS
            for n in list(self.nodes):
                if not n.is_shutdown:
                    serve = getattr(n, "serve_requests", None)
                    if serve is not None:
                        serve()

    def is_local(self, gid: bytes) -> bool:
        """True for a writer whose samples this executor delivers in memory (drop its rcl copy)."""
        return gid in self.local_writers

    def close(self) -> None:
        """Release the wait set and buffers; shut rclpy's context down if this executor started it."""
        self._ws = None
        self._taker.close()
        if self._owns_context:
            self._owns_context = False
            with contextlib.suppress(Exception):
                rclpy.try_shutdown()
