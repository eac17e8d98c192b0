"""The controller's input checks and the lift-off pieces of hover.py, tested as math."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.core.controllers.checks import InputChecks, reference_speed_bound
from dem_ros.core.controllers.hover import (
    LIFT_DETECT,
    LIFTOFF_CLEARANCE,
    LIFTOFF_SPEED,
    PREMAG_FRACTION,
    departure_acceleration,
    lift_fraction,
    liftoff_duration,
    liftoff_reference,
    liftoff_target,
    premagnetise,
)
from dem_ros.core.params import SCHEMA
from dem_ros.core.reference import ReferenceModel, command

CC = SCHEMA.defaults("controller")
RC = SCHEMA.defaults("reference")
MS = 1_000_000


def test_the_default_speed_bound_is_the_bound_of_the_default_reference_model():
    v = reference_speed_bound((RC["a0"], RC["a1"], RC["a2"]), RC["b0"], CC["reference_gap_min"],
                              CC["reference_gap_max"])
    assert v == pytest.approx(1.538e-3, rel=1e-3)
    assert v <= CC["reference_max_speed"] <= 1.03 * v  # the schema's default: the bound, rounded up


def test_the_speed_bound_is_tight_for_the_worst_command():
    """Eq. (1): the worst command switches between the range's ends as sign(h'(t0 - t)) does; a seeded random
    schedule stays below the bound, the bang-bang one reaches it to 1 %."""
    lo, hi = CC["reference_gap_min"], CC["reference_gap_max"]
    v = reference_speed_bound((RC["a0"], RC["a1"], RC["a2"]), RC["b0"], lo, hi)
    cfg = {**RC, "dt": 1e-3}
    n = 40_000
    t = np.arange(n) * 1e-3
    # h'(tau) changes sign once, at the peak of h (the peak speed of a unit step's response)
    m = ReferenceModel(cfg)
    m.reset(0.0)
    step = m.run(np.ones((n, 2)))
    tau_star = float(np.argmax(step[:, 2])) * 1e-3
    t0 = t[-1]
    r = np.where((t0 - t) < tau_star, hi, lo)  # h' > 0 before the peak: r = hi there, lo elsewhere
    m = ReferenceModel(cfg)
    m.reset(lo)
    y = m.run(np.stack([r, r], axis=1))
    assert np.abs(y[:, 2]).max() == pytest.approx(v, rel=0.01)
    rng = np.random.default_rng(3)
    r2 = np.repeat(rng.uniform(lo, hi, n // 500), 500)
    m.reset(0.5 * (lo + hi))
    y2 = m.run(np.stack([r2, r2], axis=1))
    assert np.abs(y2[:, 2]).max() < v


def _checks(**over) -> InputChecks:
    c = InputChecks({**CC, **over})
    c.plant_stamp(0)
    return c


def _clock(ch: InputChecks, t_ns: int) -> None:
    """Move the plant's clock to ``t_ns``: a jump takes two samples in a row (a lone one is refused)."""
    ch.plant_stamp(t_ns - MS)
    ch.plant_stamp(t_ns)
    assert ch.t_plant == t_ns


def test_a_lone_plant_stamp_far_ahead_or_behind_does_not_move_the_clock():
    """One corrupt /dem/applied_voltage (+1 h, or far behind) is refused and counted; the next samples
    go on; two samples in a row after a real jump (lost samples) move it."""
    ch = _checks()
    for k in range(1, 10):
        assert ch.plant_stamp(k * MS)
    assert not ch.plant_stamp(3_600_000 * MS) and ch.t_plant == 9 * MS
    assert ch.plant_stamp(10 * MS) and ch.estimate(10 * MS) == ""  # the stream goes on, estimates on time
    assert not ch.plant_stamp(-5000 * MS) and ch.t_plant == 10 * MS
    assert ch.plant_stamp(8 * MS) and ch.t_plant == 10 * MS  # an older sample taken late: the clock stays
    assert not ch.plant_stamp(200 * MS) and ch.plant_stamp(201 * MS) and ch.t_plant == 201 * MS  # confirmed
    assert ch.stamps_refused == 3


