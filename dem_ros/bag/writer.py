"""rosbag2-compatible MCAP bag writer (no ROS needed).

A bag is a directory ``NAME/`` holding ``metadata.yaml`` (rosbag2 metadata
version 8) and ``NAME_0.mcap`` (MCAP, profile ``ros2``). Humble and Jazzy
``ros2 bag info/play`` read both; see :mod:`dem_ros.bag._rosfmt` for the
upstream sources of each convention.

Crash safety:
    * The MCAP file is written through an unbuffered stream; each chunk is
      handed to the kernel as soon as it is full (``chunk_size`` bytes) or
      ``flush_interval_s`` after its first message, so a SIGKILLed writer
      leaves a file readable up to its last complete chunk.
    * A provisional ``metadata.yaml`` (custom_data ``dem_ros.status:
      recording``) is written when the bag is opened and refreshed at a chunk
      boundary at most every ``metadata_refresh_s``; ``close()`` writes the
      final one (``dem_ros.status: complete``). It is replaced atomically.
    * The run metadata goes into an MCAP Metadata record ``dem_ros`` at the
      start of the file, so it survives a kill too.

Full disk (or any write error): the writer keeps a file allocated
(``.NAME_0.mcap.reserve``) as large as what finalising the bag needs; a
failed write is cut back to the last complete record, the chunk in progress
is counted as lost (:attr:`BagWriter.lost`), writing stops (:attr:`BagWriter.failure`),
and :meth:`BagWriter.close` frees the reserve and writes the summary and the
final metadata.yaml (``dem_ros.status: failed``, ``dem_ros.failure``).

Run metadata: ``metadata.yaml`` ``custom_data`` (string map, present since
metadata version 6) carries ``dem_ros.run_info`` (JSON of the metadata dict)
and ``dem_ros.version``; the same map is in the ``rosbag2`` Metadata record
(``serialized_metadata``) that Jazzy reads, and in the ``dem_ros`` record.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import struct
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

from dem_ros import __version__
from dem_ros.contract import QoS

from . import _rosfmt
from .errors import BagError

__all__ = ["COMPRESSIONS", "BagWriter"]

COMPRESSIONS = ("zstd", "lz4", "none")
#: rosbag2_storage_mcap's default chunk size (mcap C++ McapWriterOptions: 768 KiB).
DEFAULT_CHUNK_SIZE = 768 * 1024
#: granularity of the space reserved for finalising a bag on a full disk (see BagWriter._ensure_reserve)
RESERVE_STEP = 32 * 1024


class _DirectStream:
    """Write-only file stream without user-space buffering (survives SIGKILL)."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        n = len(view)
        while view:
            k = os.write(self.fd, view)
            view = view[k:]
        self.pos += n
        return n

    def tell(self) -> int:
        return self.pos

    def cut_partial(self) -> None:
        """Drop what a failed ``write`` left after the last complete one (frees the space it took)."""
        if self.fd >= 0:
            with contextlib.suppress(OSError):  # if even this fails, the reader stops at the partial record
                os.ftruncate(self.fd, self.pos)
            os.lseek(self.fd, self.pos, os.SEEK_SET)  # ftruncate leaves the offset after the partial write

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self.fd >= 0:
            try:
                os.fsync(self.fd)
            except OSError:
                pass  # nothing more can be done for the data; close anyway
            finally:
                os.close(self.fd)
                self.fd = -1


_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_MSG_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log time, publish time
MAGIC = b"\x89MCAP0\r\n"


def _s(text: str) -> bytes:
    b = text.encode("utf-8")
    return _U32.pack(len(b)) + b


def _map(d: dict[str, str]) -> bytes:
    body = b"".join(_s(k) + _s(v) for k, v in d.items())
    return _U32.pack(len(body)) + body


def _rec(op: int, content: bytes) -> bytes:
    return bytes((op,)) + _U64.pack(len(content)) + content


