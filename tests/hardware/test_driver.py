"""The hardware driver's state machine, calibration, clock map and link accounting (no middleware, no I/O)."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.core.params import SCHEMA
from dem_ros.hardware.boardcfg import config_crc, config_frame
from dem_ros.hardware.driver import Calibration, DriverError, DriverState, HwDriver, load_gap_table
from dem_ros.hardware.link import CommandFrame, ConfigAck, ConfigFrame, Hello, Mode, SensorFrame, decode, encode

MS = 1_000_000
CFG = SCHEMA.defaults("hw_driver") | {"arm_samples": 1}  # (arm_samples has its own test)
# counts of the default calibration near 5 mm and 2.5 A (gap = c1 n + c2 n^2; i = g (n - o))
N_GAP = 19283
N_CUR = 32768 + 8192


def sensor(seq: int, *, gap=(N_GAP, N_GAP), cur=(N_CUR, N_CUR), mode=Mode.RUN, applied=(50.0, 50.0),
           bus=200.0) -> bytes:
    return encode(SensorFrame(seq, seq * 1000, gap, cur, applied, bus, 0, mode))


def board_ack(cfg, result: int = 0, active: int | None = None, configured: bool = True, mode=Mode.OFF) -> bytes:
    """The board's answer to the run's configuration (``cfg``: the driver's parameters); by default: accepted."""
    crc = config_crc(config_frame(cfg))
    return encode(ConfigAck(crc if active is None else active, crc, result, configured, mode))


def synced(cfg=None, frames: int | None = None) -> tuple[HwDriver, int]:
    """A driver past its handshake (hello, the run's configuration confirmed by the board) and clock sync (frames
    0..n-1 received 200 us after they were taken); returns (driver, next seq)."""
    cfg = {**CFG, **(cfg or {})}
    d = HwDriver(cfg)
    _, reply = d.on_bytes(encode(Hello(1, 7, 1000, 16, 10.0, 20)), 0, 0)
    assert decode(reply) == config_frame(cfg)  # the hello's answer: the run's configuration
    d.on_bytes(board_ack(cfg), 0, 0)
    assert d.configured
    n = cfg["clock_sync_frames"] if frames is None else frames
    for k in range(n):
        d.on_bytes(sensor(k), 10**18 + k * MS + 200_000, k * MS)
    return d, n


def feed(d: HwDriver, k: int, **kw):
    return d.on_bytes(sensor(k, **{k_: v for k_, v in kw.items() if k_ != "latency"}),
                      10**18 + k * MS + kw.get("latency", 200_000), k * MS)


# -- calibration ----------------------------------------------------------------------------------
def test_gap_polynomial_is_the_cubic_per_sensor():
    cfg = {**CFG, "gap1_c0": 1e-4, "gap1_c1": 2e-7, "gap1_c2": 3e-13, "gap1_c3": 1e-18, "gap2_c1": 3e-7}
    cal = Calibration(cfg)
    n = np.array([12345, 40000])
    g = cal.gap(n)
    assert g[0] == pytest.approx(np.polyval([1e-18, 3e-13, 2e-7, 1e-4], 12345), rel=1e-12)
    assert g[1] == pytest.approx(np.polyval([0.0, 8e-13, 3e-7, 0.0], 40000), rel=1e-12)


def test_current_gain_offset_and_duty_voltage():
    cal = Calibration({**CFG, "current2_gain": -1e-3, "current2_offset": 100.0, "voltage_input": "duty"})
    i = cal.current([32768 + 16384, 0])
    assert i[0] == pytest.approx(5.0)
    assert i[1] == pytest.approx(0.1)
    assert cal.voltage((0.25, -0.5), 200.0) == pytest.approx([50.0, -100.0])
    assert cal.command(np.array([50.0, -400.0]), 200.0) == pytest.approx((0.25, -1.0))  # duty saturates at -1
    assert cal.command(np.array([50.0, 50.0]), 0.0) == (0.0, 0.0)  # no bus: no duty


def test_gap_table_interpolates_and_bad_tables_are_clear_errors(tmp_path):
    p = tmp_path / "cal.csv"
    p.write_text("# counts, gap1, gap2\n0, 0.0, 0.0\n1000, 0.001, 0.002\n3000, 0.002, 0.003\n")
    cal = Calibration({**CFG, "gap_table": str(p)})
    assert cal.gap([500, 2000]) == pytest.approx([0.0005, 0.0025])
    p.write_text("0, 0.0, 0.0\n0, 0.001, 0.002\n")
    with pytest.raises(DriverError, match="strictly increasing"):
        load_gap_table(str(p))
    with pytest.raises(DriverError, match="cannot read"):
        load_gap_table(str(tmp_path / "missing.csv"))


# -- clock map and link accounting ------------------------------------------------------------------
def test_clock_offset_is_the_minimum_delay_and_stamps_stay_on_the_board_grid():
    d = HwDriver(CFG)
    rng = np.random.default_rng(3)
    lat = rng.integers(150_000, 900_000, CFG["clock_sync_frames"])
    lat[17] = 120_000  # the fastest frame sets the offset
    for k, L in enumerate(lat):
        s, _ = d.on_bytes(sensor(k), 10**18 + k * MS + int(L), 0)
        assert (s is None) == (k < len(lat) - 1)  # nothing is published before the clock is synced
    assert d.offset_ns == 10**18 + 120_000
    stamps = []
    for k in range(200, 260):
        s, _ = d.on_bytes(sensor(k), 10**18 + k * MS + int(rng.integers(150_000, 3_000_000)), 0)
        stamps.append(s.stamp_ns)
        assert s.latency_ns >= 0
    assert np.all(np.diff(stamps) == MS)  # one board period apart, whatever the jitter


def test_lost_duplicated_reordered_late_and_corrupt_frames_are_counted():
    d, k = synced()
    assert feed(d, k)[0] is not None
    assert feed(d, k)[0] is None  # duplicate
    assert feed(d, k + 3)[0] is not None  # two lost
    assert feed(d, k + 2)[0] is None  # older than the newest
    assert feed(d, k + 4, latency=5 * MS)[0] is not None  # late, still published
    bad = bytearray(sensor(k + 5))
    bad[9] ^= 0xFF
    assert d.on_bytes(bytes(bad), 0, 0) == (None, None)
    assert d.on_bytes(b"\x01\x02", 0, 0) == (None, None)
    c = d.counters
    assert (c["duplicated"], c["lost"], c["reordered"], c["late"], c["corrupt"]) == (1, 2, 1, 1, 2)
    assert d.corrupt_reasons == {"crc": 1, "short": 1}


def test_ten_thousand_random_and_mutated_frames_are_rejected_by_count_never_raised():
    d, k = synced()
    rng = np.random.default_rng(11)
    good = sensor(k + 1)
    rejected = 0
    for i in range(10_000):
        if i % 2:
            data = rng.bytes(int(rng.integers(0, 80)))
        else:
            b = bytearray(good)
            for _ in range(int(rng.integers(1, 4))):
                b[int(rng.integers(0, len(b)))] ^= int(rng.integers(1, 256))
            data = bytes(b)
        sample, _ = d.on_bytes(data, 10**18, 0)
        rejected += sample is None
    assert d.counters["corrupt"] >= 9_990  # a random 4-byte CRC matches with p = 2^-32
    assert sum(d.corrupt_reasons.values()) == d.counters["corrupt"]
    assert rejected >= 9_990


def test_a_board_with_another_rate_is_a_fault_one_with_another_command_delay_is_configured_with_ours():
    d = HwDriver(CFG)
    assert d.on_bytes(encode(Hello(1, 7, 500, 16, 10.0, 20)), 0, 0) == (None, None)
    assert d.state == DriverState.FAULT and "500 Hz" in d.reason
    d = HwDriver(CFG)
    _, reply = d.on_bytes(encode(Hello(1, 7, 1000, 16, 10.0, 20, 3)), 0, 0)
    f = decode(reply)
    assert isinstance(f, ConfigFrame) and f.command_delay == CFG["command_delay"] == 1
    assert d.state == DriverState.INACTIVE and not d.configured  # until the board's answer says it runs it
    d.on_bytes(board_ack(CFG), 0, 0)
    assert d.configured and d.status()["board_config"] == "confirmed"


# -- lifecycle, commands, watchdog, limits ------------------------------------------------------------
def test_commands_flow_only_when_armed_and_the_first_makes_the_driver_active():
    d, k = synced()
    s, _ = feed(d, k)
    assert d.command(s.stamp_ns, [50.0, 50.0], k * MS) is None  # inactive: dropped
    d.arm()
    assert d.state == DriverState.ARMED
    data = d.command(s.stamp_ns, [50.0, 51.0], k * MS)
    f = decode(data)
    assert d.state == DriverState.ACTIVE
    assert f == CommandFrame(k, (50.0, 51.0), Mode.RUN)
    s2, _ = feed(d, k + 1)
    assert d.command(s.stamp_ns, [50.0, 50.0], k * MS) is None  # for a sample the board has passed
    assert d.counters["commands_stale"] == 1
    assert d.command(s2.stamp_ns + 5 * MS, [50.0, 50.0], k * MS) is None  # from the future
    assert d.command(s2.stamp_ns, [np.nan, 50.0], k * MS) is None
    assert d.counters["commands_dropped"] == 3  # inactive, future, non-finite


def test_armed_becomes_active_only_after_arm_samples_commands_in_time():
    d, k = synced({"arm_samples": 3, "command_delay": 1})
    d.arm()
    for j in range(2):
        s, _ = feed(d, k + j)
        assert d.command(s.stamp_ns, [50.0, 50.0], (k + j) * MS) is None and d.state == DriverState.ARMED
    s, _ = feed(d, k + 2)
    feed(d, k + 3)
    assert d.command(s.stamp_ns, [50.0, 50.0], (k + 3) * MS) is None  # late: the count starts again
    for j in range(4, 6):
        s, _ = feed(d, k + j)
        assert d.command(s.stamp_ns, [50.0, 50.0], (k + j) * MS) is None
    s, _ = feed(d, k + 6)
    assert decode(d.command(s.stamp_ns, [50.0, 50.0], (k + 6) * MS)).seq == k + 6  # the third in a row
    assert d.state == DriverState.ACTIVE


def test_voltage_is_clipped_to_u_max_and_counted():
    d, k = synced({"u_max": 100.0})
    s, _ = feed(d, k)
    d.arm()
    f = decode(d.command(s.stamp_ns, [250.0, -250.0], k * MS))
    assert f.u == (100.0, -100.0)
    assert d.counters["clipped"] == 1


def test_watchdog_holds_for_hold_timeout_then_latches_a_fault_and_lands():
    d, k = synced({"hold_timeout": 0.02})
    d.arm()
    s, _ = feed(d, k)
    d.command(s.stamp_ns, [50.0, 50.0], k * MS)
    for j in range(1, 20):  # 19 ms without a command: the board holds, the driver counts
        _, reply = feed(d, k + j)
        assert reply is None and d.state == DriverState.ACTIVE
    assert d.counters["hold_samples"] == 18  # sample k+1 had its command
    _, reply = feed(d, k + 21)  # 21 ms
    assert d.state == DriverState.FAULT and "command watchdog" in d.reason
    assert decode(reply) == CommandFrame(k + 21, (0.0, 0.0), Mode.LAND)  # a landing, never a 0 V cut
    s, _ = feed(d, k + 22)
    assert d.command(s.stamp_ns, [50.0, 50.0], (k + 22) * MS) is None  # latched: commands no longer flow
    assert decode(feed(d, k + 23)[1]).mode == Mode.LAND
    d.arm()  # the operator re-arms: cleared
    assert d.state == DriverState.ARMED and d.reason == ""


def test_late_commands_are_not_forwarded_but_keep_the_watchdog_fed():
    d, k = synced({"hold_timeout": 0.02})
    d.arm()
    s, _ = feed(d, k)
    d.command(s.stamp_ns, [50.0, 50.0], k * MS)
    for j in range(1, 40):  # a slow controller: each command arrives after the next sample
        s, _ = feed(d, k + j)
        assert d.command(s.stamp_ns - MS, [50.0, 50.0], (k + j) * MS) is None
    assert d.state == DriverState.ACTIVE  # 40 ms without a usable command, but the controller lives
    assert d.counters["commands_stale"] == 39


def test_a_silent_link_trips_an_active_driver_on_the_steady_clock():
    d, k = synced({"link_timeout": 0.05, "hold_timeout": 1.0})
    d.arm()
    s, _ = feed(d, k)
    d.command(s.stamp_ns, [50.0, 50.0], k * MS)
    assert d.state == DriverState.ACTIVE
    d.check(k * MS + 40 * MS)
    assert d.state == DriverState.ACTIVE
    d.check(k * MS + 60 * MS)
    assert d.state == DriverState.FAULT and "link lost" in d.reason


def test_an_armed_driver_rides_through_a_host_stall_handshakes_again_and_counts_it():
    """Armed, not yet active: the board levitates nothing for the driver yet. A 52 ms stall of the host (no frame
    read) is no fault: the driver asks for a hello again, counts the stall and its length, and becomes active
    as usual once the board answers and the controller's commands come in time."""
    d, k = synced({"link_timeout": 0.05})
    d.arm()
    feed(d, k)
    d.check(k * MS + 52 * MS)  # the reader's timeout check, 52 ms after the last frame (the host stalled)
    assert d.state == DriverState.ARMED and d.reason == ""
    assert d.counters["stalls"] == 1 and d.counters["link_loss"] == 0
    assert d.status()["longest_stall_ms"] == pytest.approx(52.0)
    assert d.hello is None  # the node sends hello requests until the board answers again
    _, reply = d.on_bytes(encode(Hello(1, 7, 1000, 16, 10.0, 20)), 0, k * MS + 53 * MS)
    assert isinstance(decode(reply), ConfigFrame) and not d.configured  # the handshake again: hello, configuration
    d.on_bytes(board_ack(CFG), 0, k * MS + 53 * MS)
    s, _ = feed(d, k + 54)
    assert decode(d.command(s.stamp_ns, [50.0, 50.0], (k + 54) * MS)).mode == Mode.RUN
    assert d.state == DriverState.ACTIVE


def test_current_and_gap_trip_after_trip_samples_but_a_single_spike_only_counts():
    d, k = synced({"trip_samples": 3, "i_max": 6.0})
    d.arm()
    s, _ = feed(d, k)
    d.command(s.stamp_ns, [50.0, 50.0], k * MS)
    hot = 32768 + int(7.0 / CFG["current1_gain"])
    feed(d, k + 1, cur=(hot, N_CUR))
    feed(d, k + 2)
    assert d.state == DriverState.ACTIVE  # one sample over: no trip
    for j in range(3, 6):
        s, _ = feed(d, k + j, cur=(hot, N_CUR))
        d.command(s.stamp_ns, [50.0, 50.0], (k + j) * MS)
    assert d.state == DriverState.FAULT and "current limit" in d.reason
    d.arm()
    s, _ = feed(d, k + 6)
    d.command(s.stamp_ns, [50.0, 50.0], (k + 6) * MS)
    for j in range(7, 10):
        s, _ = feed(d, k + j, gap=(0, N_GAP))  # a dead sensor reads 0 m: towards the rail
        d.command(s.stamp_ns, [50.0, 50.0], (k + j) * MS)
    assert d.state == DriverState.FAULT and "gap limit" in d.reason
    assert d.counters["trips"] == 2


def test_estop_latches_and_disarm_lands_a_levitating_board():
    d, k = synced()
    d.arm()
    s, _ = feed(d, k)
    d.command(s.stamp_ns, [50.0, 50.0], k * MS)
    d.estop("operator")
    assert d.state == DriverState.FAULT and d.reason == "e-stop: operator"
    d.estop("again")
    assert d.reason == "e-stop: operator"  # the first reason stays
    assert decode(feed(d, k + 1)[1]).mode == Mode.LAND
    d.disarm()
    assert d.state == DriverState.INACTIVE
    assert decode(feed(d, k + 2, mode=Mode.RUN)[1]).mode == Mode.LAND  # still levitating: land it
    assert feed(d, k + 3, mode=Mode.LANDED)[1] is None  # landed: nothing more to say
    d.arm()
    # arming clears the board
    assert decode(feed(d, k + 4, mode=Mode.LANDED)[1]) == CommandFrame(k + 4, (0.0, 0.0), Mode.OFF)


def test_arm_re_arms_an_active_driver_whose_board_landed_on_its_own():
    """The board's hold_timeout (50 ms) is shorter than the driver's: in a host stall the board lands the plate while
    the driver stays ACTIVE. The operator's arm must then re-arm (it said 'already active' and nothing changed: the
    board stayed LANDED, ignoring every command, and the restarted controller never lifted off)."""
    d, k = synced()
    d.arm()
    s, _ = feed(d, k)
    d.command(s.stamp_ns, [50.0, 50.0], k * MS)
    assert d.state == DriverState.ACTIVE
    assert d.arm() == "already active"  # levitating: nothing to do
    feed(d, k + 1, mode=Mode.LAND)
    assert d.arm() == "already active" and d.state == DriverState.ACTIVE  # landing: not yet
    feed(d, k + 2, mode=Mode.LANDED)
    assert d.arm().startswith("armed (was active)") and d.state == DriverState.ARMED
    assert decode(feed(d, k + 3, mode=Mode.LANDED)[1]) == CommandFrame(k + 3, (0.0, 0.0), Mode.OFF)  # clears the board
    s, _ = feed(d, k + 4, mode=Mode.OFF)
    assert decode(d.command(s.stamp_ns, [50.0, 50.0], (k + 4) * MS)).mode == Mode.RUN
    assert d.state == DriverState.ACTIVE