def test_every_sample_of_the_default_schedule_is_accepted():
    cfg = {**RC, "dt": 1e-3}
    m = ReferenceModel(cfg)
    ch = _checks()
    for k in range(15_000):
        ref = m.step(command(cfg, k * 1e-3))
        ch.plant_stamp(k * MS)
        assert ch.reference(k * MS + MS, ref).ok, k


@pytest.mark.parametrize(("y", "key"), [(0.028, "reference_range"), (0.001, "reference_range"),
                                        (0.0081, "reference_rate"), (float("nan"), "reference_invalid")])
def test_a_step_or_an_implausible_gap_is_refused_and_the_last_good_one_held(y, key):
    ch = _checks()
    good = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])
    assert ch.reference(MS, good).ok
    v = ch.reference(2 * MS, np.array([y, 0.008, 0, 0, 0, 0, 0, 0]))
    assert not v.ok and v.key == key and v.why
    assert np.array_equal(ch.held_reference(), good)  # at rest at the last good gaps


def test_a_resumed_stream_is_accepted_as_soon_as_the_bound_allows_it():
    ch = _checks()
    assert ch.reference(0, np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])).ok
    moved = np.array([0.0075, 0.008, 0, 0, 0, 0, 0, 0])  # 0.5 mm away
    _clock(ch, 100 * MS)
    assert not ch.reference(100 * MS, moved).ok  # 100 ms at 1.55 mm/s: 0.155 mm at most
    _clock(ch, 350 * MS)
    assert ch.reference(350 * MS, moved).ok  # 350 ms: 0.54 mm


def test_a_too_fast_reference_is_refused():
    ch = _checks()
    assert not ch.reference(MS, np.array([0.008, 0.008, 0.01, 0, 0, 0, 0, 0])).ok  # 10 mm/s


def test_stamps_are_judged_on_the_plants_clock():
    ch = _checks()
    _clock(ch, 100 * MS)
    assert ch.estimate(100 * MS) == "" and ch.estimate(98 * MS) == ""  # d T = 1 ms late: on time; 2 ms: max_age
    assert ch.estimate(97 * MS) == "stale"
    assert ch.estimate(103 * MS) == "future"
    assert ch.reference(103 * MS, np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])).ok  # one period ahead is normal
    assert ch.reference(3_600_000 * MS, np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])).key == "reference_future"
    off = _checks(max_age=0.0)
    off.plant_stamp(100 * MS)
    assert off.estimate(0) == "" and off.estimate(10**12) == ""  # 0: no stamp checks


@pytest.mark.parametrize("v0,a0", [(None, None), ((-5.8e-3, -4e-3), (-0.21, -0.15))])
def test_liftoff_reference_is_c3_and_its_derivatives_are_its_derivatives(v0, a0):
    """Finite differences of the blend's position, speed and acceleration match the published derivatives; from rest,
    or starting with the rates of a plate that is already moving (the catch term), which fade."""
    y0 = np.array([0.0112, 0.0110])
    T = 1.3

    def stream(t):  # a moving reference stream: y = 8 mm + 0.5 mm sin(2 t)
        s, c = np.sin(2 * t), np.cos(2 * t)
        return np.array([0.008 + 5e-4 * s, 0.0075, 1e-3 * c, 0, -2e-3 * s, 0, -4e-3 * c, 0])

    h = 1e-5
    for t in np.linspace(0.0 if v0 is None else 2 * h, T + 0.2, 37):  # (the catch term starts at t = 0)
        f = [liftoff_reference(y0, stream(t + d), t + d, T, v0, a0) for d in (-h, 0.0, h)]
        for i in range(3):  # d/dt of [y, y', y''] against [y', y'', y''']
            fd = (f[2][2 * i:2 * i + 2] - f[0][2 * i:2 * i + 2]) / (2 * h)
            assert np.allclose(fd, f[1][2 * i + 2:2 * i + 4], rtol=1e-4, atol=1e-7 * 10**i), (t, i)
    start, end = liftoff_reference(y0, stream(0.0), 0.0, T, v0, a0), liftoff_reference(y0, stream(T), T, T, v0, a0)
    if v0 is None:
        assert np.array_equal(start, np.r_[y0, np.zeros(6)])  # at rest where the plate lies
    else:  # where the plate is, as fast as it moves
        assert np.allclose(start[:6], np.r_[y0, v0, a0], rtol=1e-12, atol=0.0)
    assert np.allclose(end, stream(T), rtol=0.0, atol=1e-7)  # handed over to the stream (the catch faded: e^-26)


