"""The Python frame codec and COBS framing against the shared vectors (the protocol's definition).

``linkvectors`` parses ``tests/hardware/vectors/frames.txt``; the C codec is
held to the same file in ``test_link_c.py``.
"""

from __future__ import annotations

import random
import struct
from dataclasses import replace
from pathlib import Path

import pytest

from dem_ros.hardware.framing import MAX_ENCODED_SIZE, CobsError, Deframer, cobs_decode, cobs_encode
from dem_ros.hardware.link import (
    COMMAND_SIZE,
    CONFIG_ACK_SIZE,
    CONFIG_CAL_KEYS,
    CONFIG_KEYS,
    CONFIG_RESULTS,
    CONFIG_SIZE,
    CONFIG_SUP_KEYS,
    HELLO_REQUEST,
    HELLO_SIZE,
    MAX_FRAME_SIZE,
    PROTOCOL_VERSION,
    REASONS,
    SENSOR_SIZE,
    STATUS_DEFINED,
    CommandFrame,
    ConfigAck,
    ConfigFrame,
    Hello,
    LinkError,
    Mode,
    SensorFrame,
    Status,
    decode,
    encode,
    seq_diff,
)

VECTORS = Path(__file__).resolve().parent / "vectors" / "frames.txt"


def parse_vectors(path: Path = VECTORS) -> list[dict[str, object]]:
    """Records of frames.txt as dicts: name, hex (bytes), cobs (bytes|None), expect, type, fields."""
    records: list[dict[str, object]] = []
    cur: dict[str, object] | None = None
    for lineno, raw in enumerate(path.read_text().splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, _, rest = line.partition(" ")
        if key == "vector":
            assert cur is None, f"line {lineno}: vector inside a vector"
            cur = {"name": rest, "cobs": None, "fields": {}}
        elif key == "end":
            assert cur is not None, f"line {lineno}: end without vector"
            records.append(cur)
            cur = None
        else:
            assert cur is not None, f"line {lineno}: {key} outside a vector"
            if key in ("hex", "cobs"):
                cur[key] = bytes.fromhex(rest)
            elif key in ("expect", "type"):
                cur[key] = rest
            else:
                cur["fields"][key] = rest.split()  # type: ignore[index]
    assert cur is None, "unterminated vector"
    return records


def expected_frame(rec: dict[str, object]) -> Hello | SensorFrame | CommandFrame | ConfigFrame | ConfigAck:
    """The frame a valid vector's field lines describe."""
    f: dict[str, list[str]] = rec["fields"]  # type: ignore[assignment]

    def i(k: str, n: int = 0) -> int:
        return int(f[k][n], 0)

    def x(k: str, n: int = 0) -> float:
        return float(f[k][n])

    if rec["type"] == "hello":
        return Hello(i("version"), i("board_id"), i("rate_hz"), i("adc_bits"), x("adc_vref"), i("watchdog_ms"),
                     i("command_delay"))
    if rec["type"] == "sensor":
        return SensorFrame(
            i("seq"), i("board_time_us"), (i("gap_counts"), i("gap_counts", 1)),
            (i("current_counts"), i("current_counts", 1)), (x("applied_v"), x("applied_v", 1)),
            x("bus_v"), i("status"), Mode[f["mode"][0]],
        )
    if rec["type"] == "config":
        return ConfigFrame(tuple(float(v) for v in f["supervisor"] + f["calibration"]), i("command_delay"))
    if rec["type"] == "config_ack":
        return ConfigAck(i("active_crc"), i("request_crc"), CONFIG_RESULTS.index(f["result"][0]), bool(i("configured")),
                         Mode[f["mode"][0]])
    assert rec["type"] == "command"
    return CommandFrame(i("seq"), (x("u"), x("u", 1)), Mode[f["mode"][0]])


RECORDS = parse_vectors()


def test_vectors_cover_every_reason_and_type() -> None:
    """The file is a complete definition: each frame type valid, each rejection reason at least once."""
    expects = {r["expect"] for r in RECORDS}
    assert expects == {"ok", *REASONS}
    assert {r["type"] for r in RECORDS if r["expect"] == "ok"} == {"hello", "sensor", "command", "config", "config_ack"}
    assert len({r["name"] for r in RECORDS}) == len(RECORDS)


@pytest.mark.parametrize("rec", RECORDS, ids=[str(r["name"]) for r in RECORDS])
def test_vector(rec: dict[str, object]) -> None:
    """decode gives the stated values (or reason); encode gives back the same bytes; COBS as stated."""
    data: bytes = rec["hex"]  # type: ignore[assignment]
    if rec["expect"] == "ok":
        frame = decode(data)
        assert frame == expected_frame(rec)
        assert encode(frame) == data
        assert cobs_encode(data) == rec["cobs"]
        assert cobs_decode(rec["cobs"]) == data  # type: ignore[arg-type]
    else:
        with pytest.raises(LinkError) as e:
            decode(data)
        assert e.value.reason == rec["expect"]
        assert str(e.value).startswith(f"{rec['expect']}: ")


def test_sizes_and_layout() -> None:
    """Sizes of docs/hardware-link.md; floats are 4-aligned and the u64 board time 8-aligned."""
    assert (HELLO_SIZE, SENSOR_SIZE, COMMAND_SIZE, CONFIG_SIZE, CONFIG_ACK_SIZE) == (24, 48, 24, 128, 20)
    assert MAX_FRAME_SIZE == 128 and MAX_ENCODED_SIZE == 129
    b = encode(SensorFrame(1, 0x0102030405060708, (1, 2), (3, 4), (1.0, 2.0), 3.0, 0, Mode.RUN))
    assert struct.unpack_from("<Q", b, 8)[0] == 0x0102030405060708
    assert struct.unpack_from("<fff", b, 24) == (1.0, 2.0, 3.0)
    assert b[40] == Mode.RUN


def test_config_layout_is_the_firmwares_and_the_crc_is_the_frames() -> None:
    """The config frame's floats are sup_config_t's order (the C binding's, the Python board's keys + dt), then the
    calibration as board_config_t holds it; each at offset 4 + 4 k. The configuration's CRC is the frame's CRC
    field, so a board and a PC that hold the same values report the same CRC."""
    from dem_ros.board import PLANT_KEYS, SAFETY_KEYS

    assert (*SAFETY_KEYS, *PLANT_KEYS, "dt") == CONFIG_SUP_KEYS and CONFIG_KEYS == CONFIG_SUP_KEYS + CONFIG_CAL_KEYS
    assert len(CONFIG_SUP_KEYS) == 17 and len(CONFIG_CAL_KEYS) == 12
    values = tuple(float(k + 1) for k in range(len(CONFIG_KEYS)))
    b = encode(ConfigFrame(values, 3))
    assert struct.unpack_from("<29f", b, 4) == values and b[120] == 3 and b[121:124] == bytes(3)
    got = decode(b)
    assert isinstance(got, ConfigFrame) and got == ConfigFrame(values, 3) and got.as_dict()["gap2_c1"] == 6.0 + 17
    a = encode(ConfigAck(0x11223344, 0x55667788, 8, True, Mode.HOLD))
    assert struct.unpack_from("<IIBBBB", a, 4) == (0x11223344, 0x55667788, 8, 1, 2, 0)
    assert CONFIG_RESULTS[8] == "busy" and CONFIG_RESULTS[:6] == ("ok", "not_positive", "gap_order", "arms",
                                                                  "no_braking", "nonfinite")


def test_mode_values_match_plan() -> None:
    """The mode byte values of PLAN.md mechanism 1 (shared with dem_ros.board.Mode)."""
    assert {m.name: int(m) for m in Mode} == {"OFF": 0, "RUN": 1, "HOLD": 2, "LAND": 3, "LANDED": 4, "FAULT": 5}


def test_mode_is_the_safety_supervisors() -> None:
    """The link's mode byte is the board Supervisor's Mode: one definition."""
    from dem_ros import board

    assert Mode is board.Mode


def test_status_bits_are_distinct_18_and_the_defined_mask() -> None:
    bits = [int(s) for s in Status]
    assert len(bits) == 18 and sorted(bits) == [1 << k for k in range(18)]
    assert sum(bits) == STATUS_DEFINED


def test_round_trip_random_frames() -> None:
    """5000 seeded random frames of each type: decode(encode(f)) == f for float32-exact values."""
    rng = random.Random(11)

    def f32() -> float:
        return struct.unpack("<f", struct.pack("<I", rng.choice([rng.getrandbits(32) & 0xBF7FFFFF, 0])))[0]

    for _ in range(5000):
        s = SensorFrame(rng.getrandbits(32), rng.getrandbits(64), (rng.getrandbits(16), rng.getrandbits(16)),
                        (rng.getrandbits(16), rng.getrandbits(16)), (f32(), f32()), f32(), rng.getrandbits(32),
                        Mode(rng.randrange(6)))
        c = CommandFrame(rng.getrandbits(32), (f32(), f32()), rng.choice([Mode.OFF, Mode.RUN, Mode.HOLD, Mode.LAND]))
        h = Hello(rng.randrange(1, 256), rng.getrandbits(32), rng.getrandbits(32), rng.randrange(17), abs(f32()),
                  rng.getrandbits(16), rng.getrandbits(8))
        g = ConfigFrame(tuple(f32() for _ in CONFIG_KEYS), rng.getrandbits(8))
        a = ConfigAck(rng.getrandbits(32), rng.getrandbits(32), rng.randrange(len(CONFIG_RESULTS)),
                      rng.random() < 0.5, Mode(rng.randrange(6)))
        for fr in (s, c, h, g, a):
            assert decode(encode(fr)) == fr


def test_float_rounds_to_float32() -> None:
    """A voltage not representable in float32 arrives as its nearest float32 (documented)."""
    c = decode(encode(CommandFrame(1, (0.1, 50.0), Mode.RUN)))
    assert isinstance(c, CommandFrame)
    assert c.u == (struct.unpack("<f", struct.pack("<f", 0.1))[0], 50.0) and c.u[0] != 0.1


@pytest.mark.parametrize(
    ("frame", "reason", "words"),
    [
        (CommandFrame(1, (float("nan"), 0.0), Mode.RUN), "nonfinite", "u[0]=nan"),
        (CommandFrame(1, (0.0, float("inf")), Mode.RUN), "nonfinite", "u[1]=inf"),
        (CommandFrame(1, (1e39, 0.0), Mode.RUN), "range", "float32"),
        (CommandFrame(1, (0.0, 0.0), Mode.LANDED), "mode", "cannot request mode LANDED"),
        (CommandFrame(1, (0.0, 0.0), 9), "mode", "mode=9"),  # type: ignore[arg-type]
        (CommandFrame(-1, (0.0, 0.0), Mode.RUN), "range", "seq=-1"),
        (CommandFrame(2**32, (0.0, 0.0), Mode.RUN), "range", "seq=4294967296"),
        (CommandFrame(1, (0.0,), Mode.RUN), "range", "not a pair"),  # type: ignore[arg-type]
        (CommandFrame(1, ("1", 0.0), Mode.RUN), "range", "not a number"),  # type: ignore[arg-type]
        (SensorFrame(1, 0, (65536, 0), (0, 0), (0.0, 0.0), 0.0, 0, Mode.RUN), "range", "gap_counts[0]=65536"),
        (SensorFrame(1, 0, (0, 0), (0, 0), (0.0, 0.0), 0.0, 2**32, Mode.RUN), "range", "status"),
        (SensorFrame(1, 0, (True, 0), (0, 0), (0.0, 0.0), 0.0, 0, Mode.RUN), "range", "gap_counts[0]=True"),
        (Hello(1, 1, 1000, 17, 3.0), "range", "adc_bits=17"),
        (Hello(0, 1, 1000, 12, 3.0), "range", "version=0"),
        (Hello(1, 1, 1000, 12, -1.0), "range", "adc_vref=-1.0"),
        (Hello(1, 1, 1000, 12, 3.0, 50, 256), "range", "command_delay=256"),
        (ConfigFrame((1.0,) * 28, 1), "range", "not a sequence of the 29"),
        (ConfigFrame((1.0,) * 7 + (float("nan"),) + (1.0,) * 21, 1), "nonfinite", "m=nan"),
        (ConfigFrame((1.0,) * 28 + (float("inf"),), 1), "nonfinite", "current2_offset=inf"),
        (ConfigFrame((1.0,) * 29, 256), "range", "command_delay=256"),
        (ConfigAck(0, 0, 9, True, Mode.OFF), "range", "result=9"),
        (ConfigAck(0, 0, 0, 2, Mode.OFF), "range", "configured=2"),  # type: ignore[arg-type]
        (ConfigAck(2**32, 0, 0, True, Mode.OFF), "range", "active_crc"),
        (ConfigAck(0, 0, 0, True, 7), "mode", "mode=7"),  # type: ignore[arg-type]
    ],
)
def test_encode_refuses_bad_fields(frame: object, reason: str, words: str) -> None:
    """encode raises LinkError with the reason and the offending field, never struct.error."""
    with pytest.raises(LinkError) as e:
        encode(frame)  # type: ignore[arg-type]
    assert e.value.reason == reason and words in str(e.value)


def test_encode_refuses_other_objects() -> None:
    with pytest.raises(TypeError, match="not bytes"):
        encode(b"\x01")  # type: ignore[arg-type]


def test_hello_request_and_version_refusal() -> None:
    """The PC's request is recognisable; a board of another version decodes so it can be refused by name."""
    assert HELLO_REQUEST.is_request and HELLO_REQUEST.version == PROTOCOL_VERSION
    board = Hello(PROTOCOL_VERSION + 1, 9, 1000, 12, 3.0, 50, 1)
    got = decode(encode(board))
    assert got == board and not got.is_request  # type: ignore[union-attr]
    # ... but its sensor frames are refused
    s = bytearray(encode(SensorFrame(1, 0, (0, 0), (0, 0), (0.0, 0.0), 0.0, 0, Mode.RUN)))
    s[0] = PROTOCOL_VERSION + 1
    import zlib

    s[-4:] = struct.pack("<I", zlib.crc32(bytes(s[:-4])))
    with pytest.raises(LinkError, match="version 2, this codec speaks 1"):
        decode(bytes(s))


def test_seq_diff_wraps() -> None:
    assert seq_diff(1, 0xFFFFFFFF) == 2
    assert seq_diff(0xFFFFFFFF, 1) == -2
    assert seq_diff(5, 5) == 0
    assert seq_diff(0x7FFFFFFF, 0) == 0x7FFFFFFF and seq_diff(0x80000000, 0) == -0x80000000


def test_frames_are_immutable() -> None:
    c = CommandFrame(1, (0.0, 0.0), Mode.RUN)
    with pytest.raises(AttributeError):
        c.seq = 2  # type: ignore[misc]
    assert replace(c, seq=2).seq == 2


# --- COBS and the Deframer --------------------------------------------------------------------
def test_cobs_round_trip_and_bounds() -> None:
    """Every length 0..700 with zero-rich and zero-free data: no 0x00 out, inverse exact, overhead ⌈n/254⌉ (+1)."""
    rng = random.Random(3)
    for n in range(701):
        for data in (bytes(rng.choice((0, 0, 1, 255, rng.randrange(256))) for _ in range(n)),
                     bytes(rng.randrange(1, 256) for _ in range(n))):
            e = cobs_encode(data)
            assert 0 not in e
            assert cobs_decode(e) == data
            assert len(data) + 1 <= len(e) <= len(data) + 1 + n // 254


def test_cobs_known_encodings() -> None:
    """Examples of Cheshire & Baker / the COBS Wikipedia table."""
    assert cobs_encode(b"\x00") == b"\x01\x01"
    assert cobs_encode(b"\x00\x00") == b"\x01\x01\x01"
    assert cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert cobs_encode(b"\x11\x00\x00\x00") == b"\x02\x11\x01\x01\x01"
    assert cobs_encode(bytes(range(1, 255))) == b"\xff" + bytes(range(1, 255)) + b"\x01"


@pytest.mark.parametrize("bad", [b"", b"\x00", b"\x03\x11", b"\x02\x00", b"\x05\x01\x02"])
def test_cobs_decode_rejects(bad: bytes) -> None:
    with pytest.raises(CobsError):
        cobs_decode(bad)


def _wire(frame: bytes) -> bytes:
    return cobs_encode(frame) + b"\x00"


def test_deframer_any_split() -> None:
    """Three frames on a stream split at every possible point come out whole and in order."""
    frames = [encode(HELLO_REQUEST), encode(CommandFrame(7, (1.0, 2.0), Mode.RUN)),
              encode(SensorFrame(3, 9, (1, 2), (3, 4), (0.5, 0.25), 150.0, 0, Mode.HOLD))]
    stream = b"".join(_wire(f) for f in frames)
    for cut in range(len(stream) + 1):
        d = Deframer()
        assert d.feed(stream[:cut]) + d.feed(stream[cut:]) == frames
        assert sum(d.dropped.values()) == 0
    d = Deframer()
    assert [f for b in stream for f in d.feed(bytes([b]))] == frames  # byte by byte


def test_deframer_resynchronises_on_garbage() -> None:
    """Garbage without a delimiter joins the next frame (lost, counted); after a delimiter all is well."""
    good = encode(CommandFrame(7, (1.0, 2.0), Mode.RUN))
    d = Deframer()
    out = d.feed(b"\x07noise" + _wire(good) + _wire(good))  # noise joined the first frame: invalid COBS
    assert out == [good] and d.dropped["cobs"] == 1
    out = d.feed(b"\x02\x41" + _wire(good) + _wire(good))  # noise that is valid COBS: left to decode()
    assert out[1:] == [good] and len(out) == 2
    with pytest.raises(LinkError):
        decode(out[0])
    out = d.feed(b"\x03\x01" + b"\x00" + _wire(good))  # invalid COBS, then a delimiter
    assert out == [good] and d.dropped["cobs"] == 2
    out = d.feed(b"\x01" * 500 + b"\x00" + _wire(good))  # an endless run, then resync
    assert out == [good] and d.dropped["oversize"] == 1
    assert d.frames == 5
    assert len(d._buf) == 0


def test_deframer_memory_is_bounded() -> None:
    d = Deframer()
    for _ in range(100):
        assert d.feed(b"\x01" * 1000) == []
        assert len(d._buf) <= MAX_ENCODED_SIZE
    assert d.dropped["oversize"] == 1  # one run without delimiter: counted once
    assert d.feed(b"\x00" + _wire(b"\x05")) == [b"\x05"]


def test_deframer_ignores_empty_segments() -> None:
    d = Deframer()
    assert d.feed(b"\x00\x00\x00" + _wire(b"ab") + b"\x00\x00") == [b"ab"]
    assert sum(d.dropped.values()) == 0


# --- docs/hardware-link.md says what the code does ------------------------------------------------
DOC = Path(__file__).resolve().parents[2] / "docs" / "hardware-link.md"


def _doc_section(title: str) -> str:
    text = DOC.read_text()
    start = text.index(title)
    end = text.find("\n### ", start + 1)
    end2 = text.find("\n## ", start + 1)
    return text[start:min(e for e in (end, end2, len(text)) if e > 0)]


def _table_rows(section: str, first_header: str) -> list[list[str]]:
    lines = section[section.index(f"| {first_header} |"):].splitlines()
    rows = []
    for line in lines[2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip().strip("`") for c in line.strip("|").split("|")])
    return rows


