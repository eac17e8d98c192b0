"""Extended Kalman filter (dem_ros.core.estimator) on the DEM model."""

from __future__ import annotations

import numpy as np
import pytest
from _symbolic import plant, values

from dem_ros.core.estimator import KalmanEstimator, PassThrough, ekf_step, jacobian, make_estimator
from dem_ros.core.model import plant_vector
from dem_ros.core.params import ConfigError, default_config
from dem_ros.core.scenarios import noise_samples

EC = default_config()["estimator"]


def replay(X: np.ndarray, U: np.ndarray, ecfg: dict, measure_velocity: bool, noise=0.0, k0: int = 0):
    """Run the EKF over a logged trajectory: z_k = x_k + n_k, u_prev = the voltage held over [t_k-1, t_k)."""
    est = KalmanEstimator(ecfg, measure_velocity=measure_velocity)
    Z = X + noise
    if not measure_velocity:
        Z = Z.copy()
        Z[:, [1, 3]] = np.nan  # not measured: must not be used at all
    out = np.full_like(X, np.nan)
    out[k0] = est.step(Z[k0], U[k0 - 1] if k0 else U[0])  # first call: reset
    for k in range(k0 + 1, len(X)):
        out[k] = est.step(Z[k], U[k - 1])
    return out, est


def test_jacobian_matches_sympy_model():
    """A = d f/d s of the 10-state model (plant + acceleration and voltage biases) vs the analytic sympy Jacobian."""
    sym = plant()
    p = plant_vector(EC)
    rng = np.random.default_rng(51)
    for _ in range(15):
        s = np.array([rng.uniform(4e-3, 12e-3), rng.uniform(-0.02, 0.02), rng.uniform(4e-3, 12e-3),
                      rng.uniform(-0.02, 0.02), rng.uniform(2, 5), rng.uniform(2, 5),
                      rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-5, 5), rng.uniform(-5, 5)])
        u = rng.uniform(20, 120, 2)
        A = jacobian(s, u, p)
        Aref = np.zeros((10, 10))
        Aref[:6, :6] = np.asarray(sym.jac_fn(*s[:6], *(u + s[8:]), *values(EC)), float)
        Aref[1, 6] = Aref[3, 7] = 1.0  # d1'' += beta1, d2'' += beta2; beta' = 0
        P_, Q_ = p[0], p[1]
        de = (P_ * s[0] + Q_ * s[2], Q_ * s[0] + P_ * s[2])
        Aref[4, 8] = de[0] / (2 * EC["K"])  # i_j' = (delta_j / 2K)(u_j + w_j - R i_j) + ...; w' = 0
        Aref[5, 9] = de[1] / (2 * EC["K"])
        col = np.abs(Aref).max(axis=0) + 1e-300
        np.testing.assert_allclose(A / col, Aref / col, rtol=0, atol=1e-6)


def test_make_estimator():
    assert isinstance(make_estimator(EC), KalmanEstimator)
    assert isinstance(make_estimator(EC, "none"), PassThrough)
    with pytest.raises(ConfigError, match="'ukf'"):
        make_estimator(EC, "ukf")


def test_pass_through_masks_velocities():
    z = np.array([8e-3, 1e-3, 7e-3, -1e-3, 4.0, 4.1])
    np.testing.assert_array_equal(PassThrough(False).step(z, np.zeros(2)), [8e-3, 0, 7e-3, 0, 4.0, 4.1])
    np.testing.assert_array_equal(PassThrough(True).step(z, np.zeros(2)), z)


