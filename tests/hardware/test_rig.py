"""The rig emulator's board, one tick at a time (no clock, no socket), and its fault specifications."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem_ros.core.controllers import make_controller
from dem_ros.core.estimator import make_estimator
from dem_ros.core.params import default_config
from dem_ros.hardware.driver import HwDriver
from dem_ros.hardware.link import HELLO_REQUEST, CommandFrame, Hello, Mode, SensorFrame, Status, decode, encode
from dem_ros.hardware.rig import Board, RigError, parse_fault

MS = 1_000_000


def make(faults=(), **rig):
    cfg = default_config()
    cfg["plant_sim"]["measure_velocity"] = False
    cfg["rig"].update(rig)
    b = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], [parse_fault(f) for f in faults])
    hello = decode(b.receive(encode(HELLO_REQUEST)))
    return b, cfg, hello


class Loop:
    """The graph's estimator and controller (the core classes the nodes run), in process: hold the hover."""

    def __init__(self, cfg):
        self.est = make_estimator(cfg["estimator"], None, False)
        self.ctrl = make_controller(cfg["controller"])
        g = cfg["plant_sim"]["gap0"]
        self.ref = np.array([g, g, 0, 0, 0, 0, 0, 0], dtype=float)
        self.started = False

    def __call__(self, s) -> np.ndarray:
        z = np.array([s.gap[0], 0.0, s.gap[1], 0.0, s.current[0], s.current[1]])
        xh = self.est.step(z, s.applied)
        if not self.started:
            self.ctrl.reset(xh.copy(), s.applied)
            self.started = True
        return self.ctrl.step(xh, self.ref).copy()


def exchange(b: Board, drv: HwDriver):
    """One board tick through the driver: the sample the driver publishes (None: no frame or none to publish);
    the driver's reply (a command, or the run's configuration) goes to the board, and the board's answer to a
    configuration back to the driver."""
    data = b.tick()
    if data is None:
        return None
    s, reply = drv.on_bytes(data, 10**18 + b.n * MS, b.n * MS)
    if reply is not None:
        answer = b.receive(reply)
        if answer is not None:
            drv.on_bytes(answer, 10**18 + b.n * MS, b.n * MS)
    return s


def hover_loop(b: Board, cfg, n: int, drv: HwDriver | None = None, skip=lambda k: False):
    """Close the loop through the link codec and the driver, one board tick at a time (no clock)."""
    drv = drv or HwDriver(cfg["hw_driver"] | {"clock_sync_frames": 1, "arm_samples": 1})
    if drv.state.name == "INACTIVE":
        drv.arm()
    law = Loop(cfg)
    frames = []
    for _ in range(n):
        s = exchange(b, drv)
        if s is None:
            continue
        frames.append(s)
        u = law(s)
        if skip(s.seq):
            continue
        cmd = drv.command(s.stamp_ns, u, b.n * MS)
        if cmd is not None:
            b.receive(cmd)
    return drv, frames


def test_hello_reports_rate_adc_and_watchdog():
    _b, cfg, hello = make()
    assert isinstance(hello, Hello)
    assert (hello.rate_hz, hello.adc_bits, hello.watchdog_ms, hello.command_delay) == \
        (1000, 16, round(cfg["plant_sim"]["hold_timeout"] * 1e3), cfg["hw_driver"]["command_delay"])


def test_sensor_frames_invert_the_drivers_calibration_to_one_count():
    b, cfg, _ = make()
    f = decode(b.tick())
    assert isinstance(f, SensorFrame) and f.seq == 0 and f.mode == Mode.OFF
    drv = HwDriver(cfg["hw_driver"] | {"clock_sync_frames": 1})
    s, _ = drv.on_bytes(encode(f), 10**18, 0)
    gap0 = cfg["plant_sim"]["gap0"]
    assert np.allclose(s.gap, gap0, atol=0.6e-6)  # half a count of the 16-bit gap ADC (~0.3 um/count)
    assert np.allclose(s.current, b.plant.x[4:6], atol=0.5 * cfg["hw_driver"]["current1_gain"])
    assert np.allclose(s.applied, b.plant.u0, atol=1e-4)  # clamped at hover: the hover voltage


