"""Plain CDR (XCDR1) decoding that never raises anything but :class:`CdrError`, and a fast JointState codec.

Every byte string a node receives - a topic sample, a service request, a
discovery message - is decoded here (:func:`strict`, which every IDL class of the transport carries, routes
its ``deserialize`` to :func:`decode`). This module knows the IDL classes only
through their annotations and their DDS type names: it imports no message
declarations (``msgs`` imports it), and no middleware until a generic decoder is
compiled, so the bag package can use :func:`joint_state_bytes` without DDS. A byte string is either the message it
encodes or a :class:`CdrError` that says what is wrong and where (field path
and byte offset): too short, a length or sequence count larger than what is
left, a string that is not NUL-terminated or not UTF-8, a bool byte other
than 0/1, a bounded sequence over its bound, bytes left over, or an
encapsulation other than plain CDR. Nothing else escapes (no
``struct.error``, ``IndexError``, ``UnicodeDecodeError``, ``MemoryError``).

Layout (OMG CDR as rmw_cyclonedds and rosbag2 use it): a 4-byte encapsulation
header (``00 01`` little-endian or ``00 00`` big-endian, then 2 option
bytes), then the fields in declaration order, each primitive aligned to its
size counted from the end of the header; a string is ``uint32 n`` (length
including the NUL) + ``n`` bytes; a sequence is ``uint32 count`` + elements;
an array is its elements.

``sensor_msgs/msg/JointState`` (the 1 kHz type) has a hand-written codec:
cyclonedds-python's generic serializer costs ~50 us per JointState and its
deserializer ~40 us when called once per millisecond (cold caches). Its
layout::

    int32 sec, uint32 nanosec, string frame_id,
    string[] name, float64[] position, float64[] velocity, float64[] effort

The tests check every path against cyclonedds-python's and rosbags' bytes and
values, and feed the decoders mutated samples (tests/fuzz/).
"""

from __future__ import annotations

import struct
import typing
from collections.abc import Callable, Sequence
from typing import Any

from ..api import TransportError

__all__ = [
    "CdrError",
    "decode",
    "decoder",
    "encode_joint_state",
    "encoder",
    "joint_state_bytes",
    "strict",
]

#: bytes after the message that are accepted as padding (rmw pads to 4, alignment to 8)
MAX_TRAILING = 7


class CdrError(TransportError):
    """Bytes that are not a valid plain-CDR encoding of the expected ROS type (says what and where)."""


class _Bad(Exception):
    """Internal: a decode failure at ``offset`` (from the start of the data), with the field path."""

    def __init__(self, reason: str, offset: int) -> None:
        super().__init__(reason)
        self.reason = reason
        self.offset = offset
        self.path: list[str] = []


def _ros_name(cls: type) -> str:
    """``sensor_msgs::msg::dds_::JointState_`` -> ``sensor_msgs/msg/JointState``."""
    tn = getattr(cls, "__idl_typename__", cls.__name__)
    parts = tn.split("::")
    if len(parts) == 4 and parts[2] == "dds_":
        return f"{parts[0]}/{parts[1]}/{parts[3].rstrip('_')}"
    return tn


# --------------------------------------------------------------------------- generic decoder
_PRIMS: dict[str, tuple[str, int]] = {
    "int8": ("b", 1), "uint8": ("B", 1), "byte": ("B", 1), "char": ("b", 1),
    "int16": ("h", 2), "uint16": ("H", 2), "int32": ("i", 4), "uint32": ("I", 4),
    "int64": ("q", 8), "uint64": ("Q", 8), "float32": ("f", 4), "float64": ("d", 8),
}


class _Reader:
    """Cursor over one CDR buffer: ``pos`` counts from the start of ``data`` (header included)."""

    __slots__ = ("data", "end", "le", "pos")

    def __init__(self, data: bytes, pos: int, le: bool) -> None:
        self.data = data
        self.end = len(data)
        self.pos = pos
        self.le = le

    def align(self, n: int) -> None:
        self.pos += -(self.pos - 4) % n  # alignment counts from the end of the 4-byte header

    def need(self, n: int, what: str) -> None:
        if self.pos + n > self.end:
            raise _Bad(f"{what} needs {n} bytes, only {max(self.end - self.pos, 0)} left", self.pos)

    def count(self, what: str) -> int:
        self.align(4)
        self.need(4, what)
        n: int = (_U32_LE if self.le else _U32_BE).unpack_from(self.data, self.pos)[0]
        self.pos += 4
        return n