def test_tracks_gap_rates_without_rate_sensors(s1_adaptive_15s):
    """Noiseless S1 closed loop, velocities not measured: the EKF reconstructs d1', d2'.

    Started mid-run at the fastest point of the first step (velocity initialised to 0,
    so the initial rate error is the full rate), it is within 3 % of the peak rate after
    0.1 s, 0.1 % after 0.3 s and 1e-5 after 0.5 s.
    """
    res = s1_adaptive_15s
    X, U = res.x, res.u
    k0 = int(np.argmax(np.abs(X[:, 1])))
    peak = np.abs(X[k0, 1])
    assert peak > 3e-4  # the plate is really moving (m/s)
    out, _est = replay(X, U, EC, measure_velocity=False, k0=k0)
    err = np.abs(out[:, [1, 3]] - X[:, [1, 3]])
    assert err[k0, 0] == pytest.approx(peak)  # starts with the whole rate wrong
    assert np.nanmax(err[k0 + 100:]) < 3e-2 * peak
    assert np.nanmax(err[k0 + 300:]) < 1e-3 * peak
    assert np.nanmax(err[k0 + 500:]) < 1e-5 * peak
    np.testing.assert_allclose(out[k0:, [0, 2]], X[k0:, [0, 2]], rtol=0, atol=1e-6)
    np.testing.assert_allclose(out[k0 + 300:, [0, 2]], X[k0 + 300:, [0, 2]], rtol=0, atol=1e-9)
    # from the start of the run (hover, exact initial state) the rates are exact throughout
    out0, _ = replay(X, U, EC, measure_velocity=False)
    assert np.abs(out0[:, [1, 3]] - X[:, [1, 3]]).max() < 1e-6 * peak


def test_bias_state_absorbs_unknown_mass(s2_adaptive):
    """S2 (3 kg added, unknown to the EKF's model), rates not measured: rate error stays within 3 % of the
    peak rate, and the bias converges to the model's acceleration error at hover, g (m_true/m_model - 1)."""
    res = s2_adaptive
    n = int(60.0 / 1e-3)
    X, U = res.x[:n], res.u[:n]
    out, est = replay(X, U, EC, measure_velocity=False)
    err = np.abs(out[:, [1, 3]] - X[:, [1, 3]])
    peak = np.abs(X[:, [1, 3]]).max()
    assert err.max() < 0.03 * peak
    expected_bias = EC["g"] * (res.mass[n - 1] / EC["m"] - 1.0)
    assert expected_bias == pytest.approx(1.98, abs=0.01)
    np.testing.assert_allclose(est.s[6:8], expected_bias, rtol=2e-3)
    np.testing.assert_allclose(est.s[8:], 0.0, atol=0.05)  # the coils are as modelled: no voltage bias


def test_noise_is_reduced(s1_adaptive_15s, scenarios):
    """S3a noise (uniform +-1 mm, +-1 mm/s, +-10 mA, seeded) on the S1 trajectory, EKF tuned as in S3a.

    With rate sensors: the gap error RMS drops > 10x and the rate error RMS below the raw
    rate noise. Without them: the rate estimate is > 20x better than differencing the noisy gaps.
    """
    res = s1_adaptive_15s
    X, U, t = res.x, res.u, res.t
    cfg = scenarios["S3a"].config()
    noise = noise_samples(cfg["plant_sim"], len(t), np.random.default_rng(7))
    late = t >= 0.5

    def rms(a):
        return np.sqrt(np.mean(a[late] ** 2, axis=0))

    out, est = replay(X, U, cfg["estimator"], measure_velocity=True, noise=noise)
    raw = rms(noise)
    kf = rms(out - X)
    assert np.all(kf[[0, 2]] < 0.1 * raw[[0, 2]])
    assert np.all(kf[[1, 3]] < 0.95 * raw[[1, 3]])
    assert np.all(kf[[4, 5]] < raw[[4, 5]])
    # covariance stays symmetric positive definite (Joseph form)
    np.testing.assert_allclose(est.P, est.P.T, rtol=0, atol=1e-12 * np.abs(est.P).max())
    assert np.linalg.eigvalsh(est.P).min() > 0
    # no rate sensors
    out2, _ = replay(X, U, cfg["estimator"], measure_velocity=False, noise=noise)
    fd = np.gradient(X[:, [0, 2]] + noise[:, [0, 2]], t, axis=0)
    assert np.all(rms(out2[:, [1, 3]] - X[:, [1, 3]]) < rms(fd - X[:, [1, 3]]) / 20)


