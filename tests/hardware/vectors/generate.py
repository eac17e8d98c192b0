"""Write ``frames.txt`` (run once, by hand, when the protocol changes; the tests never run this).

The committed ``frames.txt`` is the definition of the protocol: the Python
codec (``tests/hardware/test_link.py``) and the C codec (``firmware/``) are both
tested against it. This script only spares typing hex by hand: the valid
frames are built field by field with ``struct`` (not with ``dem_ros``'s
encoder, so the file is an independent statement of the layout), the invalid
ones by editing valid bytes and, where the point is a check after the CRC,
re-sealing the CRC.

    PYTHONPATH=$PWD python tests/hardware/vectors/generate.py > tests/hardware/vectors/frames.txt
"""

from __future__ import annotations

import math
import struct
import zlib

MODES = {0: "OFF", 1: "RUN", 2: "HOLD", 3: "LAND", 4: "LANDED", 5: "FAULT"}


def seal(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def hello(version: int, board_id: int, rate: int, bits: int, vref: float, wd: int, delay: int = 0) -> bytes:
    return seal(struct.pack("<BBHIIBBHf", version, 1, 24, board_id, rate, bits, delay, wd, vref))


def sensor(seq, t, g, c, a, bus, status, mode, version=1, reserved=b"\0\0\0") -> bytes:
    return seal(struct.pack("<BBHIQHHHHfffIB3s", version, 2, 48, seq, t, *g, *c, *a, bus, status, mode, reserved))


def command(seq, u, mode, version=1, reserved=b"\0\0\0") -> bytes:
    return seal(struct.pack("<BBHIffB3s", version, 3, 24, seq, *u, mode, reserved))


#: the project's defaults (core/params.py): the safety specs, the nominal plant (Table 2) and dt, then the
#: data-sheet calibration of the gap sensors and the current sensors
CONFIG_SUP = (200.0, 10.0, 0.0015, 0.013, 0.05, 0.011, 0.01, 14.852, 20.0, 4.374e-4, 0.3, 0.168, 0.5648, 36.5, 36.5,
              9.81, 0.001)
CONFIG_CAL = (0.0, 2.5e-7, 8e-13, 0.0, 0.0, 2.5e-7, 8e-13, 0.0, 10.0 / 32768, 10.0 / 32768, 32768.0, 32768.0)
RESULTS = ("ok", "not_positive", "gap_order", "arms", "no_braking", "nonfinite", "delay", "rate", "busy")


def config(sup, cal, delay, version=1, reserved=b"\0\0\0") -> bytes:
    return seal(struct.pack("<BBH29fB3s", version, 4, 128, *sup, *cal, delay, reserved))


def config_ack(active, request, result, configured, mode, reserved=b"\0") -> bytes:
    return seal(struct.pack("<BBHIIBBB1s", 1, 5, 20, active, request, result, configured, mode, reserved))


def cobs(data: bytes) -> bytes:  # the reference algorithm, written out again on purpose
    out, block = bytearray(), bytearray()
    for b in data:
        if b == 0:
            out += bytes([len(block) + 1]) + block
            block.clear()
        else:
            block.append(b)
            if len(block) == 254:
                out += b"\xff" + block
                block.clear()
    out += bytes([len(block) + 1]) + block
    return bytes(out)


def fmt(x: float) -> str:
    return repr(f32(x)) if math.isfinite(x) else str(x)


def ok(name: str, note: str, data: bytes, fields: list[str]) -> None:
    print(f"vector {name}")
    print(f"# {note}")
    print(f"hex {data.hex()}")
    print(f"cobs {cobs(data).hex()}")
    print("expect ok")
    for line in fields:
        print(line)
    print("end\n")


def bad(name: str, note: str, data: bytes, reason: str) -> None:
    print(f"vector {name}")
    print(f"# {note}")
    print(f"hex {data.hex()}")
    print(f"expect {reason}")
    print("end\n")


def ok_hello(name, note, version, board_id, rate, bits, vref, wd, delay):
    ok(name, note, hello(version, board_id, rate, bits, vref, wd, delay), [
        "type hello", f"version {version}", f"board_id {board_id}", f"rate_hz {rate}",
        f"adc_bits {bits}", f"adc_vref {fmt(vref)}", f"watchdog_ms {wd}", f"command_delay {delay}"])


def ok_sensor(name, note, seq, t, g, c, a, bus, status, mode):
    ok(name, note, sensor(seq, t, g, c, a, bus, status, mode), [
        "type sensor", f"seq {seq}", f"board_time_us {t}", f"gap_counts {g[0]} {g[1]}",
        f"current_counts {c[0]} {c[1]}", f"applied_v {fmt(a[0])} {fmt(a[1])}", f"bus_v {fmt(bus)}",
        f"status 0x{status:08x}", f"mode {MODES[mode]}"])


def ok_command(name, note, seq, u, mode):
    ok(name, note, command(seq, u, mode), [
        "type command", f"seq {seq}", f"u {fmt(u[0])} {fmt(u[1])}", f"mode {MODES[mode]}"])


def ok_config(name, note, sup, cal, delay):
    ok(name, note, config(sup, cal, delay), [
        "type config", "supervisor " + " ".join(fmt(x) for x in sup), "calibration " + " ".join(fmt(x) for x in cal),
        f"command_delay {delay}"])


def ok_config_ack(name, note, active, request, result, configured, mode):
    ok(name, note, config_ack(active, request, result, configured, mode), [
        "type config_ack", f"active_crc 0x{active:08x}", f"request_crc 0x{request:08x}", f"result {RESULTS[result]}",
        f"configured {configured}", f"mode {MODES[mode]}"])


def main() -> None:
    print("""# dem_ros device link, protocol version 1: test vectors (docs/hardware-link.md).
# This file DEFINES the protocol: the Python codec (dem_ros/hardware/link.py) and the
# C codec (firmware/dem_link.c) must both pass it.
#
# Format (line oriented, ASCII; '#' starts a comment line; blank lines ignored):
#   vector NAME                 starts a record
#   hex HEX                     the frame's bytes (lower-case hex, no spaces; may be empty)
#   cobs HEX                    (valid frames) its COBS encoding, without the 0x00 delimiter
#   expect ok | REASON          decode succeeds, or is rejected with that reason
#   type hello|sensor|command|config|config_ack
#                               (valid frames) then one line per field, name then value(s):
#     integers in decimal, status in 0x hex, floats as the shortest decimal that
#     reads back to the same float32 (strtod then cast to float is exact), modes by name;
#     config: "supervisor" its 17 floats, "calibration" its 12, command_delay; config_ack: the CRCs in
#     0x hex, result by name (ok, not_positive, gap_order, arms, no_braking, nonfinite, delay, rate, busy)
#   end                         ends the record
# A valid frame re-encodes to exactly its hex bytes.
""")
    ok_hello("hello_request", "the PC opens the link: everything but the version zero", 1, 0, 0, 0, 0.0, 0, 0)
    ok_hello("hello_board", "a board answers: id, 1 kHz, 12-bit ADC at 3.3 V (float32 3.29999995), 50 ms watchdog, "
             "command delay 1 sample", 1, 0x0DE30001, 1000, 12, 3.3, 50, 1)
    ok_hello("hello_version_2", "a newer board: a hello of any version decodes, so the PC can refuse it by name",
             2, 7, 2000, 16, 2.5, 20, 2)
    ok_sensor("sensor_hover", "hovering at ~5 mm: counts mid-range, 50 V applied, 150 V bus, no status bit, RUN",
              1000, 1_000_000, (2048, 2051), (1700, 1702), (50.0, 49.75), 150.0, 0, 1)
    ok_sensor("sensor_extremes",
              "last seq before wrap, 2^40+ us, counts 0 and 65535, negative volts, every defined bit",
              0xFFFFFFFF, (1 << 40) + 123, (0, 65535), (65535, 0), (-120.5, 0.1), 148.25, 0x3FFFF, 5)
    ok_sensor("sensor_landing", "the board lost the PC: LINK_TIMEOUT | COMMAND_LATE, mode LAND",
              42, 42_000, (2400, 2390), (1500, 1490), (31.5, 30.0), 149.5, (1 << 8) | (1 << 9), 3)
    ok_sensor("sensor_landed_reserved_bits", "reserved status bits 18-31 are ignored by receivers, not rejected",
              7, 7000, (3900, 3910), (2, 3), (0.0, 0.0), 151.0, 0x00040000, 4)
    ok_sensor("sensor_zero", "an all-zero sample (OFF): the COBS encoding is mostly code bytes",
              0, 0, (0, 0), (0, 0), (0.0, 0.0), 0.0, 0, 0)
    ok_command("command_run", "answers sensor 1000 with 50 V and 49.75 V, RUN", 1000, (50.0, 49.75), 1)
    ok_command("command_hold", "hold the last voltages", 1001, (50.0, 49.75), 2)
    ok_command("command_land", "request the board's landing law (u ignored)", 1002, (0.0, 0.0), 3)
    ok_command("command_off_negative", "OFF with negative voltages in u (ignored by the board); seq 0",
               0, (-150.0, -0.001), 0)
    good_cfg = config(CONFIG_SUP, CONFIG_CAL, 1)
    crc = struct.unpack("<I", good_cfg[-4:])[0]
    ok_config("config_defaults", "the project's defaults: safety specs, Table 2, 1 ms, data-sheet calibration, delay 1",
              CONFIG_SUP, CONFIG_CAL, 1)
    ok_config("config_delay_2_negative_offsets", "command delay 2, a gap offset below zero, a negative current gain",
              (*CONFIG_SUP[:13], 40.0, 33.0, 9.81, 0.001),
              (-1e-4, 2.5e-7, 8e-13, 1e-18, 0.0, 2.4e-7, 9e-13, 0.0, -3e-4, 3e-4, 32000.0, 33000.5), 2)
    ok_config_ack("config_ack_accepted", "the defaults accepted in OFF: the active CRC is the request's (its CRC "
                  "field)", crc, crc, 0, 1, 0)
    ok_config_ack("config_ack_busy", "refused while levitating: the board keeps its compiled-in defaults",
                  0x1234ABCD, crc, 8, 0, 1)
    ok_config_ack("config_ack_no_braking", "an invalid configuration refused in LANDED; the one set before stays",
                  0x0BADF00D, 0xFFFFFFFF, 4, 1, 4)

    good_s = sensor(1000, 1_000_000, (2048, 2051), (1700, 1702), (50.0, 49.75), 150.0, 0, 1)
    good_c = command(1000, (50.0, 49.75), 1)
    bad("empty", "no bytes at all", b"", "short")
    bad("short_7", "seven bytes: less than a header and a CRC", good_c[:7], "short")
    bad("truncated_sensor", "a sensor frame missing its last byte", good_s[:-1], "length")
    bad("extended_command", "a command frame with one extra byte", good_c + b"\x00", "length")
    flipped = bytearray(good_s)
    flipped[20] ^= 0x04
    bad("bitflip_payload", "one bit flipped in the sensor payload", bytes(flipped), "crc")
    flipped = bytearray(good_c)
    flipped[-1] ^= 0x80
    bad("bitflip_crc", "one bit flipped in the CRC itself", bytes(flipped), "crc")
    bad("sensor_version_2", "a sensor frame of protocol version 2 (CRC valid)",
        sensor(1, 1, (1, 1), (1, 1), (0.0, 0.0), 0.0, 0, 0, version=2), "version")
    bad("hello_version_0", "a hello of version 0", hello(0, 1, 1000, 12, 3.0, 50), "version")
    bad("unknown_type", "type 9, 24 bytes, CRC valid", seal(struct.pack("<BBH", 1, 9, 24) + bytes(16)), "type")
    bad("sensor_size_24", "type sensor but 24 bytes (CRC valid)", seal(struct.pack("<BBH", 1, 2, 24) + bytes(16)),
        "size")
    bad("command_reserved", "a command with a reserved byte set", command(5, (1.0, 1.0), 1, reserved=b"\0\1\0"),
        "reserved")
    bad("sensor_reserved", "a sensor frame with its last reserved byte set",
        sensor(1, 1, (1, 1), (1, 1), (0.0, 0.0), 0.0, 0, 1, reserved=b"\0\0\x80"), "reserved")
    bad("sensor_mode_6", "a sensor frame with mode 6", sensor(1, 1, (1, 1), (1, 1), (0.0, 0.0), 0.0, 0, 6), "mode")
    bad("command_mode_landed", "a command may not request LANDED", command(5, (0.0, 0.0), 4), "mode")
    bad("command_mode_fault", "a command may not request FAULT", command(5, (0.0, 0.0), 5), "mode")
    bad("command_nan", "a NaN voltage", command(5, (math.nan, 0.0), 1), "nonfinite")
    bad("sensor_bus_inf", "an infinite bus voltage", sensor(1, 1, (1, 1), (1, 1), (0.0, 0.0), math.inf, 0, 1),
        "nonfinite")
    bad("hello_adc_17", "a 17-bit ADC does not fit the u16 counts", hello(1, 1, 1000, 17, 3.0, 50), "range")
    bad("hello_vref_negative", "a negative ADC reference", hello(1, 1, 1000, 12, -3.0, 50), "range")
    bad("config_size_24", "type config but 24 bytes (CRC valid)", seal(struct.pack("<BBH", 1, 4, 24) + bytes(16)),
        "size")
    bad("config_truncated", "a config frame missing its last byte", good_cfg[:-1], "length")
    bad("config_version_2", "a config frame of protocol version 2", config(CONFIG_SUP, CONFIG_CAL, 1, version=2),
        "version")
    bad("config_reserved", "a config frame with a reserved byte set", config(CONFIG_SUP, CONFIG_CAL, 1,
                                                                             reserved=b"\0\0\1"), "reserved")
    bad("config_nan_mass", "a NaN mass", config((*CONFIG_SUP[:7], math.nan, *CONFIG_SUP[8:]), CONFIG_CAL, 1),
        "nonfinite")
    bad("config_inf_offset", "an infinite current offset", config(CONFIG_SUP, (*CONFIG_CAL[:11], -math.inf), 1),
        "nonfinite")
    bad("config_ack_reserved", "a config ack with its reserved byte set", config_ack(1, 1, 0, 1, 0, reserved=b"\2"),
        "reserved")
    bad("config_ack_mode_6", "a config ack with mode 6", config_ack(1, 1, 0, 1, 6), "mode")
    bad("config_ack_result_9", "a result the protocol does not define", config_ack(1, 1, 9, 1, 0), "range")
    bad("config_ack_configured_2", "the configured flag is 0 or 1", config_ack(1, 1, 0, 2, 0), "range")


if __name__ == "__main__":
    main()
