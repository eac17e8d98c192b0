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

Run metadata: ``metadata.yaml`` ``custom_data`` (string map, present since
metadata version 6) carries ``dem_ros.run_info`` (JSON of the metadata dict)
and ``dem_ros.version``; the same map is in the ``rosbag2`` Metadata record
(``serialized_metadata``) that Jazzy reads, and in the ``dem_ros`` record.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from dem_ros import __version__
from dem_ros.contract import QoS

from . import _rosfmt
from .errors import BagError

__all__ = ["BagWriter", "COMPRESSIONS"]

COMPRESSIONS = ("zstd", "lz4", "none")
#: rosbag2_storage_mcap's default chunk size (mcap C++ McapWriterOptions: 768 KiB).
DEFAULT_CHUNK_SIZE = 768 * 1024


class _DirectStream:
    """Write-only file stream without user-space buffering (survives SIGKILL)."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.pos = 0
        self.writes = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        n = len(view)
        while view:
            k = os.write(self.fd, view)
            view = view[k:]
        self.pos += n
        self.writes += 1
        return n

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self.fd >= 0:
            try:
                os.fsync(self.fd)
            finally:
                os.close(self.fd)
                self.fd = -1


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
        from mcap.writer import CompressionType, Writer

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
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_name = f"{self.path.name}_0.mcap"
        self.compression = compression
        self.chunk_size = chunk_size
        self.flush_interval_s = flush_interval_s
        self.metadata_refresh_s = metadata_refresh_s
        self.custom_data: dict[str, str] = {"dem_ros.version": __version__, "dem_ros.status": "recording"}
        if self.run_metadata is not None:
            self.custom_data["dem_ros.run_info"] = json.dumps(self.run_metadata, sort_keys=True)

        self._stream = _DirectStream(self.path / self.mcap_name)
        ctype = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        self._mcap = Writer(self._stream, chunk_size=chunk_size, compression=ctype[compression])
        self._mcap.start(profile="ros2", library=f"dem_ros-{__version__}")
        self._mcap.add_metadata("dem_ros", dict(self.custom_data))
        self._topics: dict[str, dict[str, Any]] = {}
        self._channel: dict[str, int] = {}
        self._schema: dict[str, int] = {}
        self._start = 2**63 - 1
        self._end = 0
        self._count = 0
        self._chunk_open_since: float | None = None
        self._last_refresh = time.monotonic()
        self._closed = False
        self._write_metadata_yaml()

    # -- topics ----------------------------------------------------------
    def add_topic(self, name: str, type_name: str, qos: QoS) -> None:
        """Register ``name`` (ROS type ``pkg/msg/Type``) with its offered QoS."""
        self._check_open()
        if name in self._topics:
            if self._topics[name]["type"] != type_name:
                raise BagError(f"topic {name!r} already added with type {self._topics[name]['type']!r}")
            return
        text = _rosfmt.msgdef(type_name)
        rihs = _rosfmt.type_hash(type_name)
        if type_name not in self._schema:
            self._schema[type_name] = self._mcap.register_schema(type_name, "ros2msg", text.encode())
        qos_string = _rosfmt.qos_to_v8_string(qos)
        self._channel[name] = self._mcap.register_channel(
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
    def write(self, topic: str, log_time_ns: int, cdr_bytes: bytes, publish_time_ns: int | None = None) -> None:
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
        if self._closed:
            self._check_open()
        t = int(log_time_ns)
        before = self._stream.writes
        self._mcap.add_message(cid, t, cdr_bytes, t if publish_time_ns is None else int(publish_time_ns))
        self._topics[topic]["count"] += 1
        self._count += 1
        if t < self._start:
            self._start = t
        if t > self._end:
            self._end = t
        now = time.monotonic()
        if self._stream.writes != before:  # a chunk was just written
            self._chunk_open_since = None
            self._after_chunk(now)
        elif self._chunk_open_since is None:
            self._chunk_open_since = now
        elif now - self._chunk_open_since > self.flush_interval_s:
            self.flush()

    def flush(self) -> None:
        """Write the chunk in progress now (smaller chunks compress less well)."""
        self._check_open()
        self._mcap.flush()
        self._chunk_open_since = None
        self._after_chunk(time.monotonic())

    def _after_chunk(self, now: float) -> None:
        if now - self._last_refresh >= self.metadata_refresh_s:
            self._last_refresh = now
            self._write_metadata_yaml()

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return {k: int(v["count"]) for k, v in self._topics.items()}

    # -- closing ---------------------------------------------------------
    def _info(self) -> dict[str, Any]:
        return _rosfmt.metadata_dict(
            relative_file=self.mcap_name, topics=list(self._topics.values()),
            start_ns=self._start, end_ns=self._end, custom_data=self.custom_data,
        )

    def _write_metadata_yaml(self) -> None:
        text = _rosfmt.dump_metadata_yaml(self._info())
        tmp = self.path / "metadata.yaml.tmp"
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, self.path / "metadata.yaml")

    def close(self) -> None:
        """Finish the MCAP (last chunk, summary, statistics) and write metadata.yaml.

        Idempotent.
        """
        if self._closed:
            return
        self._closed = True
        self.custom_data["dem_ros.status"] = "complete"
        self.custom_data["dem_ros.mcap_compression"] = self.compression
        try:
            self._mcap.add_metadata(
                "rosbag2", {"serialized_metadata": _rosfmt.dump_metadata_yaml(self._info(), wrap=False)}
            )
            self._mcap.finish()
        finally:
            self._stream.close()
        self._write_metadata_yaml()

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