def test_nan_measurement_is_skipped():
    """A non-finite sample is dropped from the update (prediction only), the estimate stays finite."""
    est = KalmanEstimator(EC)
    from dem_ros.core.model import hover_state

    x0, u0 = hover_state(default_config()["plant_sim"], 0.008)
    est.reset(x0)
    z = x0.copy()
    z[0] = np.nan
    out = est.step(z, u0)
    assert np.all(np.isfinite(out)) and np.all(np.isfinite(est.P))
    np.testing.assert_allclose(out, x0, rtol=1e-9, atol=1e-12)


def test_ekf_step_kernel_matches_class():
    est = KalmanEstimator(EC, measure_velocity=False)
    rng = np.random.default_rng(52)
    z0 = np.array([8e-3, 0, 8e-3, 0, 4.0, 4.0])
    est.reset(z0)
    s, P, mask, p, T, qc, rm = (a.copy() if isinstance(a, np.ndarray) else a for a in est.kernel_args())
    out = np.empty(6)
    for _ in range(20):
        z = z0 + rng.normal(0, 1e-5, 6)
        u = np.array([80.0, 80.0]) + rng.normal(0, 1, 2)
        ekf_step(s, P, z, mask, u, p, T, qc, rm, out)
        np.testing.assert_array_equal(est.step(z, u), out)


def test_consistent_under_a_resistance_error():
    """True coils 18 and 23 ohm, filter model 20 ohm: the per-coil voltage bias converges to (R - R_j) i_j
    and the current estimates stay unbiased; without it (bias frozen at 0) the filter's currents are biased."""
    from dem_ros.core.params import apply_overrides
    from dem_ros.core.simulate import simulate

    cfg = apply_overrides(default_config(), {"plant_sim": {"R1": 18.0, "R2": 23.0}})
    res = simulate(cfg, controller="adaptive", estimator="none", duration=3.0)
    assert not res.failed
    out, est = replay(res.x, res.u, EC, measure_velocity=True)
    k = len(res.x) - 1
    w_true = (20.0 - np.array([18.0, 23.0])) * res.x[k, 4:]
    np.testing.assert_allclose(est.s[8:], w_true, rtol=0.01)
    np.testing.assert_allclose(out[-500:, 4:], res.x[-500:, 4:], atol=2e-5)  # A
    frozen = {**EC, "voltage_bias_prior": 1e-9, "sigma_voltage_bias": 1e-9}
    out0, _ = replay(res.x, res.u, frozen, measure_velocity=True)
    assert np.abs(out0[-500:, 4:] - res.x[-500:, 4:]).max() > 10 * np.abs(out[-500:, 4:] - res.x[-500:, 4:]).max()


# -- plausibility gates, numerical guard, convergence (issue #12) ----------------------------------------------


