"""Seeded generators for the decode fuzz tests: valid random messages of an IDL class, and mutations of their bytes.

``random_message(cls, rng)`` walks the class's cyclonedds annotations (the same
ones the codec reads), so every type in ``msgs`` gets valid samples without a
hand-written generator. ``mutate(data, rng)`` applies 1-3 of the mutations a
corrupt or hostile writer produces: bit flips, random bytes, truncation,
appended or deleted or duplicated bytes, a length/count field set to an
extreme value, invalid UTF-8, a foreign encapsulation header.
"""

from __future__ import annotations

import random
import struct
import typing
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, bounded_str, sequence

_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1), "uint8": (0, 2**8 - 1), "int16": (-(2**15), 2**15 - 1), "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1), "uint32": (0, 2**32 - 1), "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_ALPHABET = "abcxyz_/01 \u00e9\u00df\u03bc\u4e2d\U0001f600"


def _value(tp: Any, rng: random.Random) -> Any:
    if tp is str:
        return "".join(rng.choice(_ALPHABET) for _ in range(rng.randrange(0, 12)))
    if tp is bool:
        return rng.random() < 0.5
    if isinstance(tp, type) and issubclass(tp, IdlStruct):
        return random_message(tp, rng)
    meta = typing.get_args(tp)[1]
    if meta in _INT_RANGES:
        lo, hi = _INT_RANGES[meta]
        return rng.choice([lo, hi, 0, 1, rng.randint(lo, hi)])
    if meta in ("float32", "float64"):
        v = rng.choice([0.0, 1e-3, -2.5, 8e-3, rng.uniform(-1e3, 1e3)])
        return struct.unpack("<f", struct.pack("<f", v))[0] if meta == "float32" else v
    if isinstance(meta, bounded_str):
        return _value(str, rng)[: meta.max_length // 4]
    if isinstance(meta, array):
        vals = [_value(meta.subtype, rng) for _ in range(meta.length)]
        return vals
    if isinstance(meta, sequence):
        n = rng.randrange(0, (meta.max_length or 4) + 1)
        return [_value(meta.subtype, rng) for _ in range(n)]
    raise TypeError(f"no generator for {tp!r}")


def random_message(cls: type, rng: random.Random) -> Any:
    """A valid instance of the IDL struct ``cls`` with random field values."""
    hints = typing.get_type_hints(cls, include_extras=True)
    return cls(**{name: _value(tp, rng) for name, tp in hints.items()})


_EXTREME_U32 = (0, 1, 2, 3, 0x7F, 0xFF, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 0xFFFFFFFE)
_BAD_UTF8 = (b"\xff", b"\xc3", b"\xed\xa0\x80", b"\xf8\x88\x80\x80\x80", b"\xe2\x82", b"\x80")


def mutate(data: bytes, rng: random.Random) -> bytes:
    """``data`` with 1-3 random mutations (may be empty, longer or shorter)."""
    b = bytearray(data)
    for _ in range(rng.randrange(1, 4)):
        op = rng.randrange(10)
        n = len(b)
        if op == 0 and n:  # flip bits
            for _ in range(rng.randrange(1, 9)):
                i = rng.randrange(n)
                b[i] ^= 1 << rng.randrange(8)
        elif op == 1 and n:  # random bytes
            for _ in range(rng.randrange(1, 5)):
                b[rng.randrange(n)] = rng.randrange(256)
        elif op == 2:  # truncate
            del b[rng.randrange(n + 1):]
        elif op == 3:  # append
            b += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 33)))
        elif op == 4 and n > 8:  # a length / count field (aligned u32 after the header) to an extreme value
            i = 4 + 4 * rng.randrange((n - 4) // 4)
            v = rng.choice((*_EXTREME_U32, n, n - i, n - i - 4, n - i + 1, rng.randrange(2**32)))
            b[i:i + 4] = struct.pack("<I", v % 2**32)
        elif op == 5 and n > 4:  # invalid UTF-8 somewhere
            i = rng.randrange(4, n)
            bad = rng.choice(_BAD_UTF8)
            b[i:i + len(bad)] = bad
        elif op == 6 and n:  # delete a slice
            i = rng.randrange(n)
            del b[i:i + rng.randrange(1, 9)]
        elif op == 7 and n:  # duplicate a slice
            i = rng.randrange(n)
            b[i:i] = b[i:i + rng.randrange(1, 17)]
        elif op == 8 and n >= 4:  # foreign encapsulation (big-endian, XCDR2, garbage)
            b[0:2] = rng.choice((b"\x00\x00", b"\x00\x06", b"\x00\x07", b"\x00\x0b", b"\x01\x01", b"\xff\xff"))
        elif op == 9 and n > 4:  # a bool-sized byte to a value other than 0/1
            b[rng.randrange(4, n)] = rng.choice((2, 0x7F, 0x80, 0xFF))
    return bytes(b)


def corpus(cls: type, n: int, seed: int, bases: int = 64) -> list[bytes]:
    """``n`` mutated byte strings derived from ``bases`` valid random ``cls`` messages (seeded)."""
    rng = random.Random(seed)
    valid = [random_message(cls, rng).serialize() for _ in range(bases)]
    return [mutate(rng.choice(valid), rng) for _ in range(n)]