def test_liftoff_duration_and_target():
    y0 = np.array([0.0112, 0.0112])
    ref = np.array([0.008, 0.0112, 0, 0, 0, 0, 0, 0])
    target, handover = liftoff_target(y0, ref)
    assert not handover and target[0] == 0.008 and target[1] == pytest.approx(0.0112 - LIFTOFF_CLEARANCE)
    dur = liftoff_duration(y0, target)
    assert dur == pytest.approx(35 / 16 * 3.2e-3 / LIFTOFF_SPEED)  # the blend's peak speed is LIFTOFF_SPEED
    speeds = [abs(liftoff_reference(y0, target, t, dur)[2]) for t in np.linspace(0, dur, 1001)]
    assert max(speeds) == pytest.approx(LIFTOFF_SPEED, rel=1e-4)


def test_lift_fraction_and_premagnetisation():
    gap = 0.008
    i_hover = premagnetise(np.array([gap, 0, gap, 0, 0, 0]), CC, 1.0)[0]
    z = np.array([gap, 0, gap, 0, *i_hover])
    assert lift_fraction(z, CC) == pytest.approx(1.0)  # the nominal hover carries the whole load
    assert lift_fraction(np.array([0.0112, 0, 0.0112, 0, 0, 0]), CC) == 0.0
    i_pm, u_pm = premagnetise(np.array([0.0112, 0, 0.0112, 0, 0, 0]), CC)
    assert lift_fraction(np.array([0.0112, 0, 0.0112, 0, *i_pm]), CC) == pytest.approx(PREMAG_FRACTION)
    assert np.allclose(u_pm, CC["R_nominal"] * i_pm)


def test_departure_acceleration_is_exact_for_a_constant_one_and_never_overstates_the_real_departure():
    """Constant acceleration from rest: exact. The magnets' departure, y_rest - y = A (cosh(lambda t) - 1) (lambda
    42 1/s, about sqrt(2 g / y) at the support): between 1/2 and 1 of the true acceleration A lambda^2 cosh(lambda t).
    Not risen LIFT_DETECT / 2, or not rising: 0."""
    g = 9.81
    rest = np.array([0.0112, 0.0112])
    for a in (0.05, 0.2, 0.5):
        t = 0.05  # s: risen 62 um or more
        y = rest - a * t * t / 2
        np.testing.assert_allclose(departure_acceleration(rest, y, np.array([-a * t, -a * t]), g), [-a, -a], rtol=1e-12)
    lam, A = 42.0, 2e-6
    for t in np.linspace(0.02, 0.2, 19):
        dy, v, a = A * (np.cosh(lam * t) - 1), A * lam * np.sinh(lam * t), A * lam**2 * np.cosh(lam * t)
        if dy < LIFT_DETECT / 2:  # not yet risen
            continue
        est = -departure_acceleration(rest, rest - dy, np.array([-v, -v]), g)
        assert np.all((0.5 * a <= est) & (est <= a * (1 + 1e-12))), (t, est, a)
    lifted = rest - np.array([LIFT_DETECT, LIFT_DETECT / 4])
    assert departure_acceleration(rest, lifted, np.array([-5e-3, -5e-3]), g)[1] == 0.0  # magnet 2 still down
    assert np.all(departure_acceleration(rest, rest - LIFT_DETECT, np.array([1e-3, 0.0]), g) == 0.0)  # falling, still
    # a lagging estimate (fast, barely risen): at most the negative stiffness's lambda^2 dy, lambda^2 = 2 g / y
    capped = departure_acceleration(rest, rest - LIFT_DETECT, np.array([-1.0, -1.0]), g)
    assert capped == pytest.approx(-2 * g * LIFT_DETECT / rest, rel=1e-12)