def _noisy(X: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    """Gaussian noise of the filter's assumed standard deviations (gaps ``sigma``; rates, currents as EC)."""
    rng = np.random.default_rng(seed)
    sd = np.array([sigma, EC["sigma_rate"], sigma, EC["sigma_rate"], EC["sigma_current"], EC["sigma_current"]])
    return X + rng.normal(0.0, 1.0, X.shape) * sd


def _run(Z: np.ndarray, U: np.ndarray, cfg: dict = EC) -> tuple[np.ndarray, KalmanEstimator, int | None]:
    """The EKF over measurements ``Z`` (n, 6); (estimates, the filter, first sample with a declared fault)."""
    est = KalmanEstimator(cfg)
    out = np.empty_like(Z)
    out[0] = est.step(Z[0], U[0])
    first = None
    for k in range(1, len(Z)):
        out[k] = est.step(Z[k], U[k - 1])
        if first is None and est.faults:
            first = k
    return out, est, first


def test_a_10mm_spike_and_a_50mm_reading_do_not_move_the_estimate(s1_adaptive_15s):
    """S1 (adaptive, 4 s) measured with 10 um Gaussian gap noise: a single +10 mm spike on gap 1 while the plate
    follows r1's step and a 50 mm reading of gap 2 later leave the estimate within a fraction of the noise of
    the clean run's (last session, ungated: 1.3 mm error from the spike, the plate 2.3 mm from the rail)."""
    X, U = s1_adaptive_15s.x[:4000], s1_adaptive_15s.u[:4000]
    Z = _noisy(X, EC["sigma_gap"], 61)
    clean, est0, _ = _run(Z, U)
    c0 = est0.counters()  # the clean run's own rejections (false alarms: expected 8000 x 1e-5 = 0.08)
    k1 = 1000 + int(np.argmax(np.abs(X[1000:2500, 1])))  # the plate moving fastest in 1..2.5 s (after r1's step)
    k2 = 3000
    Zs = Z.copy()
    Zs[k1, 0] += 0.010
    Zs[k2, 2] = 0.050
    spiked, est, _ = _run(Zs, U)
    dev = np.abs(spiked - clean)[:, [0, 2]].max()
    c = est.counters()
    assert c == {**c0, "gap1_innovation": c0["gap1_innovation"] + 1, "gap2_out_of_range": 1}, (c, c0)
    assert not est.faults and est.converged
    assert dev < 0.5 * EC["sigma_gap"], dev  # the estimate stays where the clean run's is
    err = np.abs(spiked - X)[1000:, [0, 2]].max()
    assert err < 5 * EC["sigma_gap"], err
    print(f"\nspike 10 mm at k={k1} and a 50 mm reading: estimate moved {dev * 1e6:.3f} um from the clean run's"
          f" (gap noise 10 um); max gap error {err * 1e6:.2f} um")


def test_a_dead_sensor_is_declared_after_fault_samples(s1_adaptive_15s):
    X, U = s1_adaptive_15s.x[:1500], s1_adaptive_15s.u[:1500]
    Z = _noisy(X, EC["sigma_gap"], 62)
    Z[500:, 2] = 0.0  # gap sensor 2 dead: reads 0 from sample 500 on
    out, est, first = _run(Z, U)
    assert first == 500 + EC["fault_samples"] - 1  # on the fault_samples-th rejection in a row
    assert est.faults and est.faults[0].startswith("gap sensor 2:") and len(est.faults) == 1, est.faults
    assert est.counters()["gap2_out_of_range"] == 1000 and not est.converged
    assert np.all(np.isfinite(out)) and np.abs(out[:, 2] - X[:, 2]).max() < 1e-3  # predicted, never 0


def test_a_stuck_sensor_is_declared_when_the_plate_moves(s1_adaptive_15s):
    """Gap sensor 1 frozen at its reading from t = 0.9 s (the plate at rest at 8 mm) while r1 steps to 5 mm at
    1 s: it stays plausible sample by sample (the innovation gate passes it: the acceleration bias absorbs the
    difference), but the bias check declares gap 1 faulty before the plate is 2 mm away from the reading
    (the plate moves as in a healthy run: this replays one)."""
    X, U = s1_adaptive_15s.x[:8000], s1_adaptive_15s.u[:8000]
    Z = _noisy(X, EC["sigma_gap"], 63)
    Z[900:, 0] = Z[900, 0]
    out, est, first = _run(Z, U)
    assert first is not None and est.faults[0].startswith("gap sensor 1 or the load:"), (est.counters(), est.s)
    moved = abs(X[first, 0] - Z[900, 0])
    err = np.abs(out[900:first, 0] - X[900:first, 0]).max()
    print(f"\nstuck gap sensor 1: declared at t = {first * 1e-3:.3f} s, the plate {moved * 1e6:.0f} um away from"
          f" the stuck reading; max gap-1 error of the estimate meanwhile {err * 1e6:.0f} um")
    assert moved < 2e-3 and len(est.faults) == 1


def test_false_alarm_rate_matches_the_chosen_probability():
    """A consistent filter: truth drawn from the filter's own stochastic model (its process noise added each
    sample, held by a PID on the true state at 8 mm), Gaussian measurement noise of the assumed sigmas. Each
    gap's NIS is then chi^2(1): with gate_false_alarm = 0.01 the rate of rejected good samples must be 1 %
    within the binomial spread (+-4.5 sigma over 2 x 20 000 samples)."""
    from dem_ros.core.controllers import make_controller
    from dem_ros.core.estimator import _rk4
    from dem_ros.core.model import IK, IP, IQ, hover_state

    pfa, n, skip = 0.01, 21_000, 1_000
    cfg = {**EC, "gate_false_alarm": pfa}
    est = KalmanEstimator(cfg)
    rng = np.random.default_rng(64)
    x0, u0 = hover_state(default_config()["plant_sim"], 0.008)
    ctl = make_controller(default_config()["controller"], "decentralized_pid")
    ctl.reset(x0.copy(), u0)
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0, 0.008, 0.008])
    p, T, sd = est.p, est.T, np.sqrt(est.rm)
    s = np.concatenate([x0, np.zeros(4)])  # the truth, in the filter's state
    u = u0.copy()
    rejected = 0
    for k in range(n):
        z = s[:6] + rng.normal(0.0, 1.0, 6) * sd
        before = est.counters()["gap1_innovation"] + est.counters()["gap2_innovation"]
        est.step(z, u)
        if k >= skip:
            rejected += est.counters()["gap1_innovation"] + est.counters()["gap2_innovation"] - before
        u = ctl.step(s[:6].copy(), ref).copy()
        _rk4(s, u, p, T)  # the truth moves as the filter's model under u, plus its process noise
        de = (p[IP] * s[0] + p[IQ] * s[2], p[IQ] * s[0] + p[IP] * s[2])
        s[[1, 3]] += rng.normal(0.0, cfg["sigma_accel"] * T, 2)
        s[4:6] += rng.normal(0.0, 1.0, 2) * cfg["sigma_voltage"] * np.array(de) / (2.0 * p[IK]) * T
        s[6:8] += rng.normal(0.0, cfg["sigma_bias"] * T, 2)
        s[8:10] += rng.normal(0.0, cfg["sigma_voltage_bias"] * T, 2)
    tests = 2 * (n - skip)
    rate = rejected / tests
    spread = np.sqrt(pfa * (1 - pfa) / tests)
    print(f"\nfalse alarms: {rejected} of {tests} good gap samples = {rate:.4%} (chosen {pfa:.2%}, binomial sigma"
          f" {spread:.4%}); threshold NIS > {est.chi2_threshold:.3f}")
    assert abs(rate - pfa) < 4.5 * spread, (rate, pfa, spread)
    assert est.chi2_threshold == pytest.approx(6.6349, abs=1e-4)  # chi2.isf(0.01, 1)