def test_clamped_until_the_first_run_command_then_the_loop_holds_the_hover():
    b, cfg, _ = make()
    for _ in range(5):
        b.tick()
    assert b.released_at is None and b.plant.x[0] == cfg["plant_sim"]["gap0"]
    _drv, _frames = hover_loop(b, cfg, 600)
    assert b.released_at is not None and Mode(b.sup.mode) == Mode.RUN
    assert b.c.commands_fresh >= 590
    # levitating near the hover (the adaptive law's start-up transient is a few 0.1 mm at most)
    assert (abs(b.plant.x[0] - cfg["plant_sim"]["gap0"]) < 0.5e-3
            and abs(b.plant.x[2] - cfg["plant_sim"]["gap0"]) < 0.5e-3)


def test_without_commands_the_board_holds_then_lands_on_its_support_and_never_nears_the_rail():
    b, cfg, _ = make()
    cutoff = 300
    drv, frames = hover_loop(b, cfg, 4000, skip=lambda k: k > cutoff)
    pc = cfg["plant_sim"]
    gaps = np.array([f.gap for f in frames])
    assert Mode(b.sup.mode) == Mode.LANDED
    assert gaps.min() > pc["trip_gap_min"]  # no rail contact, not even near it
    assert b.plant.x[0] == pytest.approx(cfg["rig"]["support_gap"]) and abs(b.plant.x[4]) < 0.05  # resting, no current
    s = b.summary()  # what a process-level test reads: one landing, touch-down no faster than landing_speed
    assert s["landings"] == 1 and 0 < s["land_speed_max_mm_s"] <= pc["landing_speed"] * 1e3, s
    landing = np.array([f.mode == Mode.LAND for f in frames])
    v = np.diff(gaps, axis=0)[landing[1:]] / 1e-3  # descent speed while the landing law flies (quantised gaps)
    assert landing.sum() > 100 and v.max() <= pc["landing_speed"] * 1.2
    assert drv.state.name == "FAULT" and "watchdog" in drv.reason  # the driver saw it too


def landed(b, d):
    return Mode(b.sup.mode) == Mode.LANDED and d.state.name == "FAULT"


@pytest.mark.parametrize("spec, check", [
    # a dead sensor: held by the driver, then a trip; the board (NaN for that channel) rides its observer, lands
    ("dropout:1@0.1+0.05", lambda b, d: landed(b, d) and "gap sensor 1" in d.reason
     and d.counters["sensor_holds"] >= 3),
    # one saturated sample: held for that sample, counted, no trip
    ("spike:2@0.1", lambda b, d: d.status_counts["GAP1_RANGE"] == 1 == d.counters["sensor_holds"]
     and d.state.name == "ACTIVE"),
    # corrupted sensor frames: every one rejected by CRC and counted, the loop goes on
    ("corrupt@0.1+0.05:0.5", lambda b, d: d.corrupt_reasons.get("crc") == b.c.corrupted_tx > 5
     and d.state.name == "ACTIVE"),
    # 50 ms without a link: lost frames counted; the board's watchdog lands the plate
    ("linkloss@0.1+0.05", lambda b, d: d.counters["lost"] >= 49 and Mode(b.sup.mode) == Mode.LANDED
     and b.faults[0].hits == b.c.link_lost_ticks == 50),
    # the bus sags below what holds the plate: the driver trips on the board's status, the board lands
    ("sag@0.1+0.05:60", lambda b, d: landed(b, d) and "BUS_UNDERVOLTAGE" in d.reason),
    # a coil driver fails: reported by the board, the driver trips, the board lands; the board's flux check
    # integrates what the bridges applied (0 V on the failed one), so it does not take the fault for a sensor's
    ("coil:1@0.1+0.02", lambda b, d: landed(b, d) and "DRIVER0_FAULT" in d.reason
     and b.sup.counters["implausible"] == 0),
    # a sensor stuck while the plate holds still: nothing moves that the coils' fluxes could contradict (a
    # stuck sensor on a moving plate: test_a_stuck_gap_sensor_is_found_by_the_flux_check_and_the_plate_landed)
    ("stuck:1@0.1+0.05", lambda b, d: b.faults[0].hits >= 50 and d.state.name == "ACTIVE"),
])
def test_each_injected_fault_is_counted_and_reported_never_raised(spec, check):
    b, cfg, _ = make([spec])
    drv, frames = hover_loop(b, cfg, 1500)
    assert b.faults[0].hits > 0  # a link loss too: the samples it kept off the link
    assert check(b, drv), (b.summary(), drv.status())
    assert b.failed is None  # the plant never touched the rail, whatever the fault did
    assert min(f.gap.min() for f in frames) > cfg["plant_sim"]["trip_gap_min"]