class _McapWriter:
    """Minimal chunked MCAP writer (mcap.dev/spec), ~1 us per message.

    Schemas, channels and metadata go to the data section at once (so a
    truncated file still names its topics); messages are packed into the
    current chunk, which is compressed and written - chunk, then its message
    indexes - in one ``write`` when full. ``finish`` writes DataEnd, the
    summary (schemas, channels, statistics, chunk and metadata indexes),
    summary offsets and the footer with the summary CRC.
    """

    def __init__(self, stream: _DirectStream, compression: str, chunk_size: int, library: str) -> None:
        self.s = stream
        self.compression = "" if compression == "none" else compression
        self._compress: Callable[[bytes], bytes]
        if compression == "zstd":
            import zstandard

            self._compress = zstandard.ZstdCompressor(level=3).compress
        elif compression == "lz4":
            import lz4.frame

            self._compress = lz4.frame.compress
        else:
            self._compress = bytes
        self.chunk_size = chunk_size
        self.schemas: list[bytes] = []
        self.channels: list[bytes] = []
        self.chunk_indexes: list[bytes] = []
        self.metadata_indexes: list[bytes] = []
        self.channel_counts: dict[int, int] = {}
        self.n_messages = 0
        self.t_min = 2**64 - 1
        self.t_max = 0
        self._buf = bytearray()
        self._index: dict[int, list[int]] = {}
        self._c_min = 2**64 - 1
        self._c_max = 0
        self._c_counts: dict[int, int] = {}  # channel id -> messages in the open chunk
        stream.write(MAGIC + _rec(0x01, _s("ros2") + _s(library)))

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self.schemas) + 1
        rec = _rec(0x03, _U16.pack(sid) + _s(name) + _s(encoding) + _U32.pack(len(data)) + data)
        self.s.write(rec)
        self.schemas.append(rec)
        return sid

    def add_channel(self, topic: str, encoding: str, schema_id: int, metadata: dict[str, str]) -> int:
        cid = len(self.channels) + 1
        rec = _rec(0x04, _U16.pack(cid) + _U16.pack(schema_id) + _s(topic) + _s(encoding) + _map(metadata))
        self.s.write(rec)
        self.channels.append(rec)
        self.channel_counts[cid] = 0
        return cid

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        rec = _rec(0x0C, _s(name) + _map(data))
        index = _rec(0x0D, _U64.pack(self.s.tell()) + _U64.pack(len(rec)) + _s(name))
        self.s.write(rec)
        self.metadata_indexes.append(index)

    def add_message(self, cid: int, log_time: int, data: bytes | bytearray | memoryview, publish_time: int) -> bool:
        """Append to the current chunk; True if that completed and wrote a chunk."""
        buf = self._buf
        idx = self._index.get(cid)
        if idx is None:
            idx = self._index[cid] = []
        idx.append(log_time)
        idx.append(len(buf))
        buf += _MSG_HEAD.pack(0x05, 22 + len(data), cid, 0, log_time, publish_time)
        buf += data
        if log_time < self._c_min:
            self._c_min = log_time
        if log_time > self._c_max:
            self._c_max = log_time
        self._c_counts[cid] = self._c_counts.get(cid, 0) + 1
        if len(buf) >= self.chunk_size:
            self.finish_chunk()
            return True
        return False

    def finish_chunk(self) -> None:
        if not self._buf:
            return
        raw = bytes(self._buf)
        comp = self._compress(raw)
        start, end = self._c_min, self._c_max
        chunk = _rec(0x06, struct.pack("<QQQI", start, end, len(raw), zlib.crc32(raw))
                     + _s(self.compression) + _U64.pack(len(comp)) + comp)
        chunk_off = self.s.tell()
        out = [chunk]
        offsets = []
        pos = chunk_off + len(chunk)
        for cid, flat in self._index.items():
            rec = _rec(0x07, _U16.pack(cid) + _U32.pack(8 * len(flat)) + struct.pack(f"<{len(flat)}Q", *flat))
            offsets.append(_U16.pack(cid) + _U64.pack(pos))
            pos += len(rec)
            out.append(rec)
        idx_len = pos - chunk_off - len(chunk)
        off_map = b"".join(offsets)
        self.s.write(b"".join(out))
        # only now (the chunk is in the file) does it count: indexes, statistics
        self.chunk_indexes.append(_rec(0x08, struct.pack("<QQQQ", start, end, chunk_off, len(chunk))
                                       + _U32.pack(len(off_map)) + off_map + _U64.pack(idx_len)
                                       + _s(self.compression) + _U64.pack(len(comp)) + _U64.pack(len(raw))))
        for cid, n in self._c_counts.items():
            self.channel_counts[cid] += n
            self.n_messages += n
        self.t_min = min(self.t_min, start)
        self.t_max = max(self.t_max, end)
        self.discard_chunk()

    def discard_chunk(self) -> dict[int, int]:
        """Forget the open chunk (after a failed write); its message counts per channel id."""
        lost = self._c_counts
        self._buf = bytearray()
        self._index = {}
        self._c_counts = {}
        self._c_min, self._c_max = 2**64 - 1, 0
        return lost

    def closing_size(self) -> int:
        """Bytes :meth:`finish` writes after the data (DataEnd, summary, offsets, footer), open chunk excluded."""
        n = sum(map(len, self.schemas)) + sum(map(len, self.channels))
        n += sum(map(len, self.chunk_indexes)) + sum(map(len, self.metadata_indexes))
        return n + 13 + (9 + 50 + 10 * len(self.channel_counts)) + 5 * 26 + 37 + 8

    def finish(self) -> None:
        self.finish_chunk()
        self.s.write(_rec(0x0F, _U32.pack(0)))
        summary_start = self.s.tell()
        counts = b"".join(_U16.pack(c) + _U64.pack(n) for c, n in sorted(self.channel_counts.items()))
        stats = _rec(0x0B, struct.pack(
            "<QHIIIIQQ", self.n_messages, len(self.schemas), len(self.channels), 0,
            len(self.metadata_indexes), len(self.chunk_indexes),
            self.t_min if self.n_messages else 0, self.t_max if self.n_messages else 0,
        ) + _U32.pack(len(counts)) + counts)
        groups = [(0x03, self.schemas), (0x04, self.channels), (0x0B, [stats]),
                  (0x08, self.chunk_indexes), (0x0D, self.metadata_indexes)]
        body = bytearray()
        offsets = bytearray()
        for op, recs in groups:
            if not recs:
                continue
            g0 = len(body)
            for r in recs:
                body += r
            offsets += _rec(0x0E, bytes((op,)) + _U64.pack(summary_start + g0) + _U64.pack(len(body) - g0))
        offset_start = summary_start + len(body)
        body += offsets
        footer_head = bytes((0x02,)) + _U64.pack(20) + _U64.pack(summary_start) + _U64.pack(offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(body))
        self.s.write(bytes(body) + footer_head + _U32.pack(crc) + MAGIC)