def test_never_raises_near_zero_gap():
    """The rig's landing: gaps near zero make the model singular (delta^-2) and numpy raised LinAlgError from
    the update. Now a non-finite S skips the update, a non-finite state is re-initialised from the
    measurement, both counted; the filter keeps running and the ungated kernel does not raise either."""
    rng = np.random.default_rng(65)
    for gap in (1e-3, 1e-4, 1e-5, 1e-6, 1e-8):
        est = KalmanEstimator(EC, measure_velocity=False)
        z = np.array([gap, 0.0, 0.008, 0.0, 9.0, 4.0])
        est.reset(z)
        s, P, mask, p, T, qc, rm = (a.copy() if isinstance(a, np.ndarray) else a for a in est.kernel_args())
        out = np.empty(6)
        for _ in range(200):
            zk = z + rng.normal(0.0, 1e-5, 6)
            u = np.array([200.0, -200.0]) * rng.choice([-1.0, 1.0], 2)
            x = est.step(zk, u)
            ekf_step(s, P, zk, mask, u, p, T, qc, rm, out)  # ungated: must not raise
            assert np.all(np.isfinite(x) | np.isnan(x))
        c = est.counters()
        if gap < 1e-5:
            assert c["reinitialised"] + c["updates_skipped"] + c["gap1_out_of_range"] + c["gap1_innovation"] > 0, c
        print(f"gap {gap:g} m: {c}")