@pytest.mark.parametrize(
    ("title", "frame", "fmt_of"),
    [
        ("### Sensor frame", SensorFrame(0, 0, (0, 0), (0, 0), (0.0, 0.0), 0.0, 0, Mode.OFF),
         {"u32": "<I", "u64": "<Q", "u16": "<H", "f32": "<f", "u8": "<B"}),
        ("### Command frame", CommandFrame(0, (0.0, 0.0), Mode.OFF), {"u32": "<I", "f32": "<f", "u8": "<B"}),
        ("### Hello", Hello(1, 0, 0, 0, 0.0, 0, 0), {"u32": "<I", "f32": "<f", "u8": "<B", "u16": "<H"}),
        ("### Config ack", ConfigAck(0, 0, 0, False, Mode.OFF), {"u32": "<I", "u8": "<B"}),
    ],
)
def test_doc_byte_tables_match_the_codec(title: str, frame: object, fmt_of: dict[str, str]) -> None:
    """Each field row (offset, size, type, name) of the document: setting that field moves exactly those bytes."""
    rows = _table_rows(_doc_section(title), "offset")
    base = encode(frame)  # type: ignore[arg-type]
    covered = 0
    for offset, size, typ, name, *_ in rows:
        if typ not in fmt_of or name in ("crc", "reserved"):
            continue
        field, _, idx = name.partition("[")
        value: object = 7.5 if typ == "f32" else (3 if field == "mode" else 1 if field == "configured" else 5)
        old = getattr(frame, field)
        if idx:
            k = int(idx.rstrip("]"))
            value = tuple(value if j == k else v for j, v in enumerate(old))
        changed = encode(replace(frame, **{field: value}))  # type: ignore[type-var,arg-type]
        diff = [i for i in range(len(base) - 4) if base[i] != changed[i]]
        lo, n = int(offset), int(size)
        assert diff and lo <= min(diff) and max(diff) < lo + n, (name, diff, offset, size)
        assert struct.unpack_from(fmt_of[typ], changed, lo)[0] == (value[k] if idx else value)  # type: ignore[index]
        covered += n
    assert covered + 4 + 4 + sum(int(r[1]) for r in rows if r[3] == "reserved") == len(base)