_U32_LE = struct.Struct("<I")
_U32_BE = struct.Struct(">I")


def _read_string(r: _Reader) -> str:
    start = r.pos
    n = r.count("string length")
    if n == 0:  # not what ROS writes (it counts the NUL), but unambiguous
        return ""
    if n > r.end - r.pos:
        raise _Bad(f"string length {n} exceeds the {r.end - r.pos} bytes left", start)
    raw = r.data[r.pos:r.pos + n]
    if raw[-1] != 0:
        raise _Bad(f"string of length {n} is not NUL-terminated", start)
    try:
        s = raw[:-1].decode("utf-8")
    except UnicodeDecodeError as e:
        raise _Bad(f"string is not UTF-8 ({e.reason} at byte {e.start})", start) from None
    r.pos += n
    return s


def _bounded_string_reader(bound: int) -> Callable[[_Reader], str]:
    def read(r: _Reader) -> str:
        start = r.pos
        s = _read_string(r)
        n = r.pos - start - 5  # bytes without the length field and the NUL (after alignment: <= that)
        if n > bound and len(s.encode()) > bound:
            raise _Bad(f"string of {len(s.encode())} bytes exceeds its bound {bound}", start)
        return s

    return read


def _read_bool(r: _Reader) -> bool:
    r.need(1, "bool")
    b = r.data[r.pos]
    if b > 1:
        raise _Bad(f"bool byte is {b}, not 0 or 1", r.pos)
    r.pos += 1
    return b == 1


def _prim_reader(fmt: str, size: int) -> Callable[[_Reader], Any]:
    le, be = struct.Struct("<" + fmt), struct.Struct(">" + fmt)

    def read(r: _Reader) -> Any:
        r.align(size)
        r.need(size, _FMT_NAME[fmt])
        v = (le if r.le else be).unpack_from(r.data, r.pos)[0]
        r.pos += size
        return v

    return read


_FMT_NAME = {"b": "int8", "B": "uint8", "h": "int16", "H": "uint16", "i": "int32", "I": "uint32",
             "q": "int64", "Q": "uint64", "f": "float32", "d": "float64"}


def _bulk(r: _Reader, n: int, fmt: str, size: int, as_bytes: bool) -> Any:
    """``n`` primitives of one kind (already counted); uint8 arrays come back as bytes, as cyclonedds does."""
    if n == 0:
        return b"" if as_bytes else []
    r.align(size)
    if n * size > r.end - r.pos:
        raise _Bad(f"{n} x {_FMT_NAME[fmt]} need {n * size} bytes, only {max(r.end - r.pos, 0)} left", r.pos)
    if as_bytes:
        v: Any = r.data[r.pos:r.pos + n]
    else:
        v = list(struct.unpack_from(f"{'<' if r.le else '>'}{n}{fmt}", r.data, r.pos))
    r.pos += n * size
    return v


def _bools(r: _Reader, n: int) -> list[bool]:
    r.need(n, f"{n} x bool")
    raw = r.data[r.pos:r.pos + n]
    if raw.strip(b"\x00\x01"):
        bad = next(i for i, b in enumerate(raw) if b > 1)
        raise _Bad(f"bool byte is {raw[bad]}, not 0 or 1", r.pos + bad)
    r.pos += n
    return [b == 1 for b in raw]


class _Plan:
    """How to read one IDL type: ``read(reader) -> value`` and the fewest bytes one element takes."""

    __slots__ = ("min_size", "read")

    def __init__(self, read: Callable[[_Reader], Any], min_size: int) -> None:
        self.read = read
        self.min_size = min_size


_PLANS: dict[Any, _Plan] = {}


def _plan(tp: Any) -> _Plan:
    """Compile (once) the reader of an annotation as cyclonedds-python writes it."""
    key = tp
    try:
        hit = _PLANS.get(key)
    except TypeError:  # unhashable annotation
        hit, key = None, None
    if hit is not None:
        return hit
    p = _compile(tp)
    if key is not None:
        _PLANS[key] = p
    return p


