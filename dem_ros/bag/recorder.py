"""The middleware-free core of the recorder node.

A recorder node subscribes to the contract topics and, in each callback,
calls :meth:`Recorder.on_message` with the receive time and the serialized
(CDR) message. ``on_message`` only appends to a bounded queue (O(1), no I/O);
a writer thread drains the queue into a :class:`~dem_ros.bag.BagWriter`. If
the queue is full, the message is dropped and counted; counters are written
into the bag's ``custom_data`` (``dem_ros.recorder_counters``) on close, so a
drop is never silent.

:meth:`Recorder.on_object` queues a message object and the function that
serializes it instead: the writer thread then does the encoding, off the
caller's thread (used when the recorder shares a process with a 1 kHz loop).

Threading: ``on_message`` may be called from any one thread (or several:
the per-topic counters are then approximate, the bag is not). ``close()`` is
idempotent and may be called from a signal handler (see
:func:`finalize_on_signals`).
"""

from __future__ import annotations

import json
import signal
import struct
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from dem_ros.contract import Topic

from .errors import BagError
from .writer import DEFAULT_CHUNK_SIZE, BagWriter

__all__ = ["GRID_TOPICS", "Recorder", "StampGrid", "TopicCounters", "finalize_on_signals"]

#: the plant's streams, one sample per period from its first to its last: every one missing from the bag is lost
GRID_TOPICS = ("/dem/measurement", "/dem/plant/truth", "/dem/applied_voltage")


@dataclass
class TopicCounters:
    """Per-topic message counts: received = written + dropped + still queued. ``lost``: on a topic with a sample
    grid (the plant's 1 kHz streams, :class:`StampGrid`), the samples between the first and the newest stamp
    written that the bag lacks, whatever happened to them (never sent to us, lost on the wire, dropped here)."""

    received: int = 0
    written: int = 0
    dropped: int = 0
    lost: int = 0


class StampGrid:
    """Which samples of a fixed-rate stream (``period_ns``) the bag holds, by header stamp: the lost ones are the
    grid points from the first stamp written to the newest that none of the written samples has (a repeated stamp,
    e.g. a foreign writer's, counts once). A stamp further than ``horizon_ns`` ahead of the newest (a corrupt or
    foreign stamp) or before the first is off the grid and counted apart (``off_grid``). One bit per sample."""

    __slots__ = ("bits", "first", "horizon", "newest", "off_grid", "period", "present")

    def __init__(self, period_ns: int, horizon_ns: int = 10_000_000_000):
        self.period = int(period_ns)
        self.horizon = int(horizon_ns)
        self.first: int | None = None
        self.newest = -1  # index of the newest stamp
        self.present = 0  # distinct grid points written
        self.off_grid = 0
        self.bits = bytearray()

    def add(self, stamp_ns: int) -> None:
        if self.first is None:
            self.first = stamp_ns
        k = round((stamp_ns - self.first) / self.period)
        if k < 0 or (k - self.newest) * self.period > self.horizon:
            self.off_grid += 1
            return
        byte, bit = divmod(k, 8)
        if byte >= len(self.bits):
            self.bits.extend(bytes(max(byte + 1 - len(self.bits), 4096)))
        if not self.bits[byte] >> bit & 1:
            self.bits[byte] |= 1 << bit
            self.present += 1
        if k > self.newest:
            self.newest = k

    @property
    def lost(self) -> int:
        """Grid points from the first stamp to the newest that no written sample has."""
        return self.newest + 1 - self.present


def _cdr_stamp(data: bytes) -> int | None:
    """``header.stamp`` (ns) of a serialized message whose first field is a std_msgs/Header (CDR, either order)."""
    if len(data) < 12:
        return None
    sec, nsec = struct.unpack_from("<iI" if data[1] & 1 else ">iI", data, 4)
    return int(sec) * 1_000_000_000 + int(nsec)


class _Deferred:
    __slots__ = ("msg", "serialize")

    def __init__(self, msg: Any, serialize: Callable[[Any], bytes]):
        self.msg = msg
        self.serialize = serialize