def test_the_boards_own_watchdog_landing_is_flagged_link_timeout():
    """The PC falls silent (no command, no LAND request): after hold_timeout the board lands on its own and
    every landing frame says why (LINK_TIMEOUT), so the driver can report the board's watchdog, not "its own
    trip" (the rig catalogue's kill-controller row, before)."""
    b, cfg, _ = make()
    hover_loop(b, cfg, 300)
    frames = [decode(d) for d in (b.tick() for _ in range(200)) if d is not None]
    assert b.sup.command_timeout and "no command for" in b.sup.reason
    landing = [f for f in frames if f.mode == Mode.LAND]
    assert landing and all(f.status & Status.LINK_TIMEOUT for f in landing)


def test_a_fault_lasts_its_duration_in_samples_whatever_the_float_sums():
    """0.1 + 0.05 is 0.15000000000000002 in floats: the window is on the board's sample grid, 50 samples."""
    for spec, n in (("linkloss@0.1+0.05", 50), ("linkloss@2.5+0.05", 50), ("dropout:1@2.5+0.0015", 2),
                    ("spike:1@0.3", 1), ("corrupt@1.7+0.5:0.1", 500)):
        k0, k1 = parse_fault(spec).window(1e-3)
        assert k1 - k0 == n, spec
    assert parse_fault("sag@3:80").window(1e-3) == (3000, math.inf)


def test_fault_specifications_are_checked_with_a_clear_message():
    f = parse_fault("dropout:2@1.5+0.25")
    assert (f.kind, f.channel, f.start, f.end) == ("dropout", 2, 1.5, 1.75)
    assert math.isinf(parse_fault("sag@3:80").end) and parse_fault("sag@3:80").value == 80
    for bad in ("dropout@1", "linkloss@1", "nonsense@1", "sag:1@2", "corrupt@1:2", "dropout:3@1", "spike:1"):
        with pytest.raises(RigError, match="expected KIND"):
            parse_fault(bad)


def test_an_operator_off_after_landing_clears_the_board():
    b, _cfg, _ = make()
    b.sup.land("test")
    for _ in range(3):
        b.tick()
    b.sup.mode = Mode.LANDED
    b.receive(encode(CommandFrame(b.n - 1, (0.0, 0.0), Mode.OFF)))
    b.tick()
    assert Mode(b.sup.mode) == Mode.OFF
    assert Status.LINK_TIMEOUT not in Status(0)


def s1_lockstep(b: Board, cfg, duration: float, d: int = 2):
    """S1 through the rig board, the link codec and the driver, closed by the graph's estimator and controller
    at command_delay d, every command in time (no clock). Returns (tracking errors (n, 2) [m] from t = 0,
    the driver); stops at ``duration`` or when the emulated plate fails."""
    from dem_ros.core.reference import ReferenceModel, command

    cfg["controller"]["command_delay"] = cfg["hw_driver"]["command_delay"] = cfg["plant_sim"]["command_delay"] = d
    b.delay = d
    drv = HwDriver(cfg["hw_driver"] | {"clock_sync_frames": 1})
    drv.arm()
    law = Loop(cfg)
    model = ReferenceModel(cfg["reference"])
    rest = model.step_hold().copy()
    epoch = None
    e = []
    for _ in range(round((duration + 1.5) / 1e-3)):
        s = exchange(b, drv)
        if s is None:
            continue
        if epoch is None and b.released_at is not None:
            epoch = b.released_at + b.n_pre  # the driver's t = 0: preroll after the release
        k = s.seq - epoch if epoch is not None else -1
        law.ref[:] = rest if k <= 0 else model.step(command(cfg["reference"], k * 1e-3))
        if k >= 0:
            truth = b.plant.x  # (the state this frame sampled: the board integrates after sending)
            e.append(np.array([truth[0], truth[2]]) - law.ref[:2])
        u = law(s)
        cmd = drv.command(s.stamp_ns, u, b.n * MS)
        if cmd is not None:
            b.receive(cmd)
        if k >= duration / 1e-3 or b.failed:
            break
    return np.array(e), drv


