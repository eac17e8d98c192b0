"""Frames of the board ↔ PC device link: layout, ``encode``, ``decode``.

The board (an I/O board or microcontroller beside the rig) is the clock: every
sample period it samples the two gap sensors and the two coil currents, sends a
:class:`SensorFrame`, and applies the newest :class:`CommandFrame` it has
received. A :class:`Hello` exchange opens the link; a :class:`ConfigFrame` then sets
the board's configuration (its safety specs, nominal plant, sensor calibration and
command delay) and the board answers with a :class:`ConfigAck` carrying the CRC-32 of
the configuration it runs. The full protocol (roles,
timing, watchdog, transports, error handling) is in ``docs/hardware-link.md``;
the shared test vectors ``tests/hardware/vectors/frames.txt`` define it and the
C codec in ``firmware/`` passes the same vectors.

Every frame is little-endian with a fixed layout::

    offset size field
    0      1    version   protocol version (PROTOCOL_VERSION)
    1      1    type      FrameType (HELLO=1, SENSOR=2, COMMAND=3, CONFIG=4, CONFIG_ACK=5)
    2      2    length    total frame length in bytes, CRC included (u16)
    4      n    payload   fixed per type (see each class)
    4+n    4    crc       CRC-32 (zlib/IEEE 802.3) of bytes [0, 4+n)

Sizes: Hello 24 bytes, SensorFrame 48 bytes, CommandFrame 24 bytes, ConfigFrame 128
bytes, ConfigAck 20 bytes. Reserved
bytes are sent as zero and a frame with a non-zero reserved byte is rejected
(they are free for a later protocol version, not for private use).

Floats are IEEE-754 binary32: a value survives ``decode(encode(f))`` exactly
only if it is representable in float32 (``encode(decode(b)) == b`` always
holds for a valid frame). Non-finite floats (NaN, ±inf) are refused by both
``encode`` and ``decode``: a NaN voltage must never reach a coil driver.

``decode`` never raises anything but :class:`LinkError`, whose ``reason`` is
one of :data:`REASONS`, so a receiver counts rejections by reason.
"""

from __future__ import annotations

import enum
import math
import struct
import zlib
from dataclasses import dataclass

from ..board.modes import Mode  # the board's modes: one definition, shared with the Supervisor

__all__ = [
    "COMMAND_MODES",
    "COMMAND_SIZE",
    "CONFIG_ACK_SIZE",
    "CONFIG_CAL_KEYS",
    "CONFIG_KEYS",
    "CONFIG_RESULTS",
    "CONFIG_SIZE",
    "CONFIG_SUP_KEYS",
    "HEADER",
    "HELLO_REQUEST",
    "HELLO_SIZE",
    "MAX_FRAME_SIZE",
    "PROTOCOL_VERSION",
    "REASONS",
    "SENSOR_SIZE",
    "STATUS_DEFINED",
    "CommandFrame",
    "ConfigAck",
    "ConfigFrame",
    "Frame",
    "FrameType",
    "Hello",
    "LinkError",
    "Mode",
    "SensorFrame",
    "Status",
    "decode",
    "encode",
    "seq_diff",
]

PROTOCOL_VERSION = 1
"""The version byte of every sensor and command frame this codec speaks."""


COMMAND_MODES = frozenset({Mode.OFF, Mode.RUN, Mode.HOLD, Mode.LAND})
"""The modes a command frame may request (LANDED and FAULT are states, not requests)."""


class FrameType(enum.IntEnum):
    """The type byte of the header."""

    HELLO = 1
    SENSOR = 2
    COMMAND = 3
    CONFIG = 4
    CONFIG_ACK = 5