class Recorder:
    """Record CDR messages of the given topics into a bag directory.

    Args:
        bag_dir: bag directory to create (see :class:`BagWriter`).
        topics: contract topics to record (name, ROS type, QoS).
        metadata: run metadata (config, scenario, controller, transport, version).
        queue_size: maximum number of messages waiting for the writer thread.
        compression, chunk_size: passed to :class:`BagWriter`.
        poll_s: writer thread sleep (s) when the queue is empty.
        kick_on: a topic whose message wakes the writer thread at once. In a
            1 kHz loop sharing this process (composition) the writer then does
            its Python work right after the loop's last message of a cycle,
            while the loop sleeps, instead of contending with it for the GIL.
        on_error: called once, on the writer thread, with the one-line reason
            when writing fails (disk full, I/O error): the node reports it at
            once. Recording stops; :meth:`close` still finalises the bag.

    A write failure never raises out of the recorder: it is :attr:`failure`,
    the messages that did not reach the file are counted as dropped, and the
    bag's metadata says ``dem_ros.status: failed`` with the reason.
    """

    def __init__(
        self,
        bag_dir: Path | str,
        topics: Iterable[Topic],
        metadata: dict[str, Any] | None = None,
        *,
        queue_size: int = 50_000,
        compression: str = "zstd",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        poll_s: float = 0.005,
        kick_on: str | None = None,
        on_error: Callable[[str], None] | None = None,
    ) -> None:
        if queue_size < 1:
            raise BagError(f"queue_size must be >= 1, got {queue_size}")
        self.topics = list(topics)
        if not self.topics:
            raise BagError("Recorder needs at least one topic")
        self._writer = BagWriter(bag_dir, compression=compression, chunk_size=chunk_size, metadata=metadata)
        for t in self.topics:
            self._writer.add_topic(t.name, t.type, t.qos)
        self.path = self._writer.path
        self.queue_size = queue_size
        self.poll_s = poll_s
        self.kick_on = kick_on
        self.on_error = on_error
        #: why recording stopped early (one line), or None
        self.failure: str | None = None
        self._wake = threading.Event()
        self._counters = {t.name: TopicCounters() for t in self.topics}
        #: the plant's fixed-rate streams: which of their samples the bag holds (``lost``)
        self.grids = {t.name: StampGrid(round(1e9 / t.rate_hz)) for t in self.topics if t.name in GRID_TOPICS
                      and t.rate_hz}
        self._queue: deque[tuple[str, int, bytes | _Deferred]] = deque()
        self.max_queue_depth = 0
        self.error: BaseException | None = None
        self.serialize_errors = 0
        self.last_serialize_error = ""
        self._closing = False
        self._stop = threading.Event()
        self._close_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="dem_ros-bag-writer", daemon=True)
        self._thread.start()

    # -- callback side ---------------------------------------------------
    def on_message(self, topic_name: str, recv_time_ns: int, cdr_bytes: bytes) -> bool:
        """Queue one message; returns False if it was dropped (queue full or closed).

        Raises:
            BagError: ``topic_name`` is not one of the recorded topics.
        """
        return self._put(topic_name, recv_time_ns, cdr_bytes)

    def on_object(self, topic_name: str, recv_time_ns: int, msg: Any, serialize: Callable[[Any], bytes]) -> bool:
        """Like :meth:`on_message`, with ``serialize(msg)`` (CDR bytes) called on the writer thread.

        ``msg`` must not change after this call (published messages do not).
        """
        return self._put(topic_name, recv_time_ns, _Deferred(msg, serialize))

    def _put(self, topic_name: str, recv_time_ns: int, data: bytes | _Deferred) -> bool:
        c = self._counters.get(topic_name)
        if c is None:
            raise BagError(f"Recorder got a message on {topic_name!r}, which it does not record")
        c.received += 1
        q = self._queue
        if self._closing or self.error is not None or len(q) >= self.queue_size:
            c.dropped += 1
            return False
        q.append((topic_name, recv_time_ns, data))
        if topic_name == self.kick_on:
            self._wake.set()
        return True

    # -- writer thread ---------------------------------------------------
    def _run(self) -> None:
        q, w, counters, grids = self._queue, self._writer, self._counters, self.grids
        while True:
            depth = len(q)
            if depth > self.max_queue_depth:
                self.max_queue_depth = depth
            if not depth:
                if self._stop.is_set():
                    return
                self._wake.wait(self.poll_s)
                self._wake.clear()
                continue
            try:
                for _ in range(depth):
                    topic, t, data = q.popleft()
                    if isinstance(data, _Deferred):
                        try:
                            data = data.serialize(data.msg)
                        except Exception as exc:  # one unencodable message: drop it, keep recording
                            counters[topic].dropped += 1
                            self.serialize_errors += 1
                            self.last_serialize_error = f"{topic}: {exc!r}"
                            continue
                    w.write(topic, t, data)
                    c = counters[topic]
                    c.written += 1
                    g = grids.get(topic)
                    if g is not None:
                        stamp = _cdr_stamp(data)
                        if stamp is not None:
                            g.add(stamp)
                            c.lost = g.lost
            except BagError as exc:  # disk full, I/O error: the writer has stopped; account and report
                self._stopped(str(exc))
                return
            except BaseException as exc:  # a bug: same, never a silent end of recording
                self._stopped(f"{self.path}: bag writer thread failed: {exc!r}")
                return

    def _stopped(self, reason: str) -> None:
        """Recording stopped: what is not in the file counts as dropped; tell ``on_error`` once."""
        self.error = RuntimeError(reason)  # on_message drops from now on
        self.failure = reason
        self._drain_as_dropped()
        self._recount()
        if self.on_error is not None:
            try:
                self.on_error(reason)
            except Exception as exc:  # the report must not kill the thread that keeps the counters right
                print(f"dem_ros.bag: on_error callback failed: {exc!r}", file=sys.stderr)

    def _recount(self) -> None:
        """After a failure: written = what is in the file, dropped = the rest of what was received."""
        in_file = self._writer.counts
        for name, c in self._counters.items():
            c.written = in_file.get(name, 0)
            c.dropped = c.received - c.written

    def _drain_as_dropped(self) -> None:
        q = self._queue
        while q:
            self._counters[q.popleft()[0]].dropped += 1

    # -- status ----------------------------------------------------------
    def counters(self) -> dict[str, TopicCounters]:
        """Snapshot of the per-topic counters."""
        return {k: TopicCounters(**asdict(v)) for k, v in self._counters.items()}

    @property
    def closed(self) -> bool:
        return self._writer.closed

    # -- closing ---------------------------------------------------------
    def close(self) -> dict[str, TopicCounters]:
        """Drain the queue, finalize the bag, return the final counters. Idempotent.

        Never raises for a write failure: see :attr:`failure` (the bag is
        finalised as far as the disk allows; counters are kept).
        """
        if not self._close_lock.acquire(blocking=False):
            return self.counters()  # re-entered (signal during close) or concurrent close
        try:
            if not self._writer.closed:
                self._closing = True
                self._stop.set()
                self._thread.join()
                self._drain_as_dropped()  # raced in after a writer failure
                if self.failure is not None:
                    self._recount()
                counts = {k: asdict(v) for k, v in self._counters.items()}
                self._writer.set_custom_data("dem_ros.recorder_counters", json.dumps(counts, sort_keys=True))
                try:
                    self._writer.close()
                except BagError as exc:  # failed while finalising: reported like a failure while recording
                    if self.failure is None:
                        self.failure = str(exc)
                        if self.on_error is not None:
                            self.on_error(self.failure)
        finally:
            self._close_lock.release()
        return self.counters()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def finalize_on_signals(
    recorder: Recorder | BagWriter,
    signals: Iterable[int] = (signal.SIGINT, signal.SIGTERM),
    *,
    then: Callable[[int], None] | None = None,
) -> Callable[[], None]:
    """Install handlers that finalize ``recorder`` on SIGINT/SIGTERM.

    The handler closes the recorder (queue drained, summary and
    ``metadata.yaml`` written), then calls ``then(signum)`` if given, else
    exits with status ``128 + signum`` (``SystemExit`` in the main thread, so
    ``finally`` blocks run). Must be called from the main thread. Returns a
    function that restores the previous handlers.

    With a :class:`BagWriter` (no writer thread) the handler may interrupt a
    ``write`` in progress; prefer a :class:`Recorder`.
    """
    sigs = list(signals)

    def handler(signum: int, _frame: FrameType | None) -> None:
        try:
            recorder.close()
        except BagError as exc:
            print(f"dem_ros.bag: {exc}", file=sys.stderr)
        if then is not None:
            then(signum)
        else:
            raise SystemExit(128 + signum)

    previous = {s: signal.signal(s, handler) for s in sigs}

    def restore() -> None:
        for s, h in previous.items():
            signal.signal(s, h)

    return restore