def test_doc_config_table_is_the_codecs_layout() -> None:
    """The config frame's rows: the floats' names in the codec's order, each 4 bytes from offset 4; the delay, the
    reserved bytes and the CRC where the codec puts them; the results table is CONFIG_RESULTS."""
    rows = _table_rows(_doc_section("### Config (type 4"), "offset")
    names: list[str] = []
    for offset, size, typ, name, *_ in rows:
        if "× f32" in typ:
            fields = [n.strip().strip("`") for n in name.split(",")]
            assert int(offset) == 4 + 4 * len(names) and int(size) == 4 * len(fields) == 4 * int(typ.split()[0])
            names += fields
    assert tuple(names) == CONFIG_KEYS
    rest = {r[3]: (int(r[0]), int(r[1])) for r in rows if "f32" not in r[2]}
    assert rest == {"header": (0, 4), "command_delay": (120, 1), "reserved": (121, 3), "crc": (124, 4)}
    b = encode(ConfigFrame(tuple(float(k) for k in range(len(CONFIG_KEYS))), 9))
    assert len(b) == CONFIG_SIZE and b[120] == 9 and struct.unpack_from("<f", b, 4 + 4 * 28)[0] == 28.0
    results = _table_rows(_doc_section("**Config results**"), "value")
    assert [(int(r[0]), r[1]) for r in results] == list(enumerate(CONFIG_RESULTS))


def test_doc_status_modes_and_reasons_match_the_code() -> None:
    status = {r[1]: int(r[0]) for r in _table_rows(_doc_section("**Status bits**"), "bit")}
    assert status == {s.name: int(s).bit_length() - 1 for s in Status}
    modes = {r[1]: int(r[0]) for r in _table_rows(_doc_section("**Modes**"), "value")}
    assert modes == {m.name: int(m) for m in Mode}
    reasons = [r[0] for r in _table_rows(_doc_section("## 6. Error handling"), "reason")]
    assert reasons == list(REASONS)