class Status(enum.IntFlag):
    """Status and fault bits of a sensor frame (u32); each bit reports this sample.

    Bits 18-31 are reserved (sent as zero; a receiver ignores them so a later
    board can add bits without breaking an older PC: 16 and 17 were added so).
    """

    GAP0_RANGE = 1 << 0  # gap sensor 1 out of its range (ADC at 0 or full scale, or sensor missing)
    GAP1_RANGE = 1 << 1  # gap sensor 2 out of its range
    CURRENT0_LIMIT = 1 << 2  # coil 1 current above the board's hardware limit (tripped)
    CURRENT1_LIMIT = 1 << 3  # coil 2 current above the board's hardware limit (tripped)
    DRIVER0_FAULT = 1 << 4  # coil driver 1 reports a fault (bridge fault pin, over-temperature)
    DRIVER1_FAULT = 1 << 5  # coil driver 2 reports a fault
    BUS_UNDERVOLTAGE = 1 << 6  # DC bus below the driver's minimum
    BUS_OVERVOLTAGE = 1 << 7  # DC bus above the driver's maximum
    LINK_TIMEOUT = 1 << 8  # no valid command within the board's link watchdog: landing
    COMMAND_LATE = 1 << 9  # no fresh command for the previous sample: the last voltage was held
    RX_ERROR = 1 << 10  # the board rejected a frame (CRC, length, ...) since its previous sensor frame
    VOLTAGE_CLIPPED = 1 << 11  # the commanded voltage exceeded the driver's limit and was clipped
    ESTOP = 1 << 12  # the hardware emergency-stop input is active
    OVERRUN = 1 << 13  # the board missed its own sample deadline
    GAP_LIMIT = 1 << 14  # a gap outside the board's safe band (tripped)
    ADC_FAULT = 1 << 15  # the ADC conversion failed or timed out
    GAP0_IMPLAUSIBLE = 1 << 16  # gap sensor 1 contradicts coil 1's flux: ignored, landing on the flux (latched)
    GAP1_IMPLAUSIBLE = 1 << 17  # gap sensor 2 contradicts coil 2's flux (latched)


STATUS_DEFINED = 0x3FFFF
"""Mask of the status bits defined by this protocol version."""

REASONS = (
    "short",  # fewer bytes than a header + CRC
    "length",  # the header's length field differs from the bytes received
    "crc",  # CRC-32 mismatch
    "version",  # a sensor/command frame of another protocol version
    "type",  # unknown type byte
    "size",  # the length does not match the type's fixed size
    "reserved",  # a reserved byte is not zero
    "mode",  # a mode byte outside Mode, or a command requesting LANDED/FAULT
    "nonfinite",  # a float field is NaN or infinite
    "range",  # a field outside its documented range (e.g. adc_bits > 16)
)
"""Why a frame was rejected: the values of :attr:`LinkError.reason`, in check order."""

#: the configuration frame's floats, in its order: the supervisor's (firmware ``sup_config_t``: the safety specs,
#: the nominal plant, the sample period) then the sensors' calibration (``board_config_t``: gap polynomials, current
#: gains, current offsets). The names are the ``hw_driver`` group's parameters (docs/hardware-link.md, "Config").
CONFIG_SUP_KEYS = ("u_max", "i_max", "trip_gap_min", "trip_gap_max", "hold_timeout", "landing_gap", "landing_speed",
                   "m", "R", "K", "L", "l", "I", "N1", "N2", "g", "dt")
CONFIG_CAL_KEYS = ("gap1_c0", "gap1_c1", "gap1_c2", "gap1_c3", "gap2_c0", "gap2_c1", "gap2_c2", "gap2_c3",
                   "current1_gain", "current2_gain", "current1_offset", "current2_offset")
CONFIG_KEYS = CONFIG_SUP_KEYS + CONFIG_CAL_KEYS

CONFIG_RESULTS = (
    "ok",  # accepted (or already the active one): the board runs it
    "not_positive",  # a value that must be positive is not (firmware SUP_CFG_NOT_POSITIVE)
    "gap_order",  # not 0 <= trip_gap_min < landing_gap <= trip_gap_max (SUP_CFG_GAP_ORDER)
    "arms",  # not l < L (SUP_CFG_ARMS)
    "no_braking",  # the loads leave no pull away from the rail at an end (SUP_CFG_NO_BRAKING)
    "nonfinite",  # a value is not finite (SUP_CFG_NONFINITE)
    "delay",  # command_delay outside the board's range (1 .. its command ring - 1)
    "rate",  # dt is not the board's own sample period (a board does not change its clock over the link)
    "busy",  # the board is not OFF or LANDED: a configuration never changes in flight
)
"""The ``result`` byte of a :class:`ConfigAck`: its index here (codes 1-5 are the firmware's ``sup_cfg_result``)."""


class LinkError(ValueError):
    """A frame could not be encoded or decoded.

    ``reason`` is one of :data:`REASONS` (count rejections by it); the message
    says what was wrong in words, to be printed without a traceback.
    """

    def __init__(self, reason: str, message: str) -> None:
        if reason not in REASONS:  # pragma: no cover - a programming error in this module
            raise AssertionError(f"unknown LinkError reason {reason!r}")
        super().__init__(f"{reason}: {message}")
        self.reason = reason


