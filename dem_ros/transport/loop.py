"""The executor core both middleware transports share: timers, intra-process delivery, rounds.

One thread runs the callbacks of one or more nodes, like rclpy's ``SingleThreadedExecutor``:
:meth:`LoopExecutor.spin_once` waits on the middleware's wait set (the subclass's
:meth:`~LoopExecutor._wait`) until data arrives or the next timer is due, then runs on the
calling thread, one at a time: the samples taken from the middleware (:meth:`~LoopExecutor._take`),
the due timers, and the queued intra-process deliveries. :class:`~.dds.executor.DdsExecutor`
waits on a Cyclone DDS wait set, :class:`~.rclpy.executor.RclpyExecutor` on an rcl wait set.

Intra-process (composition). An executor made with ``intra_process=True``
hosts several nodes in one process, as a ROS 2 component container with
``use_intra_process_comms`` does. A message published on a topic that a node
of the same executor subscribes to is handed to that subscription through an
in-memory FIFO (the message object itself; CDR bytes, encoded once, for raw
subscriptions; ``(message, writer GID)`` for sourced ones: :func:`deliver_local`) and never
crosses the middleware, so a sensor -> estimator -> controller -> plant chain costs no
socket, no context switch and no (de)serialisation. The middleware's endpoints still exist
(``ros2 topic info`` lists them; remote publishers and subscribers are served as usual), and a
publisher writes to the middleware only while a remote subscriber is matched. Published
messages are shared, not copied: do not modify a message after publishing it.

Delivery order is FIFO over all topics of the executor (publish order), never
re-entrant. (Depth-first delivery - what a callback publishes first - would take
the reference node off the estimator -> controller path, about 50 us here, but
a lockstep plant catching up inside its command callback then overtakes the
reference's one-sample lead, and the controller acts on an older reference:
97 of 6000 samples in tests/graph/test_composed.py.)

Due timers fire **rate-monotonic** (the shortest period first, as a fixed-priority real-time
scheduler ranks periodic tasks), and what each one sets off is delivered before the next
fires: the 1 kHz tick's chain never waits behind a 1 Hz diagnostics timer due in the same
round. **Background nodes** (:meth:`LoopExecutor.set_background`; the recorder of a
container) come last in every round: their timers and intra-process deliveries run after
every other node's work of that round, i.e. after the 1 kHz chain measurement -> estimate ->
command has run to its end. Recording is best-effort and never delays the loop. Samples from
other processes are taken for all nodes at once, in the order the subscriptions were made
(deferring a background node's made the loop's commands stale behind a hardware driver on a
pty: its readers are 1000 deep).
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from ..realtime import StallMonitor, loop_monitor

__all__ = ["MAX_WAIT_NS", "LocalSubscription", "LoopExecutor", "LoopTimer", "Member", "SourcedLocalSubscription",
           "deliver_local"]

#: the longest a blocking wait lasts, so that Python signal handlers run promptly
MAX_WAIT_NS = 200_000_000


class Member(Protocol):
    """What the executor needs of a node it dispatches for."""

    @property
    def is_shutdown(self) -> bool:
        """Its callbacks no longer run."""

    @property
    def has_pending_replies(self) -> bool:
        """Service replies wait for their client's reader to match: poll again soon."""

    def flush_replies(self) -> None:
        """Send the service replies whose client is now matched (or timed out)."""

    def shutdown(self) -> None:
        """Stop: leave the executor (idempotent)."""


class LoopTimer:
    """A periodic callback scheduled against absolute deadlines on the monotonic clock.

    Attributes:
        period_ns: period (ns).
        next_ns: next deadline, ``time.monotonic_ns()`` scale (ns).
        fired: number of calls so far.
        overruns: number of deadlines skipped because a call came too late
            (the timer then resumes at the next future deadline, never bursts).
    """

    def __init__(self, period_s: float, callback: Callable[[], object], node: Member | None = None):
        if not period_s > 0:
            raise ValueError(f"timer period must be positive, got {period_s!r} s")
        self.period_ns = round(period_s * 1e9)
        self.callback = callback
        self.node = node
        self.next_ns = time.monotonic_ns() + self.period_ns
        self.fired = 0
        self.overruns = 0
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True

    def fire(self) -> None:
        """Run the callback for the current deadline and schedule the next one."""
        self.fired += 1
        self.next_ns += self.period_ns
        self.callback()
        now = time.monotonic_ns()
        if self.next_ns <= now:  # we are late by at least one whole period: skip, count
            missed = (now - self.next_ns) // self.period_ns + 1
            self.overruns += int(missed)
            self.next_ns += int(missed) * self.period_ns