def test_s1_through_the_board_models_in_lockstep_tracks_as_offline():
    """The hardware path without the clock: rig sensors (16-bit ADC, calibration), actuators (12-bit PWM,
    bus sag), the Supervisor, the link codec and the driver, closed by the graph's estimator and
    controller at command_delay 2, every command in time. Tracks S1 within max(2x offline, offline +
    10 um) RMS: what the free-running runs lose is the clock (docs/results.md: hardware in the loop)."""
    from dem_ros.core.simulate import simulate

    duration = 12.0
    b, cfg, _ = make()
    e, drv = s1_lockstep(b, cfg, duration)
    assert b.failed is None and Mode(b.sup.mode) == Mode.RUN and drv.state.name == "ACTIVE"
    rms = np.sqrt(np.mean(np.square(e), axis=0)) * 1e6
    off = np.array(simulate(cfg, controller="adaptive", estimator="kf", duration=duration,
                            scenario="S1").metrics()["rms_error_um"])
    print(f"lockstep rig RMS {rms} um, offline {off} um")
    assert np.all(rms <= np.maximum(2 * off, off + 10.0)), (rms, off)


@pytest.mark.parametrize("rogue", [(200.0, 200.0), (200.0, 0.0)], ids=["both-coils-u_max", "one-coil-u_max"])
def test_a_diverged_controller_is_braked_before_the_rail(rogue):
    """The #11 finding through the whole board: after 300 ms of hover the PC forwards a diverged law's
    saturated command; the board trips on the predicted stopping gap, brakes with the bus it measures and
    lands the plate on its support. The summary reports the true smallest gap (never below trip_gap_min)
    and the supervisor's snapshot."""
    b, cfg, _ = make()
    drv, _ = hover_loop(b, cfg, 300)
    assert Mode(b.sup.mode) == Mode.RUN
    for _ in range(3000):
        s = exchange(b, drv)
        if s is not None:
            cmd = drv.command(s.stamp_ns, np.array(rogue), b.n * MS)
            if cmd is not None:
                b.receive(cmd)
        if Mode(b.sup.mode) == Mode.LANDED:
            break
    s = b.summary()
    assert s["mode"] == "LANDED" and s["failed"] == "" and "predicted stopping gap" in s["reason"]
    assert s["min_gap_mm"] > cfg["plant_sim"]["trip_gap_min"] * 1e3
    assert s["supervisor"]["trips"] == 1 and s["supervisor"]["min_stop_gap_mm"] < cfg["plant_sim"]["trip_gap_min"] * 1e3


@pytest.mark.parametrize("spec", ["stuck:1@2.5+1", "stuck:2@11.5+1"], ids=["gap1-in-its-step", "gap2-in-its-step"])
def test_a_stuck_gap_sensor_is_found_by_the_flux_check_and_the_plate_landed(spec):
    """The #11 rail contact: a gap sensor freezes at a plausible reading while its end moves (S1: r1 steps at
    1 s, r2 at 10 s; the fault 1.5 s after, times since the release, the pre-roll is 1 s). Controller and
    estimator steer by the frozen reading and the unstable plate drifts off it (before the board's flux check
    it reached the rail 183 ms later). The board finds the sensor contradicting the coils' fluxes, flags
    GAPj_IMPLAUSIBLE (the driver trips on it) and lands on that coil's flux: never near the rail, descent
    within landing_speed. Measured: found 0.55 mm off, the plate at 6.1 mm at its closest, 8.6 mm/s."""
    j = int(spec.split(":")[1][0]) - 1
    b, cfg, _ = make([spec])
    pc = cfg["plant_sim"]
    s1_lockstep(b, cfg, 5.0 + 9.0 * j)
    s = b.summary()
    assert s["failed"] == "" and s["mode"] == "LANDED", s
    assert s["supervisor"]["implausible"] == 1 and b.sup.implausible == [j == 0, j == 1]
    assert f"gap sensor {j + 1} implausible" in s["supervisor"]["fault"]
    assert s["min_gap_mm"] > 3.0 and s["land_speed_max_mm_s"] <= pc["landing_speed"] * 1e3, s
    print(f"\n{spec}: {s['supervisor']['fault']}; closest {s['min_gap_mm']:.2f} mm, "
          f"descent {s['land_speed_max_mm_s']:.1f} mm/s")