# --- layouts (struct formats, little-endian, no implicit padding) ---------------------------
HEADER = struct.Struct("<BBH")  # version, type, length
_CRC = struct.Struct("<I")
# board_id u32, rate_hz u32, adc_bits u8, command_delay u8, watchdog_ms u16, adc_vref f32
_HELLO = struct.Struct("<IIBBHf")
# seq u32, board_time_us u64, gap_counts 2×u16, current_counts 2×u16, applied_v 2×f32,
# bus_v f32, status u32, mode u8, reserved 3×u8
_SENSOR = struct.Struct("<IQHHHHfffIB3s")
# seq u32, u 2×f32, mode u8, reserved 3×u8
_COMMAND = struct.Struct("<IffB3s")
# 29×f32 (CONFIG_KEYS), command_delay u8, reserved 3×u8
_CONFIG = struct.Struct(f"<{len(CONFIG_KEYS)}fB3s")
# active_crc u32, request_crc u32, result u8, configured u8, mode u8, reserved u8
_CONFIG_ACK = struct.Struct("<IIBBB1s")

HELLO_SIZE = HEADER.size + _HELLO.size + _CRC.size  # 24
SENSOR_SIZE = HEADER.size + _SENSOR.size + _CRC.size  # 48
COMMAND_SIZE = HEADER.size + _COMMAND.size + _CRC.size  # 24
CONFIG_SIZE = HEADER.size + _CONFIG.size + _CRC.size  # 128
CONFIG_ACK_SIZE = HEADER.size + _CONFIG_ACK.size + _CRC.size  # 20
MAX_FRAME_SIZE = max(HELLO_SIZE, SENSOR_SIZE, COMMAND_SIZE, CONFIG_SIZE, CONFIG_ACK_SIZE)
_SIZES = {FrameType.HELLO: HELLO_SIZE, FrameType.SENSOR: SENSOR_SIZE, FrameType.COMMAND: COMMAND_SIZE,
          FrameType.CONFIG: CONFIG_SIZE, FrameType.CONFIG_ACK: CONFIG_ACK_SIZE}
_ZERO3 = b"\x00\x00\x00"
_ZERO1 = b"\x00"
_U16 = 0xFFFF
_U32 = 0xFFFFFFFF
_U64 = 0xFFFFFFFFFFFFFFFF
_F32_MAX = 3.4028234663852886e38


@dataclass(frozen=True)
class Hello:
    """The handshake frame (24 bytes; its layout never changes between versions).

    The PC sends :data:`HELLO_REQUEST` (all fields but ``version`` zero); the
    board answers with its own Hello and only then starts streaming. ``version``
    travels in the header's version byte, so a PC can read the version of any
    board and refuse a mismatch with a clear message.

    Attributes:
        version: protocol version the sender speaks (u8).
        board_id: the board's serial number or id (u32; 0 in a request).
        rate_hz: the board's sample rate (Hz, u32; 1000 for the DEM rig).
        adc_bits: ADC resolution (bits, 0..16; 0 in a request).
        adc_vref: ADC full-scale voltage (V, float32, ≥ 0): a count c reads
            c · adc_vref / 2**adc_bits volts at the ADC pin.
        watchdog_ms: the board's link watchdog (ms, u16): with no valid command
            for this long the board lands the plate. 0 in a request.
        command_delay: the board's command delay d (samples, u8): at tick k it
            applies the command answering sample k - d. 0 in a request (and
            "not stated" from a board that does not report it); a PC whose
            controller predicts over another delay must refuse the board.
        (``watchdog_ms`` and ``command_delay`` are additions to the PLAN.md API;
        their defaults keep that API.)
    """

    version: int
    board_id: int
    rate_hz: int
    adc_bits: int
    adc_vref: float
    watchdog_ms: int = 0
    command_delay: int = 0

    @property
    def is_request(self) -> bool:
        """True for the PC's request (no board id, rate or ADC scale)."""
        return self.board_id == 0 and self.rate_hz == 0 and self.adc_bits == 0


HELLO_REQUEST = Hello(version=PROTOCOL_VERSION, board_id=0, rate_hz=0, adc_bits=0, adc_vref=0.0)
"""What the PC sends to open the link."""