def test_convergence_after_a_restart():
    """Rates not measured: a (re)start counts as converged after converge_samples samples in a row that
    passed every gate; a rejected sample starts the count again; a start on an implausible measurement is
    refused (NaN output). Rates measured: converged once the start (it is the measurement) is confirmed by
    the next sample passing the gates: two samples."""
    from dem_ros.core.model import hover_state

    x0, u0 = hover_state(default_config()["plant_sim"], 0.008)
    measured = KalmanEstimator(EC)
    measured.step(x0, u0)
    assert not measured.converged and not measured.confirmed  # the range gate only: not yet confirmed
    measured.step(x0, u0)
    assert measured.converged and measured.confirmed
    est = KalmanEstimator(EC, measure_velocity=False)
    bad = x0.copy()
    bad[0] = 0.05
    assert np.all(np.isnan(est.step(bad, u0))) and not est.started  # a 50 mm reading cannot start the filter
    n = EC["converge_samples"]
    for _ in range(n):
        assert not est.converged
        est.step(x0, u0)
    assert est.converged
    spike = x0.copy()
    spike[2] += 0.005
    est.step(spike, u0)
    assert not est.converged
    for _ in range(n):
        est.step(x0, u0)
    assert est.converged


@pytest.mark.parametrize("measure_velocity", [True, False])
def test_an_in_range_spike_as_the_first_sample_is_not_taken_as_the_start(measure_velocity):
    """Review defect: a restart with measured rates counted as converged on its first sample, which had passed
    only the range gate: an in-range spike (2 mm) as that sample gave an estimate 2 mm off, published, and the
    innovation gate then rejected the true samples after it. Now the start must be confirmed by the next
    sample; one that is not starts the filter again from that sample: converged one sample later (3 with
    measured rates: well inside the board's 50 ms hold), on the true gaps, no fault."""
    from dem_ros.core.model import hover_state

    x0, u0 = hover_state(default_config()["plant_sim"], 0.008)
    est = KalmanEstimator(EC, measure_velocity=measure_velocity)
    spike = x0.copy()
    spike[0] += 0.002
    assert EC["gap_range_min"] < spike[0] < EC["gap_range_max"]  # passes the range gate
    need = 2 if measure_velocity else EC["converge_samples"]
    est.step(spike, u0)
    assert not est.converged
    k = 1
    while not est.converged and k < 200:
        out = est.step(x0, u0)
        k += 1
    assert est.converged and k == 1 + need, k  # the spike, the restart on the first true sample, its confirmation
    assert k * EC["dt"] < default_config()["plant_sim"]["hold_timeout"]
    assert abs(out[0] - x0[0]) < 1e-6 and abs(out[2] - x0[2]) < 1e-6
    for _ in range(100):
        out = est.step(x0, u0)
    assert not est.faulty and abs(out[0] - x0[0]) < 1e-6
    c = est.counters()
    assert c["unconfirmed_starts"] == 1 and c["gap1_innovation"] == 1, c


