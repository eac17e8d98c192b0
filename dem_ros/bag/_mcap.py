"""A small MCAP reader that survives truncation.

Complete files are read through their summary (footer -> summary section:
schemas, channels, statistics, chunk indexes, metadata indexes). A file
without a valid footer (writer killed) is scanned record by record from the
start; the scan stops at the first record that runs past the end of the file
or has an unknown opcode, and says where. Every complete chunk before that
point is readable, because a chunk record is written in one piece.

Record layout (mcap.dev/spec): ``opcode u8 | length u64 | content``; strings
are ``u32 length + UTF-8``, maps are ``u32 byte length + pairs``.
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .errors import BagError

__all__ = ["MAGIC", "Channel", "ChunkInfo", "McapFile", "Schema", "Statistics", "Truncation"]

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 7, 8, 9, 10
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 11, 12, 13, 14, 15

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQI")
_STATS = struct.Struct("<QHIIIIQQ")


@dataclass(frozen=True)
class Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class Statistics:
    """The MCAP Statistics record: counts, and the log-time range [ns] of the messages."""

    message_count: int
    schema_count: int
    channel_count: int
    attachment_count: int
    metadata_count: int
    chunk_count: int
    message_start_time: int
    message_end_time: int
    channel_message_counts: dict[int, int]  # channel id -> messages


@dataclass
class ChunkInfo:
    """One chunk: file offset, record length, log-time range (ns), compression."""

    offset: int
    length: int
    start_ns: int
    end_ns: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages (scan only)
    index: int = 0  # position in the file's chunk list (0-based, file order)

    def describe(self) -> str:
        """How a report names this chunk: number, byte offset and log-time range."""
        return f"chunk {self.index} at offset {self.offset} (log time {self.start_ns}..{self.end_ns} ns)"


@dataclass(frozen=True)
class Truncation:
    """Where a file without a valid footer stops being readable."""

    offset: int  # byte offset of the first unreadable byte
    file_size: int
    reason: str


class _Buf:
    """Cursor over a bytes-like object."""

    __slots__ = ("b", "p")

    def __init__(self, b: bytes | memoryview, p: int = 0) -> None:
        self.b, self.p = b, p

    def u16(self) -> int:
        (v,) = _U16.unpack_from(self.b, self.p)
        self.p += 2
        return int(v)

    def u32(self) -> int:
        (v,) = _U32.unpack_from(self.b, self.p)
        self.p += 4
        return int(v)

    def u64(self) -> int:
        (v,) = _U64.unpack_from(self.b, self.p)
        self.p += 8
        return int(v)

    def raw(self, n: int) -> bytes:
        if self.p + n > len(self.b):
            raise struct.error("field runs past end of record")
        v = bytes(self.b[self.p:self.p + n])
        self.p += n
        return v

    def string(self) -> str:
        return self.raw(self.u32()).decode("utf-8")

    def str_map(self) -> dict[str, str]:
        n = self.u32()
        end = self.p + n
        out = {}
        while self.p < end:
            k = self.string()
            out[k] = self.string()
        return out


def parse_schema(b: memoryview) -> Schema:
    c = _Buf(b)
    sid, name, enc = c.u16(), c.string(), c.string()
    return Schema(sid, name, enc, c.raw(c.u32()))


def parse_channel(b: memoryview) -> Channel:
    c = _Buf(b)
    cid, sid, topic, enc = c.u16(), c.u16(), c.string(), c.string()
    return Channel(cid, sid, topic, enc, c.str_map())


def parse_metadata(b: memoryview) -> tuple[str, dict[str, str]]:
    c = _Buf(b)
    return c.string(), c.str_map()


def decompress(compression: str, data: bytes | memoryview, size: int) -> bytes | memoryview:
    """Chunk payload; ``size`` is the uncompressed size from the chunk header."""
    if compression == "":
        return data
    if compression == "zstd":
        try:
            import zstandard
        except ImportError:  # pragma: no cover - zstandard is a dependency
            raise BagError("chunk is zstd-compressed but the 'zstandard' package is missing") from None
        out: bytes = zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size)
        return out
    if compression == "lz4":
        try:
            import lz4.frame
        except ImportError:  # pragma: no cover
            raise BagError("chunk is lz4-compressed but the 'lz4' package is missing") from None
        raw: bytes = lz4.frame.decompress(bytes(data))
        return raw
    raise BagError(f"unsupported chunk compression {compression!r}")


class McapFile:
    """Random access to one MCAP file (memory-mapped).

    Attributes after opening: ``profile``, ``library``, ``schemas`` (id ->
    :class:`Schema`), ``channels`` (id -> :class:`Channel`), ``chunks`` (in
    file order), ``metadata`` (list of (name, dict) in file order),
    ``statistics`` (:class:`Statistics` or None), ``has_summary``, ``truncation`` (None for a
    complete file), ``loose_messages`` (offsets of Message records outside
    chunks).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        try:
            self._f = self.path.open("rb")
        except OSError as exc:
            raise BagError(f"cannot open {self.path}: {exc.strerror}") from None
        self.size = self.path.stat().st_size
        if self.size < len(MAGIC) + 9:
            self._f.close()
            if self.size == 0:
                raise BagError(f"{self.path} is empty (0 bytes): not an MCAP file")
            raise BagError(f"{self.path} is too short ({self.size} bytes) to be an MCAP file")
        self._mm = mmap.mmap(self._f.fileno(), 0, access=mmap.ACCESS_READ)
        self.buf = memoryview(self._mm)
        head = bytes(self.buf[:8])
        if head != MAGIC:
            self.close()
            raise BagError(f"{self.path} is not an MCAP file (starts with {head!r}, not the MCAP magic)")
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunks: list[ChunkInfo] = []
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self.statistics: Statistics | None = None
        self.has_summary = False
        self.truncation: Truncation | None = None
        self.loose_messages: list[int] = []
        #: chunk offset -> why it cannot be read (found by a scan or :meth:`verify_chunks`)
        self.bad_chunks: dict[int, str] = {}
        self._reported: set[int] = set()
        self.profile = self.library = ""
        try:
            self._read_header()
            if not self._read_summary():
                self._scan()
        except BagError:
            self.close()
            raise
        except (struct.error, UnicodeDecodeError, ValueError) as exc:
            self.close()
            raise BagError(f"{self.path}: malformed MCAP record ({exc})") from None

    # -- opening ---------------------------------------------------------
    def _record(self, pos: int) -> tuple[int, int, int]:
        """(opcode, content start, content end) of the record at ``pos``."""
        op, ln = _REC.unpack_from(self.buf, pos)
        return op, pos + 9, pos + 9 + ln

    def _read_header(self) -> None:
        op, s, e = self._record(8)
        if op != OP_HEADER or e > self.size:
            raise BagError(f"{self.path}: MCAP header record missing or cut off")
        c = _Buf(self.buf[s:e])
        self.profile, self.library = c.string(), c.string()
        self.data_start = e

    def _read_summary(self) -> bool:
        """Use footer + summary if the file is complete; False if it is not."""
        if self.size < 8 + 9 + 29 + 8 or bytes(self.buf[-8:]) != MAGIC:
            return False
        fpos = self.size - 8 - 29
        op, s, e = self._record(fpos)
        if op != OP_FOOTER or e != self.size - 8:
            return False
        summary_start, _summary_offset_start = _U64.unpack_from(self.buf, s)[0], _U64.unpack_from(self.buf, s + 8)[0]
        if summary_start == 0 or not self.data_start <= summary_start <= fpos:
            return False
        pos = summary_start
        chunk_index: list[ChunkInfo] = []
        meta_index: list[tuple[int, int]] = []
        while pos < fpos:
            op, s, e = self._record(pos)
            if e > fpos:
                return False
            b = self.buf[s:e]
            if op == OP_SCHEMA:
                sc = parse_schema(b)
                self.schemas[sc.id] = sc
            elif op == OP_CHANNEL:
                ch = parse_channel(b)
                self.channels[ch.id] = ch
            elif op == OP_STATISTICS:
                self.statistics = self._parse_stats(b)
            elif op == OP_CHUNK_INDEX:
                c = _Buf(b)
                start, end, off, ln = c.u64(), c.u64(), c.u64(), c.u64()
                n_idx = c.u32()  # message index offsets map, skipped
                c.p += n_idx
                c.u64()  # message index length
                comp = c.string()
                chunk_index.append(ChunkInfo(off, ln, start, end, comp, c.u64(), c.u64()))
            elif op == OP_METADATA_INDEX:
                c = _Buf(b)
                meta_index.append((c.u64(), c.u64()))
            pos = e
        if not chunk_index and self.statistics and self.statistics.message_count:
            return False  # unchunked file: messages must be found by scanning
        self.chunks = sorted(chunk_index, key=lambda ch: ch.offset)
        for i, chunk in enumerate(self.chunks):
            chunk.index = i
        for off, _ln in meta_index:
            op, s, e = self._record(off)
            if op == OP_METADATA:
                self.metadata.append(parse_metadata(self.buf[s:e]))
        self.has_summary = True
        return True

    @staticmethod
    def _parse_stats(b: memoryview) -> Statistics:
        (msgs, n_schema, n_chan, n_att, n_meta, n_chunk, t0, t1) = _STATS.unpack_from(b, 0)
        c = _Buf(b, _STATS.size)
        n = c.u32()
        end = c.p + n
        counts = {}
        while c.p < end:
            cid = c.u16()
            counts[cid] = c.u64()
        return Statistics(message_count=msgs, schema_count=n_schema, channel_count=n_chan,
                          attachment_count=n_att, metadata_count=n_meta, chunk_count=n_chunk,
                          message_start_time=t0, message_end_time=t1, channel_message_counts=counts)

    def _scan(self) -> None:
        """Walk the data section record by record (file without usable summary)."""
        pos = self.data_start
        stop: Truncation | None = None
        while pos < self.size:
            if pos + 9 > self.size:
                stop = Truncation(pos, self.size, "record header cut off")
                break
            op, s, e = self._record(pos)
            if op == 0 or op > 0x0F:
                if bytes(self.buf[pos:pos + 8]) == MAGIC and pos + 8 == self.size:
                    break
                stop = Truncation(pos, self.size, f"unknown opcode 0x{op:02x} (garbage or partial write)")
                break
            if e > self.size:
                stop = Truncation(pos, self.size, f"record (opcode 0x{op:02x}, {e - s} bytes) cut off")
                break
            b = self.buf[s:e]
            if op == OP_FOOTER:
                break
            elif op == OP_SCHEMA:
                sc = parse_schema(b)
                self.schemas[sc.id] = sc
            elif op == OP_CHANNEL:
                ch = parse_channel(b)
                self.channels[ch.id] = ch
            elif op == OP_METADATA:
                self.metadata.append(parse_metadata(b))
            elif op == OP_MESSAGE:
                self.loose_messages.append(pos)
            elif op == OP_CHUNK:
                start, end, usize, _crc = _CHUNK_HEAD.unpack_from(b, 0)
                c = _Buf(b, _CHUNK_HEAD.size)
                comp = c.string()
                clen = c.u64()
                info = ChunkInfo(pos, e - pos, start, end, comp, clen, usize, index=len(self.chunks))
                try:
                    data = self._payload(info, b)
                    records = list(_records(data))
                except BagError as exc:  # a damaged chunk: later ones may be fine; reads of this one fail
                    self.bad_chunks[info.offset] = str(exc)
                    self.chunks.append(info)
                    pos = e
                    continue
                for op2, s2, e2 in records:
                    if op2 == OP_MESSAGE:
                        cid = _U16.unpack_from(data, s2)[0]
                        info.counts[cid] = info.counts.get(cid, 0) + 1
                    elif op2 == OP_SCHEMA:
                        sc = parse_schema(memoryview(data)[s2:e2])
                        self.schemas[sc.id] = sc
                    elif op2 == OP_CHANNEL:
                        ch = parse_channel(memoryview(data)[s2:e2])
                        self.channels[ch.id] = ch
                self.chunks.append(info)
            pos = e
        self.truncation = stop if stop is not None else (
            None if self._ends_with_footer() else Truncation(pos, self.size, "no footer")
        )

    def _ends_with_footer(self) -> bool:
        return bytes(self.buf[-8:]) == MAGIC and self.size > 8 + 9

    # -- reading ---------------------------------------------------------
    def chunk_data(self, ch: ChunkInfo) -> bytes | memoryview:
        """The chunk's records, decompressed and checked against the chunk's CRC-32 and size.

        Raises:
            BagError: naming the chunk, when it does not decompress or its CRC or size do not match.
        """
        op, s, e = self._record(ch.offset)
        if op != OP_CHUNK or e > self.size:
            raise BagError(f"{self.path}: no chunk record at offset {ch.offset} (index is wrong)")
        return self._payload(ch, self.buf[s:e])

    def _payload(self, ch: ChunkInfo, b: memoryview) -> bytes | memoryview:
        try:
            _start, _end, usize, crc = _CHUNK_HEAD.unpack_from(b, 0)
            c = _Buf(b, _CHUNK_HEAD.size)
            comp = c.string()
            clen = c.u64()
            packed = b[c.p:c.p + clen]
            if c.p + clen > len(b):
                raise ValueError("compressed data run past the chunk record")
        except (struct.error, ValueError, UnicodeDecodeError) as exc:
            raise BagError(f"{self.path}: {ch.describe()}: malformed chunk header ({exc})") from None
        try:
            data = decompress(comp, packed, usize)
        except BagError:
            raise
        except Exception as exc:  # corrupt compressed payload
            raise BagError(f"{self.path}: {ch.describe()} does not decompress ({exc})") from None
        if len(data) != usize:
            raise BagError(f"{self.path}: {ch.describe()}: {len(data)} bytes after decompression, "
                           f"the header says {usize}: the chunk is corrupt")
        if crc != 0:  # 0: the writer did not compute one (mcap spec)
            got = zlib.crc32(data)
            if got != crc:
                raise BagError(f"{self.path}: {ch.describe()}: CRC-32 {got:#010x} of the data does not match "
                               f"the stored {crc:#010x}: the chunk is corrupt")
        return data

    def verify_chunks(self) -> list[str]:
        """Decompress and CRC-check every chunk; the problems, one line each (empty: all good).

        Chunks reported here are skipped by :meth:`iter_raw` afterwards (the
        caller has been told); without this call a read of a bad chunk raises.
        """
        for ch in self.chunks:
            if ch.offset in self.bad_chunks:
                continue
            try:
                self.chunk_data(ch)
            except BagError as exc:
                self.bad_chunks[ch.offset] = str(exc)
        self._reported = set(self.bad_chunks)
        return [self.bad_chunks[ch.offset] for ch in self.chunks if ch.offset in self.bad_chunks]

    def file_size_unread(self) -> int:
        """Bytes after the truncation point (0 for a complete file)."""
        return 0 if self.truncation is None else self.size - self.truncation.offset

    def loose_channel_ids(self) -> Iterator[int]:
        """Channel id of each Message record outside chunks (unchunked files)."""
        for off in self.loose_messages:
            yield _U16.unpack_from(self.buf, off + 9)[0]

    def iter_raw(self, channel_ids: set[int] | None = None) -> Iterator[tuple[int, int, int, memoryview]]:
        """Yield ``(channel_id, log_time_ns, publish_time_ns, data)`` in file order."""
        unpack = _MSG.unpack_from
        for off in self.loose_messages:
            _op, s, e = self._record(off)
            cid, _seq, lt, pt = unpack(self.buf, s)
            if channel_ids is None or cid in channel_ids:
                yield cid, lt, pt, self.buf[s + 22:e]
        for ch in self.chunks:
            if channel_ids is not None and ch.counts and not (channel_ids & ch.counts.keys()):
                continue
            if ch.offset in self._reported:
                continue  # reported by verify_chunks(); the rest of the file is still read
            if ch.offset in self.bad_chunks:
                raise BagError(self.bad_chunks[ch.offset])
            data = memoryview(self.chunk_data(ch))
            for op, s, e in _records(data):
                if op == OP_MESSAGE:
                    cid, _seq, lt, pt = unpack(data, s)
                    if channel_ids is None or cid in channel_ids:
                        yield cid, lt, pt, data[s + 22:e]

    def close(self) -> None:
        try:
            self.buf.release()
            self._mm.close()
        except (AttributeError, BufferError):
            pass
        self._f.close()


def _records(data: bytes | memoryview) -> Iterator[tuple[int, int, int]]:
    """(opcode, content start, content end) for the records inside a chunk."""
    pos, n = 0, len(data)
    unpack = _REC.unpack_from
    while pos + 9 <= n:
        op, ln = unpack(data, pos)
        s = pos + 9
        pos = s + ln
        if pos > n:
            raise BagError(f"record inside chunk runs past the chunk end ({pos} > {n})")
        yield op, s, pos