def _compile(tp: Any) -> _Plan:
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, bounded_str, sequence

    if tp is str:
        return _Plan(_read_string, 4)
    if tp is bool:
        return _Plan(_read_bool, 1)
    if isinstance(tp, type) and issubclass(tp, IdlStruct):
        return _struct_plan(tp)
    if typing.get_origin(tp) is typing.Annotated:
        meta = typing.get_args(tp)[1]
        if isinstance(meta, str) and meta in _PRIMS:
            fmt, size = _PRIMS[meta]
            return _Plan(_prim_reader(fmt, size), size)
        if isinstance(meta, (sequence, array)):
            return _container_plan(meta)
        if isinstance(meta, bounded_str):
            return _Plan(_bounded_string_reader(meta.max_length), 4)
    if tp is int or tp is float:
        raise TypeError(f"plain {tp.__name__} has no CDR size; annotate it (int32, float64, ...)")
    raise TypeError(f"no CDR decoder for annotation {tp!r}")


def _prim_of(tp: Any) -> tuple[str, int] | None:
    if typing.get_origin(tp) is typing.Annotated:
        meta = typing.get_args(tp)[1]
        if isinstance(meta, str) and meta in _PRIMS:
            return _PRIMS[meta]
    return None


def _container_plan(meta: Any) -> _Plan:
    from cyclonedds.idl.types import array

    is_array = isinstance(meta, array)
    fixed: int = meta.length if is_array else 0
    bound: int | None = None if is_array else meta.max_length
    sub = meta.subtype
    prim = _prim_of(sub)
    as_bytes = is_array and prim is not None and prim[0] == "B"
    elem = None if prim is not None or sub is bool else _plan(sub)
    elem_min = prim[1] if prim is not None else 1 if elem is None else max(elem.min_size, 1)
    kind = "array" if is_array else "sequence"

    def read(r: _Reader) -> Any:
        start = r.pos
        if is_array:
            n = fixed
        else:
            n = r.count("sequence count")
            if bound is not None and n > bound:
                raise _Bad(f"sequence count {n} exceeds its bound {bound}", start)
        if n * elem_min > r.end - r.pos:
            raise _Bad(f"{kind} count {n} needs at least {n * elem_min} bytes, only {max(r.end - r.pos, 0)} left",
                       start)
        if prim is not None:
            return _bulk(r, n, prim[0], prim[1], as_bytes)
        if elem is None:  # bool
            return _bools(r, n)
        out = []
        for i in range(n):
            try:
                out.append(elem.read(r))
            except _Bad as e:
                e.path.insert(0, f"[{i}]")
                raise
        return out

    return _Plan(read, fixed * elem_min if is_array else 4)


def _struct_plan(cls: type) -> _Plan:
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = [(name, _plan(tp)) for name, tp in hints.items()]
    new = object.__new__

    def read(r: _Reader) -> Any:
        vals = {}
        for name, p in fields:
            try:
                vals[name] = p.read(r)
            except _Bad as e:
                e.path.insert(0, name)
                raise
        obj: Any = new(cls)
        obj.__dict__.update(vals)
        return obj

    return _Plan(read, sum(p.min_size for _, p in fields))