def _rest_then_lift(ecfg: dict, measure_velocity: bool, rest_s: float = 3.0, support: float = 0.0112,
                    start: float | None = None):
    """The rig's plate (true model, support at ``support`` as in hardware/rig.py) resting at 0 A for
    ``rest_s``, then a voltage ramp to 1.3x the hover voltage at the support over 0.4 s: the current rises,
    the plate lifts off and flies toward the rail; the run ends at a 9 mm gap (still flying). Seeded sensor
    noise sigma_gap / sigma_rate / sigma_current; ``start``: the plate starts there at 0 A instead (it drops onto
    its support). Returns (true states, estimates, estimator, k of lift-off)."""
    from dem_ros.core.model import hover_state, rk4

    pc = default_config()["plant_sim"]
    p = plant_vector(pc)
    _, u_sup = hover_state(pc, support)
    rng = np.random.default_rng(1112)
    sd = np.array([ecfg["sigma_gap"], ecfg["sigma_rate"]] * 2 + [ecfg["sigma_current"]] * 2)
    est = KalmanEstimator(ecfg, measure_velocity=measure_velocity)
    x = np.array([start or support, 0.0, start or support, 0.0, 0.0, 0.0])
    u = np.zeros(2)
    X, E = [], []
    k_lift = None
    n_rest = round(rest_s / 1e-3)
    for k in range(n_rest + 400):
        z = x + rng.normal(0.0, 1.0, 6) * sd
        if not measure_velocity:
            z[[1, 3]] = np.nan
        X.append(x.copy())
        E.append(est.step(z, u).copy())
        assert not est.faulty, (k, est.faults)
        u = u_sup * 1.3 * min(max(k + 1 - n_rest, 0) / 400.0, 1.0)
        rk4(x, u, p, 1e-3, 4)
        for i in (0, 2):  # the support (hardware/rig.py)
            if x[i] >= support:
                x[i], x[i + 1] = support, min(x[i + 1], 0.0)
        if k_lift is None and k >= n_rest and max(x[0], x[2]) < support - 1e-6:
            k_lift = k + 1
        if max(x[0], x[2]) < 0.009:
            break
    return np.array(X), np.array(E), est, k_lift, n_rest


@pytest.mark.parametrize("measure_velocity", [True, False])
def test_a_plate_resting_on_its_support_then_lifting_off(measure_velocity):
    """Review defect: at 0 A on its support the model predicts free fall (~14.7 m/s^2) and the support's
    reaction was missing: with gap rates the acceleration bias ran to -14.7 m/s^2 and latched a false fault
    at sample 21; without, 2996 of 3000 readings were rejected and the estimate fell through the support
    (27.6 mm at 50 ms). With the support as a hard stop in the prediction: 3 s at rest give no fault, no
    rejection and an estimate within noise of the readings; the lift-off under a current ramp is tracked
    (no fault, error a few sigma_gap)."""
    X, E, est, k_lift, n_rest = _rest_then_lift(EC, measure_velocity)
    rest = slice(0, n_rest)
    err = E[rest][:, [0, 2]] - X[rest][:, [0, 2]]
    assert np.all(np.abs(err) < 5 * EC["sigma_gap"]), np.abs(err).max()
    assert np.all(np.abs(E[1:n_rest][:, [1, 3]]) < 1e-9)  # held by the support (sample 0: the start, measured)
    assert np.all(np.abs(est.s[6:8]) < EC["bias_max"])
    c = est.counters()
    assert c["gap1_innovation"] == c["gap2_innovation"] == 0, c
    assert k_lift is not None and k_lift > n_rest and len(X) > k_lift + 20, (k_lift, len(X))  # it lifted and flew
    fly = slice(k_lift + 10, len(X))
    ferr = np.abs(E[fly][:, [0, 2]] - X[fly][:, [0, 2]]).max()
    assert ferr < 10 * EC["sigma_gap"], ferr
    assert est.converged
    print(f"measure_velocity={measure_velocity}: lift-off at {(k_lift - n_rest) * 1e-3:.3f} s into the ramp, "
          f"{len(X) - k_lift} ms of flight to 9 mm, max gap error in flight {ferr * 1e6:.1f} um, {c}")


def test_a_support_off_its_nominal_gap_is_taken_from_steady_readings():
    """The plate, released at 0 A from 9 mm, drops onto a support the sensor puts 0.4 mm beyond ``support_gap``:
    the estimate stops at d_s while the plate still moves (rejected), then the gap is re-initialised from
    the steady readings (counted) before fault_samples: no fault, the estimate within noise of the readings
    after that, and the lift-off is tracked."""
    X, E, est, k_lift, n_rest = _rest_then_lift(EC, False, rest_s=1.0, support=0.0114, start=0.009)
    c = est.counters()
    assert c["gap1_support_reinit"] >= 1 and c["gap2_support_reinit"] >= 1, c
    assert np.all(np.abs(E[200:n_rest][:, [0, 2]] - X[200:n_rest][:, [0, 2]]) < 5 * EC["sigma_gap"])
    assert k_lift is not None and len(X) > k_lift + 20
    print(c)
