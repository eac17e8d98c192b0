"""COBS framing of link frames on a byte stream (a serial line).

Consistent Overhead Byte Stuffing (Cheshire & Baker, IEEE/ACM Trans.
Networking 7(2), 1999) rewrites a frame so that it contains no 0x00 byte; a
0x00 then delimits frames on the wire. Each frame is sent between two
delimiters (:func:`wire_frame`)::

    wire = b"\\x00" + cobs_encode(frame) + b"\\x00"

The trailing one ends the frame at once (no waiting for the next frame); the
leading one cuts off whatever line noise came before it, so noise between
frames costs no frame (the receiver ignores the empty segment between two
back-to-back delimiters). Cost: 2 bytes per frame (a sensor frame is 51 bytes).

The encoding splits the frame at its zero bytes; each block is sent as one
code byte ``c`` (1..255) followed by ``c - 1`` non-zero data bytes. ``c < 255``
means "a zero followed in the original" (except after the last block);
``c == 255`` means 254 data bytes and no zero. Overhead: at most
⌈n / 254⌉ bytes for n bytes of frame, so a 48-byte sensor frame is 49 bytes
plus the delimiter.

A receiver that starts mid-stream, or sees line noise, loses at most the
frames up to the next 0x00: :class:`Deframer` resynchronises there and counts
what it dropped.
"""

from __future__ import annotations

from collections import Counter

from .link import MAX_FRAME_SIZE

__all__ = [
    "DEFRAME_REASONS",
    "DELIMITER",
    "MAX_ENCODED_SIZE",
    "CobsError",
    "Deframer",
    "cobs_decode",
    "cobs_encode",
    "wire_frame",
]

DELIMITER = 0
MAX_ENCODED_SIZE = MAX_FRAME_SIZE + (MAX_FRAME_SIZE + 253) // 254
"""Largest COBS-encoded link frame (delimiter excluded): 129 bytes (a config frame; a sensor frame: 49)."""

DEFRAME_REASONS = ("cobs", "oversize")
"""Why a :class:`Deframer` dropped bytes: invalid COBS, or more bytes than any frame before a delimiter."""


class CobsError(ValueError):
    """The bytes are not a valid COBS encoding (a code byte of zero, or a block overrunning the end)."""


def cobs_encode(data: bytes | bytearray | memoryview) -> bytes:
    """COBS-encode ``data``: the result has no 0x00 byte and ⌈n/254⌉ bytes at most of overhead."""
    out = bytearray()
    for part in bytes(data).split(b"\x00"):  # each part is followed by a zero, except the last
        while len(part) >= 254:  # a full block: code 255, no zero implied
            out.append(255)
            out += part[:254]
            part = part[254:]
        out.append(len(part) + 1)
        out += part
    return bytes(out)


def cobs_decode(data: bytes | bytearray | memoryview) -> bytes:
    """Invert :func:`cobs_encode` (the delimiter excluded).

    Raises:
        CobsError: a zero byte inside the encoding, or a code byte pointing past the end.
    """
    src = bytes(data)
    n = len(src)
    if n == 0:
        raise CobsError("empty COBS block")
    z = src.find(0)
    if z >= 0:
        raise CobsError(f"zero byte at offset {z}")
    out = bytearray()
    i = 0
    while i < n:
        code = src[i]
        end = i + code
        if end > n:
            raise CobsError(f"code byte {code} at offset {i} runs past the end ({n} bytes)")
        out += src[i + 1 : end]
        i = end
        if code < 255 and i < n:
            out.append(0)
    return bytes(out)


def wire_frame(frame: bytes | bytearray | memoryview) -> bytes:
    """The bytes a sender puts on a serial line for one frame: 0x00, COBS(frame), 0x00."""
    return b"\x00" + cobs_encode(frame) + b"\x00"


class Deframer:
    """Split a byte stream into COBS-decoded frames, resynchronising on garbage.

    Feed whatever the line delivered (any split, any garbage); get back the
    decoded frames completed by a 0x00 delimiter. Bytes that cannot be a frame
    are dropped and counted by reason in :attr:`dropped` (``"cobs"``: the bytes
    before a delimiter are not valid COBS; ``"oversize"``: more than
    ``max_encoded`` bytes without a delimiter, discarded up to the next one).
    Empty segments (back-to-back delimiters, used by a sender to flush a
    receiver) are ignored. The frames returned are NOT checked further: pass
    each to :func:`dem_ros.hardware.link.decode`.

    Memory is bounded: the pending buffer never exceeds ``max_encoded`` bytes.
    """

    def __init__(self, max_encoded: int = MAX_ENCODED_SIZE) -> None:
        if max_encoded < 2:
            raise ValueError(f"max_encoded={max_encoded} must be at least 2")
        self.max_encoded = max_encoded
        self.dropped: Counter[str] = Counter({r: 0 for r in DEFRAME_REASONS})
        self.frames = 0
        self._buf = bytearray()
        self._skipping = False  # inside an oversize run: discard up to the next delimiter

    def reset(self) -> None:
        """Forget a partial frame (e.g. after reopening the port); counters stay."""
        self._buf.clear()
        self._skipping = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[bytes]:
        """Append received bytes; return the frames they complete, in order."""
        out: list[bytes] = []
        mv = bytes(data)
        start = 0
        while start <= len(mv):
            z = mv.find(b"\x00", start)
            chunk = mv[start:] if z < 0 else mv[start:z]
            if not self._skipping:
                if len(self._buf) + len(chunk) > self.max_encoded:
                    self.dropped["oversize"] += 1
                    self._buf.clear()
                    self._skipping = True
                else:
                    self._buf += chunk
            if z < 0:
                break
            # a delimiter: close the current segment
            if self._skipping:
                self._skipping = False
            elif self._buf:
                try:
                    out.append(cobs_decode(self._buf))
                    self.frames += 1
                except CobsError:
                    self.dropped["cobs"] += 1
            self._buf.clear()
            start = z + 1
        return out