@dataclass(frozen=True)
class SensorFrame:
    """One sample from the board (48 bytes), sent right after sampling.

    Attributes:
        seq: sample number (u32, +1 per sample, wraps modulo 2**32; see :func:`seq_diff`).
        board_time_us: the board's clock at the sample (µs, u64, monotonic).
        gap_counts: raw ADC counts of gap sensors 1 and 2 (u16 each).
        current_counts: raw ADC counts of coil current sensors 1 and 2 (u16 each).
        applied_v: voltage actually applied to coils 1 and 2 over the period
            that ends at this sample (V, float32), after the board's clipping.
        bus_v: measured DC bus voltage (V, float32).
        status: :class:`Status` bits (u32).
        mode: the board's :class:`Mode` at this sample.
    """

    seq: int
    board_time_us: int
    gap_counts: tuple[int, int]
    current_counts: tuple[int, int]
    applied_v: tuple[float, float]
    bus_v: float
    status: int
    mode: Mode


@dataclass(frozen=True)
class CommandFrame:
    """A command from the PC (24 bytes).

    Attributes:
        seq: the ``seq`` of the sensor frame this command answers (u32).
        u: coil voltages 1 and 2 to apply (V, float32, finite; the board clips
            them to its driver's limit and reports VOLTAGE_CLIPPED).
        mode: the requested :class:`Mode`, one of :data:`COMMAND_MODES`.
    """

    seq: int
    u: tuple[float, float]
    mode: Mode


@dataclass(frozen=True)
class ConfigFrame:
    """The board's configuration, PC -> board (128 bytes): what the firmware's ``board_config_t`` holds but the
    board's own identity and ADC (board id, ADC bits and reference: the hello states them).

    Attributes:
        values: the 29 values of :data:`CONFIG_KEYS` in that order (float32 on the wire, finite): the safety specs,
            the nominal plant and ``dt`` [SI], then the gap polynomials [m/count^p], the current gains [A/count] and
            offsets [count].
        command_delay: d [samples] (u8): at tick k the board applies the command answering sample k - d.

    The configuration's CRC-32 (what the board reports in :class:`ConfigAck`) is this frame's CRC field: the CRC of
    its canonical bytes (the header is fixed, the reserved bytes zero).
    """

    values: tuple[float, ...]
    command_delay: int

    def as_dict(self) -> dict[str, float]:
        """{name: value} of :data:`CONFIG_KEYS` (``command_delay`` too, as a float)."""
        return {**dict(zip(CONFIG_KEYS, self.values, strict=True)), "command_delay": float(self.command_delay)}


@dataclass(frozen=True)
class ConfigAck:
    """The board's answer to a :class:`ConfigFrame`, board -> PC (20 bytes).

    Attributes:
        active_crc: the CRC-32 of the configuration the board runs after this request (u32): the request's CRC when
            it was accepted, the previous one's when it was refused.
        request_crc: the CRC-32 of the configuration this answers (u32; the PC tells a late answer from the current).
        result: the index of :data:`CONFIG_RESULTS` (u8): 0 accepted, else why it was refused.
        configured: True once a configuration was set over the link; False: the board runs the defaults it was
            built with (firmware ``board_config.h``).
        mode: the board's :class:`Mode` when it answered (a refusal with ``busy`` says which).
    """

    active_crc: int
    request_crc: int
    result: int
    configured: bool
    mode: Mode


Frame = Hello | SensorFrame | CommandFrame | ConfigFrame | ConfigAck


def seq_diff(a: int, b: int) -> int:
    """Signed distance ``a - b`` of two u32 sequence numbers, in [-2**31, 2**31).

    ``seq_diff(1, 0xFFFFFFFF) == 2``: numbers wrap modulo 2**32.
    """
    return ((a - b + 0x80000000) & _U32) - 0x80000000