class LocalSubscription:
    """An intra-process subscription: ``raw`` ones get CDR bytes, the others the message."""

    __slots__ = ("callback", "node", "raw")

    def __init__(self, node: Member, callback: Callable[[Any], object], raw: bool):
        self.node = node
        self.callback = callback
        self.raw = raw


class SourcedLocalSubscription(LocalSubscription):
    """An intra-process subscription whose callback takes ``(msg, writer_gid)`` as one tuple."""

    __slots__ = ()


def deliver_local(local: list[LocalSubscription], queue: deque[tuple[LocalSubscription, Any]], msg: Any,
                  gid: bytes, cdr: Callable[[Any], bytes]) -> bytes | None:
    """Queue ``msg`` for the intra-process subscriptions ``local`` of a topic (its CDR, made once by
    ``cdr(msg)``, for raw ones; ``(msg, gid)`` for sourced ones); return the CDR if it was made."""
    data = None
    for sub in local:
        if sub.raw:
            if data is None:
                data = cdr(msg)
            queue.append((sub, data))
        elif sub.__class__ is SourcedLocalSubscription:
            queue.append((sub, (msg, gid)))
        else:
            queue.append((sub, msg))
    return data


class LoopExecutor:
    """Timers, intra-process queue and rounds of an executor; the middleware's wait and take are
    the subclass's (:meth:`_wait`, :meth:`_take`, :meth:`wake`, :meth:`_forget_endpoints`)."""

    def __init__(self, *, intra_process: bool = False):
        self.intra_process = intra_process
        self.nodes: list[Member] = []
        self.timers: list[LoopTimer] = []
        #: pending intra-process deliveries, (LocalSubscription, argument), FIFO over all topics
        self.queue: deque[tuple[LocalSubscription, Any]] = deque()
        #: nodes whose work runs after every other node's in each round (see the module docstring)
        self.background: set[Member] = set()
        self._later: deque[tuple[LocalSubscription, Any]] = deque()  # background deliveries of this round
        self._monitor: StallMonitor | None = None
        self._monitor_known = False  # looked up on the spinning thread (see spin_once)
        #: topic name -> intra-process subscriptions (the list object is shared with publishers)
        self.local: dict[str, list[LocalSubscription]] = {}
        self._lock = threading.Lock()
        self._owner: int | None = None  # thread inside spin_once
        self._deferred: list[tuple[Member, Callable[[], None]]] = []
        self._stopped = False

    # -- the middleware's part ------------------------------------------------------------
    def _wait(self, timeout_ns: int) -> bool:
        """Wait up to ``timeout_ns`` (0: poll) for data or :meth:`wake`; True when something woke it."""
        raise NotImplementedError

    def _take(self) -> None:
        """Run the callbacks of every sample (and request) waiting in the middleware."""
        raise NotImplementedError

    def wake(self) -> None:
        """Make a blocked :meth:`_wait` return."""
        raise NotImplementedError

    def _forget_endpoints(self, node: Member) -> None:
        """Stop waiting on ``node``'s middleware endpoints."""

    # -- membership ---------------------------------------------------------------------
    def add_node(self, node: Member) -> None:
        self.nodes.append(node)

    def set_background(self, node: Member) -> None:
        """Run ``node``'s callbacks after every other node's in each round (best-effort work,
        such as recording, that must never delay the loop's chain)."""
        self.background.add(node)

    def add_timer(self, timer: LoopTimer) -> None:
        """Timers fire rate-monotonic: the shortest period first (after those of equal period)."""
        bisect.insort_right(self.timers, timer, key=lambda t: t.period_ns)

    def local_subscriptions(self, topic: str) -> list[LocalSubscription]:
        """The (shared, live) list of intra-process subscriptions of a topic."""
        return self.local.setdefault(topic, [])

    def remove_node(self, node: Member, then: Callable[[], None]) -> None:
        """Forget a node's endpoints, timers and intra-process subscriptions, then call ``then()``.

        From a callback or a signal handler on the spinning thread this happens when the
        current :meth:`spin_once` has finished; from another thread it waits for that.
        """
        if self._owner == threading.get_ident():
            self._deferred.append((node, then))
            return
        with self._lock:
            self._forget(node)
        then()

    def _forget(self, node: Member) -> None:
        self.background.discard(node)
        self._forget_endpoints(node)
        self.timers = [t for t in self.timers if t.node is not node]
        for subs in self.local.values():
            subs[:] = [s for s in subs if s.node is not node]
        if node in self.nodes:
            self.nodes.remove(node)
        if not self.nodes:
            self._stopped = True

    @property
    def stopped(self) -> bool:
        return self._stopped

    # -- dispatch ------------------------------------------------------------------------
    def spin_once(self, timeout_s: float | None = 0.1) -> None:
        """Wait for data, a timer deadline or ``timeout_s``; then run what is ready."""
        with self._lock:
            if self._stopped:
                return
            self._owner = threading.get_ident()
            if not self._monitor_known:  # the loop's thread (after enter_loop) reports its stalls
                self._monitor, self._monitor_known = loop_monitor(), True
            try:
                self._dispatch(timeout_s)
            finally:
                self._owner = None
                while self._deferred:  # nodes shut down from a callback or a signal handler
                    node, then = self._deferred.pop(0)
                    self._forget(node)
                    then()

    def _dispatch(self, timeout_s: float | None) -> None:
        queue = self.queue
        now = time.monotonic_ns()
        deadline = now + (MAX_WAIT_NS if timeout_s is None else max(0, int(timeout_s * 1e9)))
        for t in self.timers:
            if t.next_ns < deadline and not t.cancelled:
                deadline = t.next_ns
        if any(n.has_pending_replies for n in self.nodes):
            deadline = min(deadline, now + 5_000_000)
        wait = min(deadline - now, MAX_WAIT_NS) if not queue else 0
        # a zero wait still polls: a loop that runs late must not starve its readers
        triggered = self._wait(max(wait, 0))
        if self._stopped:
            return
        woke = time.monotonic_ns()
        bg = self.background
        if triggered:
            self._take()
        for t in self.timers:  # rate-monotonic: what a timer sets off runs before any slower timer
            if t.next_ns <= woke and not t.cancelled and t.node not in bg \
                    and not (t.node is not None and t.node.is_shutdown):
                t.fire()
                self._deliver(bg)
        self._deliver(bg)
        later = self._later
        monitor = self._monitor
        if monitor is not None:  # the loop's work of this round is done: was it in time?
            # due: the deadline it slept to, or when it woke (data, or a round that had no wait)
            monitor.round(deadline if wait > 0 and woke >= deadline else woke, time.monotonic_ns())
        if bg:  # best-effort nodes: after the loop's chain
            now = time.monotonic_ns()
            for t in self.timers:
                if t.next_ns <= now and not t.cancelled and t.node is not None and t.node in bg \
                        and not t.node.is_shutdown:
                    t.fire()
            while later or queue:
                sub, arg = later.popleft() if later else queue.popleft()
                if not sub.node.is_shutdown:
                    sub.callback(arg)
        for n in self.nodes:
            if n.has_pending_replies:
                n.flush_replies()

    def _deliver(self, bg: set[Member]) -> None:
        """Run the queued intra-process deliveries, including those the callbacks add; those of
        background nodes wait in ``_later``."""
        queue, later = self.queue, self._later
        while queue:
            sub, arg = queue.popleft()
            if sub.node in bg:
                later.append((sub, arg))
            elif not sub.node.is_shutdown:
                sub.callback(arg)

    def spin(self) -> None:
        """Dispatch until every node has shut down (waits are bounded so signals are handled)."""
        while not self._stopped:
            self.spin_once(None)

    def shutdown(self) -> None:
        """Shut every node of this executor down."""
        for n in list(self.nodes):
            n.shutdown()
        self._stopped = True
        self.wake()