class BagWriter:
    """Write a rosbag2 MCAP bag directory from CDR-serialized messages.

    Args:
        path: bag directory to create (must not exist, or be empty).
        compression: MCAP chunk compression, ``"zstd"``, ``"lz4"`` or ``"none"``.
        chunk_size: uncompressed chunk size (bytes) at which a chunk is written.
        metadata: run metadata (JSON-serializable dict: config, scenario,
            controller, transport, ...); recoverable with
            :meth:`dem_ros.bag.BagReader.run_metadata`.
        flush_interval_s: a chunk is written at the latest this long (s) after
            its first message, so slow topics reach the disk too.
        metadata_refresh_s: minimum interval (s) between provisional
            ``metadata.yaml`` refreshes.

    Use as a context manager, or call :meth:`close`. Not thread-safe: one
    thread writes (see :class:`dem_ros.bag.Recorder`).
    """

    def __init__(
        self,
        path: Path | str,
        *,
        compression: str = "zstd",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        metadata: dict[str, Any] | None = None,
        flush_interval_s: float = 1.0,
        metadata_refresh_s: float = 5.0,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise BagError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        if chunk_size < 1024:
            raise BagError(f"chunk_size must be >= 1024 bytes, got {chunk_size}")
        self.path = Path(path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise BagError(f"{self.path} exists and is not an empty directory; not overwriting")
        try:
            self.run_metadata = json.loads(json.dumps(metadata)) if metadata is not None else None
        except (TypeError, ValueError) as exc:
            raise BagError(f"run metadata is not JSON-serializable: {exc}") from None
        try:
            self._open(metadata_refresh_s, flush_interval_s, compression, chunk_size)
        except OSError as exc:
            raise BagError(f"cannot create bag {self.path}: {exc.strerror or exc}") from None

    def _open(self, metadata_refresh_s: float, flush_interval_s: float, compression: str, chunk_size: int) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_name = f"{self.path.name}_0.mcap"
        self.compression = compression
        self.chunk_size = chunk_size
        self.flush_interval_s = flush_interval_s
        self.metadata_refresh_s = metadata_refresh_s
        self.custom_data: dict[str, str] = {"dem_ros.version": __version__, "dem_ros.status": "recording"}
        if self.run_metadata is not None:
            self.custom_data["dem_ros.run_info"] = json.dumps(self.run_metadata, sort_keys=True)

        self._reserve_path = self.path / f".{self.mcap_name}.reserve"
        self._reserve_size = 0
        self._meta_size = 4096  # size of the last metadata.yaml text, for the reserve
        self._stream = _DirectStream(self.path / self.mcap_name)
        self._mcap = _McapWriter(self._stream, compression, chunk_size, f"dem_ros-{__version__}")
        self._mcap.add_metadata("dem_ros", dict(self.custom_data))
        self._topics: dict[str, dict[str, Any]] = {}
        self._channel: dict[str, int] = {}
        #: why writing stopped (an I/O error), or None
        self.failure: str | None = None
        #: per topic, messages accepted by write() that never reached the file (the chunk lost to a failure)
        self.lost: dict[str, int] = {}
        self._schema: dict[str, int] = {}
        self._chunk_open_since: float | None = None
        self._last_refresh = time.monotonic()
        self._closed = False
        self._write_metadata_yaml()
        self._ensure_reserve()

    # -- space reserve ---------------------------------------------------
    def _ensure_reserve(self) -> None:
        """Keep a file allocated that is large enough to finalise the bag (summary, final metadata.yaml).

        When the disk fills, writing fails while this space is still ours;
        :meth:`close` deletes the reserve first, so the bag is finalised with
        its counters even on a full disk. Grows in steps of ``RESERVE_STEP``.
        """
        need = self._mcap.closing_size() + 3 * self._meta_size + RESERVE_STEP // 4
        if need <= self._reserve_size:
            return
        size = -(-need // RESERVE_STEP) * RESERVE_STEP
        fd = os.open(self._reserve_path, os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            try:
                os.posix_fallocate(fd, 0, size)
            except OSError as exc:
                if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                    raise
                os.lseek(fd, self._reserve_size, os.SEEK_SET)  # no fallocate here: write zeros
                zeros = bytes(size - self._reserve_size)
                view = memoryview(zeros)
                while view:
                    view = view[os.write(fd, view):]
        finally:
            os.close(fd)
        self._reserve_size = size

    def _release_reserve(self) -> None:
        self._reserve_path.unlink(missing_ok=True)
        self._reserve_size = 0

    # -- topics ----------------------------------------------------------
    def add_topic(self, name: str, type_name: str, qos: QoS) -> None:
        """Register ``name`` (ROS type ``pkg/msg/Type``) with its offered QoS."""
        self._check_open()
        if name in self._topics:
            if self._topics[name]["type"] != type_name:
                raise BagError(f"topic {name!r} already added with type {self._topics[name]['type']!r}")
            return
        try:
            self._add_topic(name, type_name, qos)
        except OSError as exc:
            raise self._fail(exc) from None

    def _add_topic(self, name: str, type_name: str, qos: QoS) -> None:
        text = _rosfmt.msgdef(type_name)
        rihs = _rosfmt.type_hash(type_name)
        if type_name not in self._schema:
            self._schema[type_name] = self._mcap.add_schema(type_name, "ros2msg", text.encode())
        qos_string = _rosfmt.qos_to_v8_string(qos)
        self._ensure_reserve()
        self._channel[name] = self._mcap.add_channel(
            name, "cdr", self._schema[type_name],
            {"offered_qos_profiles": qos_string, "topic_type_hash": rihs},
        )
        self._topics[name] = {"name": name, "type": type_name, "qos_string": qos_string,
                              "hash": rihs, "count": 0}
        self._write_metadata_yaml()

    def set_custom_data(self, key: str, value: str) -> None:
        """Add a ``custom_data`` entry to the final metadata (string values only)."""
        if not isinstance(value, str):
            raise BagError(f"custom_data values must be str, got {type(value).__name__} for {key!r}")
        self.custom_data[key] = value

    # -- messages --------------------------------------------------------
    def write(self, topic: str, log_time_ns: int, cdr_bytes: bytes | bytearray | memoryview,
              publish_time_ns: int | None = None) -> None:
        """Append one message.

        Args:
            topic: a topic registered with :meth:`add_topic`.
            log_time_ns: receive time (ns), rosbag2's ``recv_timestamp``.
            cdr_bytes: CDR data including the 4-byte encapsulation header.
            publish_time_ns: send time (ns); defaults to ``log_time_ns``.
        """
        try:
            cid = self._channel[topic]
        except KeyError:
            self._check_open()
            raise BagError(f"topic {topic!r} was not added to {self.path}") from None
        if self._closed or self.failure is not None:
            self._check_open()
            raise BagError(f"{self.path}: recording stopped: {self.failure}")
        t = int(log_time_ns)
        try:
            chunk_written = self._mcap.add_message(cid, t, cdr_bytes,
                                                   t if publish_time_ns is None else int(publish_time_ns))
            now = time.monotonic()
            if chunk_written:
                self._chunk_open_since = None
                self._after_chunk(now)
            elif self._chunk_open_since is None:
                self._chunk_open_since = now
            elif now - self._chunk_open_since > self.flush_interval_s:
                self._flush()
        except OSError as exc:
            raise self._fail(exc) from None

    def flush(self) -> None:
        """Write the chunk in progress now (smaller chunks compress less well)."""
        self._check_open()
        try:
            self._flush()
        except OSError as exc:
            raise self._fail(exc) from None

    def _flush(self) -> None:
        self._mcap.finish_chunk()
        self._chunk_open_since = None
        self._after_chunk(time.monotonic())

    def _fail(self, exc: OSError) -> BagError:
        """Stop writing after an I/O error (disk full, ...): forget the chunk in progress, cut the partial write.

        The file stays readable up to its last complete record; :attr:`lost`
        counts per topic the messages of the chunk that never reached it.
        """
        lost = self._mcap.discard_chunk()
        self._stream.cut_partial()
        topic_of = {cid: name for name, cid in self._channel.items()}
        for cid, n in lost.items():
            self.lost[topic_of[cid]] = self.lost.get(topic_of[cid], 0) + n
        if self.failure is None:
            self.failure = (f"write failed ({exc.strerror or exc}) after {self._mcap.n_messages} messages; "
                            f"{sum(lost.values())} in the unwritten chunk lost")
        return BagError(f"{self.path}: {self.failure}")

    def _after_chunk(self, now: float) -> None:
        self._ensure_reserve()
        if now - self._last_refresh >= self.metadata_refresh_s:
            self._last_refresh = now
            self._write_metadata_yaml()

    @property
    def counts(self) -> dict[str, int]:
        """Messages in the file per topic (chunks written; the chunk in progress is not counted)."""
        return {k: self._mcap.channel_counts[self._channel[k]] for k in self._topics}

    # -- closing ---------------------------------------------------------
    def _info(self) -> dict[str, Any]:
        m = self._mcap  # what is in the file: chunks written, not the one in progress
        topics = [dict(v, count=m.channel_counts[self._channel[k]]) for k, v in self._topics.items()]
        return _rosfmt.metadata_dict(
            relative_file=self.mcap_name, topics=topics,
            start_ns=m.t_min if m.n_messages else 0, end_ns=m.t_max if m.n_messages else 0,
            custom_data=self.custom_data,
        )

    def _write_metadata_yaml(self) -> None:
        text = _rosfmt.dump_metadata_yaml(self._info())
        self._meta_size = len(text.encode())
        tmp = self.path / "metadata.yaml.tmp"
        try:
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, self.path / "metadata.yaml")
        except OSError:
            tmp.unlink(missing_ok=True)  # the previous metadata.yaml stays
            raise

    def close(self) -> None:
        """Finish the MCAP (last chunk, summary, statistics) and write metadata.yaml. Idempotent.

        After a write failure (:attr:`failure`), close still finalises what is
        in the file: summary and metadata.yaml (``dem_ros.status: failed``,
        ``dem_ros.failure``) where the disk takes them, else the file is left
        readable up to its last complete chunk.

        Raises:
            BagError: the failure happened here, in close (a failure of
                :meth:`write` was raised there).
        """
        if self._closed:
            return
        self._closed = True
        failed_before = self.failure is not None
        cd = self.custom_data
        cd["dem_ros.mcap_compression"] = self.compression
        self._release_reserve()  # the space set aside for this
        try:
            self._mcap.finish_chunk()  # counted in the metadata below
            self._mark_status()
            self._mcap.add_metadata(
                "rosbag2", {"serialized_metadata": _rosfmt.dump_metadata_yaml(self._info(), wrap=False)}
            )
            self._mcap.finish()
        except OSError as exc:
            self._fail(exc)
            self._mark_status()
        finally:
            self._stream.close()
        try:
            self._write_metadata_yaml()
        except OSError as exc:
            if self.failure is None:
                self.failure = f"metadata.yaml not written ({exc.strerror or exc})"
        if self.failure is not None and not failed_before:
            raise BagError(f"{self.path}: {self.failure}")

    def _mark_status(self) -> None:
        self.custom_data["dem_ros.status"] = "failed" if self.failure is not None else "complete"
        if self.failure is not None:
            self.custom_data["dem_ros.failure"] = self.failure

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"bag {self.path} is closed")

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()