# --- encode ---------------------------------------------------------------------------------
def _uint(name: str, v: object, top: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= top:
        raise LinkError("range", f"{name}={v!r} is not an integer in [0, {top}]")
    return v


def _f32(name: str, v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise LinkError("range", f"{name}={v!r} is not a number")
    f = float(v)
    if not math.isfinite(f):
        raise LinkError("nonfinite", f"{name}={f!r} is not finite")
    if abs(f) > _F32_MAX:
        raise LinkError("range", f"{name}={f!r} does not fit a float32")
    return f


def _pair(name: str, v: object) -> tuple[object, object]:
    if not isinstance(v, (tuple, list)) or len(v) != 2:
        raise LinkError("range", f"{name}={v!r} is not a pair")
    return v[0], v[1]


def _mode(v: object, allowed: frozenset[Mode] | None) -> Mode:
    try:
        m = Mode(v)  # type: ignore[arg-type]
    except (ValueError, TypeError):
        raise LinkError("mode", f"mode={v!r} is not a Mode") from None
    if allowed is not None and m not in allowed:
        raise LinkError("mode", f"a command cannot request mode {m.name}")
    return m


def _seal(ftype: FrameType, payload: bytes, version: int = PROTOCOL_VERSION) -> bytes:
    body = HEADER.pack(version, ftype, HEADER.size + len(payload) + _CRC.size) + payload
    return body + _CRC.pack(zlib.crc32(body))


def encode(frame: Frame) -> bytes:
    """Serialise a frame to its fixed little-endian layout with header and CRC-32.

    Raises:
        LinkError: a field out of its range (reason ``range``), a non-finite
            float (``nonfinite``) or a mode not allowed (``mode``).
    """
    if isinstance(frame, SensorFrame):
        g0, g1 = _pair("gap_counts", frame.gap_counts)
        c0, c1 = _pair("current_counts", frame.current_counts)
        a0, a1 = _pair("applied_v", frame.applied_v)
        payload = _SENSOR.pack(
            _uint("seq", frame.seq, _U32),
            _uint("board_time_us", frame.board_time_us, _U64),
            _uint("gap_counts[0]", g0, _U16),
            _uint("gap_counts[1]", g1, _U16),
            _uint("current_counts[0]", c0, _U16),
            _uint("current_counts[1]", c1, _U16),
            _f32("applied_v[0]", a0),
            _f32("applied_v[1]", a1),
            _f32("bus_v", frame.bus_v),
            _uint("status", frame.status, _U32),
            _mode(frame.mode, None),
            _ZERO3,
        )
        return _seal(FrameType.SENSOR, payload)
    if isinstance(frame, CommandFrame):
        u0, u1 = _pair("u", frame.u)
        payload = _COMMAND.pack(
            _uint("seq", frame.seq, _U32),
            _f32("u[0]", u0),
            _f32("u[1]", u1),
            _mode(frame.mode, COMMAND_MODES),
            _ZERO3,
        )
        return _seal(FrameType.COMMAND, payload)
    if isinstance(frame, Hello):
        version = _uint("version", frame.version, 0xFF)
        if version == 0:
            raise LinkError("range", "version=0 is not a protocol version")
        adc_bits = _uint("adc_bits", frame.adc_bits, 16)
        vref = _f32("adc_vref", frame.adc_vref)
        if vref < 0.0:
            raise LinkError("range", f"adc_vref={vref!r} is negative")
        payload = _HELLO.pack(
            _uint("board_id", frame.board_id, _U32),
            _uint("rate_hz", frame.rate_hz, _U32),
            adc_bits,
            _uint("command_delay", frame.command_delay, 0xFF),
            _uint("watchdog_ms", frame.watchdog_ms, _U16),
            vref,
        )
        return _seal(FrameType.HELLO, payload, version)
    if isinstance(frame, ConfigFrame):
        values = frame.values
        if not isinstance(values, (tuple, list)) or len(values) != len(CONFIG_KEYS):
            raise LinkError("range", f"values={values!r} is not a sequence of the {len(CONFIG_KEYS)} CONFIG_KEYS")
        payload = _CONFIG.pack(*(_f32(k, v) for k, v in zip(CONFIG_KEYS, values, strict=True)),
                               _uint("command_delay", frame.command_delay, 0xFF), _ZERO3)
        return _seal(FrameType.CONFIG, payload)
    if isinstance(frame, ConfigAck):
        payload = _CONFIG_ACK.pack(
            _uint("active_crc", frame.active_crc, _U32),
            _uint("request_crc", frame.request_crc, _U32),
            _uint("result", frame.result, len(CONFIG_RESULTS) - 1),
            _uint("configured", int(frame.configured) if isinstance(frame.configured, bool) else frame.configured, 1),
            _mode(frame.mode, None),
            _ZERO1,
        )
        return _seal(FrameType.CONFIG_ACK, payload)
    raise TypeError(f"encode() takes a Hello, SensorFrame, CommandFrame, ConfigFrame or ConfigAck, not "
                    f"{type(frame).__name__}")


# --- decode ---------------------------------------------------------------------------------
def _finite(name: str, f: float) -> float:
    if not math.isfinite(f):
        raise LinkError("nonfinite", f"{name} is {f!r}")
    return f


def decode(data: bytes | bytearray | memoryview) -> Frame:
    """Parse one frame; checks in the order of :data:`REASONS`.

    Args:
        data: exactly one frame (one UDP datagram, or one COBS-decoded serial frame).

    Raises:
        LinkError: the frame is rejected; ``reason`` says why.
    """
    b = bytes(data)
    n = len(b)
    if n < HEADER.size + _CRC.size:
        raise LinkError("short", f"{n} bytes, a frame has at least {HEADER.size + _CRC.size}")
    version, ftype, length = HEADER.unpack_from(b, 0)
    if length != n:
        raise LinkError("length", f"header says {length} bytes, received {n}")
    (crc,) = _CRC.unpack_from(b, n - _CRC.size)
    if crc != zlib.crc32(b[: n - _CRC.size]):
        raise LinkError("crc", f"CRC-32 {crc:#010x} does not match the frame's {zlib.crc32(b[:-4]):#010x}")
    if ftype == FrameType.HELLO:
        if n != HELLO_SIZE:
            raise LinkError("size", f"a hello frame has {HELLO_SIZE} bytes, not {n}")
        board_id, rate_hz, adc_bits, delay, watchdog_ms, vref = _HELLO.unpack_from(b, HEADER.size)
        if version == 0:
            raise LinkError("version", "version 0 is not a protocol version")
        if adc_bits > 16:
            raise LinkError("range", f"adc_bits={adc_bits} (at most 16)")
        _finite("adc_vref", vref)
        if vref < 0.0:
            raise LinkError("range", f"adc_vref={vref!r} is negative")
        return Hello(version, board_id, rate_hz, adc_bits, vref, watchdog_ms, delay)
    if version != PROTOCOL_VERSION:
        raise LinkError("version", f"protocol version {version}, this codec speaks {PROTOCOL_VERSION}")
    if ftype not in _SIZES:
        raise LinkError("type", f"unknown frame type {ftype}")
    if n != _SIZES[FrameType(ftype)]:
        raise LinkError("size", f"a {FrameType(ftype).name.lower()} frame has {_SIZES[FrameType(ftype)]} bytes, "
                                f"not {n}")
    if ftype == FrameType.SENSOR:
        seq, t_us, g0, g1, c0, c1, a0, a1, bus, status, mode, res = _SENSOR.unpack_from(b, HEADER.size)
        if res != _ZERO3:
            raise LinkError("reserved", f"sensor reserved bytes are {res.hex()}")
        m = _mode(mode, None)
        return SensorFrame(
            seq,
            t_us,
            (g0, g1),
            (c0, c1),
            (_finite("applied_v[0]", a0), _finite("applied_v[1]", a1)),
            _finite("bus_v", bus),
            status,
            m,
        )
    if ftype == FrameType.COMMAND:
        seq, u0, u1, mode, res = _COMMAND.unpack_from(b, HEADER.size)
        if res != _ZERO3:
            raise LinkError("reserved", f"command reserved bytes are {res.hex()}")
        m = _mode(mode, COMMAND_MODES)
        return CommandFrame(seq, (_finite("u[0]", u0), _finite("u[1]", u1)), m)
    if ftype == FrameType.CONFIG:
        *values, delay, res = _CONFIG.unpack_from(b, HEADER.size)
        if res != _ZERO3:
            raise LinkError("reserved", f"config reserved bytes are {res.hex()}")
        return ConfigFrame(tuple(_finite(k, v) for k, v in zip(CONFIG_KEYS, values, strict=True)), delay)
    active, request, result, configured, mode, res = _CONFIG_ACK.unpack_from(b, HEADER.size)
    if res != _ZERO1:
        raise LinkError("reserved", f"config ack reserved byte is {res.hex()}")
    m = _mode(mode, None)
    if result >= len(CONFIG_RESULTS):
        raise LinkError("range", f"result={result} (at most {len(CONFIG_RESULTS) - 1})")
    if configured > 1:
        raise LinkError("range", f"configured={configured} (0 or 1)")
    return ConfigAck(active, request, result, bool(configured), m)