def _header(cls: type, data: Any) -> tuple[bytes, bool]:
    """The data as bytes and whether it is little-endian; CdrError for anything not plain CDR."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise CdrError(f"{_ros_name(cls)}: expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) < 4:
        raise CdrError(f"{_ros_name(cls)}: {len(data)} bytes, shorter than the 4-byte encapsulation header")
    if data[0] != 0 or data[1] > 1:
        raise CdrError(
            f"{_ros_name(cls)}: encapsulation {data[:2].hex()} is not plain CDR (0000 big- or 0001 little-endian); "
            "ROS 2 endpoints send XCDR1"
        )
    return data, data[1] == 1


def decode(cls: type, data: Any, has_header: bool = True) -> Any:
    """The ``cls`` message (a msgs IDL struct) encoded by ``data``; :class:`CdrError` for anything else.

    ``has_header=False``: ``data`` is the little-endian body without the 4-byte header.
    """
    if not has_header:
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise CdrError(f"{_ros_name(cls)}: expected bytes, got {type(data).__name__}")
        data = b"\x00\x01\x00\x00" + bytes(data)
    return decoder(cls)(data)


def _decode_generic(cls: type, data: Any) -> Any:
    data, le = _header(cls, data)
    r = _Reader(data, 4, le)
    try:
        msg = _plan(cls).read(r)
        left = r.end - r.pos
        if left > MAX_TRAILING:
            raise _Bad(f"{left} bytes left after the message (a different type?)", r.pos)
    except _Bad as e:
        where = ".".join(e.path).replace(".[", "[")
        raise CdrError(f"{_ros_name(cls)}{': ' + where if where else ''}: {e.reason} (offset {e.offset})") from None
    except RecursionError:
        raise CdrError(f"{_ros_name(cls)}: nesting too deep") from None
    return msg


# --------------------------------------------------------------------------- JointState fast path
_HDR = b"\x00\x01\x00\x00"
_u32 = struct.Struct("<I")
_time = struct.Struct("<iI")
_unpack_u32 = _u32.unpack_from
#: the DDS type name of the one message type with a hand-written codec
JOINT_STATE = "sensor_msgs::msg::dds_::JointState_"


def _put_str(parts: list[bytes], pos: int, s: str) -> int:
    b = s.encode()
    pad = -pos % 4
    if pad:
        parts.append(b"\0" * pad)
        pos += pad
    parts.append(_u32.pack(len(b) + 1))
    parts.append(b)
    parts.append(b"\0")
    return pos + 5 + len(b)


def _put_doubles(parts: list[bytes], pos: int, seq: Sequence[float]) -> int:
    n = len(seq)
    pad = -pos % 4
    if pad:
        parts.append(b"\0" * pad)
        pos += pad
    parts.append(_u32.pack(n))
    pos += 4
    if n:
        pad = -pos % 8
        if pad:
            parts.append(b"\0" * pad)
            pos += pad
        parts.append(struct.pack(f"<{n}d", *seq))
        pos += 8 * n
    return pos


def joint_state_bytes(sec: int, nanosec: int, frame_id: str, name: Sequence[str], position: Sequence[float],
                      velocity: Sequence[float], effort: Sequence[float]) -> bytes:
    """CDR bytes (little-endian, with encapsulation header) of a ``sensor_msgs/msg/JointState``.

    ``sec``/``nanosec``: header stamp [s] and [ns] (0 <= nanosec < 1e9); the three value
    sequences are float64 (units per the topic contract: m, m/s, A or V).
    """
    parts: list[bytes] = [_HDR, _time.pack(sec, nanosec)]
    pos = _put_str(parts, 8, frame_id)
    pad = -pos % 4
    if pad:
        parts.append(b"\0" * pad)
        pos += pad
    parts.append(_u32.pack(len(name)))
    pos += 4
    for s in name:
        pos = _put_str(parts, pos, s)
    pos = _put_doubles(parts, pos, position)
    pos = _put_doubles(parts, pos, velocity)
    pos = _put_doubles(parts, pos, effort)
    return b"".join(parts)


def encode_joint_state(m: Any) -> bytes:
    """CDR bytes (with encapsulation header) of a JointState object (any class with the ROS fields)."""
    st = m.header.stamp
    return joint_state_bytes(st.sec, st.nanosec, m.header.frame_id, m.name, m.position, m.velocity, m.effort)


# Positions below count from the end of the header (body offset); data index = pos + 4.
def _get_str(data: bytes, pos: int, end: int) -> tuple[str, int]:
    pos += -pos % 4
    if pos + 4 > end:
        raise _Bad("string length needs 4 bytes", pos + 4)
    n: int = _unpack_u32(data, pos + 4)[0]
    if n == 0:
        return "", pos + 4
    if pos + 4 + n > end:
        raise _Bad(f"string length {n} exceeds the {end - pos - 4} bytes left", pos + 4)
    if data[pos + 7 + n] != 0:
        raise _Bad(f"string of length {n} is not NUL-terminated", pos + 4)
    try:
        s = data[pos + 8:pos + 7 + n].decode()
    except UnicodeDecodeError as e:
        raise _Bad(f"string is not UTF-8 ({e.reason} at byte {e.start})", pos + 4) from None
    return s, pos + 4 + n


def _get_doubles(data: bytes, pos: int, end: int) -> tuple[list[float], int]:
    pos += -pos % 4
    if pos + 4 > end:
        raise _Bad("sequence count needs 4 bytes", pos + 4)
    n: int = _unpack_u32(data, pos + 4)[0]
    pos += 4
    if not n:
        return [], pos
    pos += -pos % 8
    if pos + 8 * n > end:
        raise _Bad(f"sequence count {n} needs {8 * n} bytes, only {max(end - pos, 0)} left", pos + 4)
    return list(struct.unpack_from(f"<{n}d", data, pos + 4)), pos + 8 * n


def _joint_state_decoder(cls: type) -> Callable[[Any], Any]:
    """The fast decoder of the JointState class ``cls``; its Header and Time classes come from its annotations."""
    header_cls = typing.get_type_hints(cls)["header"]
    time_cls = typing.get_type_hints(header_cls)["stamp"]
    new = object.__new__

    def decode_joint_state(data: Any) -> Any:
        if type(data) is not bytes or len(data) < 12 or data[0] != 0 or data[1] != 1:
            # not the common little-endian case (or too short): the generic decoder says why or handles it
            return _decode_generic(cls, data)
        end = len(data) - 4  # body length
        field = "header.frame_id"
        try:
            sec, nanosec = _time.unpack_from(data, 4)
            frame_id, pos = _get_str(data, 8, end)
            field = "name"
            pos += -pos % 4
            if pos + 4 > end:
                raise _Bad("sequence count needs 4 bytes", pos + 4)
            count: int = _unpack_u32(data, pos + 4)[0]
            pos += 4
            if 4 * count > end - pos:
                raise _Bad(f"sequence count {count} needs at least {4 * count} bytes, only {end - pos} left", pos)
            names = []
            for i in range(count):
                field = f"name[{i}]"
                s, pos = _get_str(data, pos, end)
                names.append(s)
            field = "position"
            position, pos = _get_doubles(data, pos, end)
            field = "velocity"
            velocity, pos = _get_doubles(data, pos, end)
            field = "effort"
            effort, pos = _get_doubles(data, pos, end)
            if end - pos > MAX_TRAILING:
                field = ""
                raise _Bad(f"{end - pos} bytes left after the message (a different type?)", pos + 4)
        except _Bad as e:
            where = f": {field}" if field else ""
            raise CdrError(f"sensor_msgs/msg/JointState{where}: {e.reason} (offset {e.offset})") from None
        t: Any = new(time_cls)
        t.__dict__.update(sec=sec, nanosec=nanosec)
        h: Any = new(header_cls)
        h.__dict__.update(stamp=t, frame_id=frame_id)
        m: Any = new(cls)
        m.__dict__.update(header=h, name=names, position=position, velocity=velocity, effort=effort)
        return m

    return decode_joint_state


# --------------------------------------------------------------------------- codec per class
def _typename(cls: type) -> str:
    return str(getattr(cls, "__idl_typename__", ""))


_DECODERS: dict[type, Callable[[Any], Any]] = {}


def decoder(cls: type) -> Callable[[Any], Any]:
    """The fastest decoder of IDL class ``cls``: CDR bytes (with header) -> message, or :class:`CdrError`.

    Hand-written for JointState (found by DDS type name), the generic one otherwise.
    """
    dec = _DECODERS.get(cls)
    if dec is None:
        if _typename(cls) == JOINT_STATE:
            dec = _joint_state_decoder(cls)
        else:
            def dec(data: Any) -> Any:
                return _decode_generic(cls, data)
        _DECODERS[cls] = dec
    return dec


def encoder(cls: type) -> Callable[[Any], bytes] | None:
    """A hand-written encoder of IDL class ``cls`` (faster than its ``serialize``), or None."""
    return encode_joint_state if _typename(cls) == JOINT_STATE else None


def _deserialize(cls: type, data: bytes, has_header: bool = True, use_version_2: bool | None = None) -> Any:
    if use_version_2:
        raise CdrError(f"{cls.__name__}: XCDR2 is not used by ROS 2 endpoints")
    return decode(cls, data, has_header=has_header)


def strict(cls: type) -> type:
    """Class decorator: ``cls.deserialize(data)`` is :func:`decode` - a message or a ``CdrError``.

    cyclonedds-python's own deserializer raises whatever the bytes provoke
    (``struct.error``, ``IndexError``, ``UnicodeDecodeError``, ...), accepts
    some invalid input (bool bytes other than 0/1) and loops for minutes on
    some (a sequence count of ~4e9 structs); every decode of received bytes -
    the nodes' readers, the service servers and clients, typed cyclonedds
    readers - goes through this method. (A decorator, not a base class:
    cyclonedds' type-object builder walks the bases of a topic type.)
    """
    cls.deserialize = classmethod(_deserialize)  # type: ignore[attr-defined]
    return cls
