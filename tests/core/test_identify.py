"""dem_ros.core.identify: the integrated coil equations (each coil with its own R_j and its magnet's K_j), the
modulated heave and pitch balances, the coil simulation, the flux-noise estimate, the intervals under correlated
residuals and the identifiability verdicts (one K or two), on data integrated independently (scipy's solve_ivp)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from dem_ros.core.identify import (
    FIT,
    NAMES,
    PARAMS,
    Z95,
    IdentError,
    RunData,
    _stage1,
    _tau,
    coil_rows,
    flux_noise,
    heave_rows,
    identify,
    pitch_rows,
    simulate_coils,
)
from dem_ros.core.params import TABLE2

GEO = {k: TABLE2[k] for k in ("L", "l", "I", "N1", "N2", "g")}
NOMINAL = {"R1": 20.0, "R2": 20.0, "K": TABLE2["K"], "m": TABLE2["m"]}
P = (GEO["L"] + GEO["l"]) / (2 * GEO["L"])
Q = 1 - P


def _gaps(t, sin=np.sin):
    """A prescribed plate motion (m): heave and pitch sinusoids around 6 mm, smooth (analytic). ``sin``: math.sin
    for a float ``t`` (the integrator's right-hand side: the same formula without numpy's per-call overhead)."""
    d1 = 6e-3 + 1e-3 * sin(2 * np.pi * 0.7 * t) + 0.3e-3 * sin(2 * np.pi * 2.3 * t)
    d2 = 6e-3 + 0.8e-3 * sin(2 * np.pi * 0.5 * t + 1.0)
    return d1, d2


def _gaps_rate(t, cos=np.cos):
    w1, w2, w3 = 2 * np.pi * 0.7, 2 * np.pi * 2.3, 2 * np.pi * 0.5
    return 1e-3 * w1 * cos(w1 * t) + 0.3e-3 * w2 * cos(w2 * t), 0.8e-3 * w3 * cos(w3 * t + 1.0)


def coil_data(R1=17.3, R2=23.9, Ks=((3.9e-4, 4.4e-4), (4.1e-4, 4.1e-4)), T=4.0, dt=1e-3, seed=3):
    """Coil currents integrated by solve_ivp (rtol 1e-10) from held random voltages and the prescribed gaps:
    i_j' = (delta_j/2K_j)(u_j - R_j i_j) + i_j delta_j'/delta_j (the model's coil equation), sampled every dt;
    one RunData per pair (K1, K2) of ``Ks`` (the same voltages and gaps, integrated together)."""
    K = np.asarray(Ks, float).ravel()
    R = np.tile([R1, R2], len(Ks))
    rng = np.random.default_rng(seed)
    n = round(T / dt) + 1
    t = np.arange(n) * dt
    held = 40.0 + 20.0 * rng.standard_normal((n, 2))  # u over (t_{k-1}, t_k]: row k
    held[0] = 40.0

    def f(tt, i):
        k = min(int(np.ceil(tt / dt - 1e-9)), n - 1)
        d1, d2 = _gaps(tt, math.sin)
        r1, r2 = _gaps_rate(tt, math.cos)
        de = np.tile([P * d1 + Q * d2, Q * d1 + P * d2], len(Ks))
        dd = np.tile([P * r1 + Q * r2, Q * r1 + P * r2], len(Ks))
        u = np.tile(held[max(k, 1)], len(Ks))
        return de / (2 * K) * (u - R * i) + i * dd / de

    i = np.empty((n, K.size))
    i[0] = 2.0
    for k in range(1, n):  # one interval at a time: the voltage steps at the samples
        sol = solve_ivp(f, (t[k - 1], t[k]), i[k - 1], rtol=1e-10, atol=1e-12, method="DOP853")
        i[k] = sol.y[:, -1]
    d1, d2 = _gaps(t)
    return [RunData(t, np.column_stack([d1, d2]), i[:, 2 * c:2 * c + 2], held) for c in range(len(Ks))]


@pytest.fixture(scope="module")
def both():
    """(magnets of K1 = 3.9e-4 and K2 = 4.4e-4, magnets alike: K = 4.1e-4)"""
    return coil_data()


@pytest.fixture(scope="module")
def coils(both):
    return both[0]


def test_integrated_coil_equations_recover_R1_R2_K1_K2_from_independently_integrated_data(coils):
    A, b, noise = coil_rows(coils, GEO, 20)
    assert FIT == ("R1", "R2", "K1", "K2", "m") and A.shape[1] == 5
    M = b.size // 2
    assert np.all(A[:M, [1, 3, 4]] == 0) and np.all(A[M:, [0, 2, 4]] == 0)  # each coil: its own R_j and K_j
    theta = np.linalg.lstsq(A[:, :4], b, rcond=None)[0]
    # K: 0.2 %, the trapezoid rule on currents with a kink at every voltage step (20 V steps every sample)
    assert theta == pytest.approx([17.3, 23.9, 3.9e-4, 4.4e-4], rel=5e-3)
    assert np.all(noise[:, [0, 1, 4]] == 0) and np.all(noise[:M, 2] > 0) and np.all(noise[M:, 3] > 0)


def test_coil_simulation_matches_the_independent_integration(coils):
    i = simulate_coils(coils, GEO, 17.3, 23.9, 3.9e-4, 4.4e-4)
    assert np.max(np.abs(i - coils.current)) < 1e-4 * np.max(np.abs(coils.current))
    wrong = simulate_coils(coils, GEO, 17.3 * 1.03, 23.9, 3.9e-4, 4.4e-4)
    assert np.max(np.abs(wrong[:, 0] - coils.current[:, 0])) > 20 * np.max(np.abs(i[:, 0] - coils.current[:, 0]))
    one = simulate_coils(coils, GEO, 17.3, 23.9, 3.9e-4)  # one K: coil 2 with K1, off
    assert np.max(np.abs(one[:, 0] - i[:, 0])) == 0 and np.max(np.abs(one[:, 1] - coils.current[:, 1])) > 1e-3


def test_modulating_function_moves_both_derivatives_onto_phi():
    """int phi d'' dt = int phi'' d dt for phi = sin^2 on its window: a heave row's acceleration term against
    the analytic second derivative of the prescribed motion."""
    t = np.arange(0, 2.0001, 1e-3)
    d1, d2 = _gaps(t)
    w1, w2, w3 = 2 * np.pi * 0.7, 2 * np.pi * 2.3, 2 * np.pi * 0.5
    acc = 0.5 * (-1e-3 * w1 ** 2 * np.sin(w1 * t) - 0.3e-3 * w2 ** 2 * np.sin(w2 * t)
                 - 0.8e-3 * w3 ** 2 * np.sin(w3 * t + 1.0))
    data = RunData(t, np.column_stack([d1, d2]), np.ones((t.size, 2)), np.zeros((t.size, 2)))
    A, _, wphi = heave_rows(data, GEO, 200)
    for r, a in enumerate(range(0, t.size - 200, 200)):
        tt = t[a:a + 201]
        phi = np.sin(np.pi * (tt - tt[0]) / (tt[-1] - tt[0])) ** 2
        lhs = GEO["g"] * wphi[r] - np.trapezoid(phi * acc[a:a + 201], tt)
        assert -A[r, 4] == pytest.approx(lhs, rel=1e-6)


def _held_motion(m, K1, K2, N=(36.5, 36.5)):
    """Currents that hold the prescribed motion (Eq. 3 solved for the magnet forces F1, F2 at each instant) with
    mass m and the magnets' K1, K2: F_j = K_j i_j^2/delta_j^2."""
    t = np.arange(0, 4.0001, 1e-3)
    d1, d2 = _gaps(t)
    w1, w2, w3 = 2 * np.pi * 0.7, 2 * np.pi * 2.3, 2 * np.pi * 0.5
    a1 = -1e-3 * w1 ** 2 * np.sin(w1 * t) - 0.3e-3 * w2 ** 2 * np.sin(w2 * t)
    a2 = -0.8e-3 * w3 ** 2 * np.sin(w3 * t + 1.0)
    geo = GEO | {"N1": N[0], "N2": N[1]}
    L, l, I, g = geo["L"], geo["l"], geo["I"], geo["g"]
    A, B, C, D = 1 / m + L * l / I, 1 / m - L * l / I, 1 / m + L * L / I, 1 / m - L * L / I
    rhs = np.stack([C * N[0] + D * N[1] + g - a1, D * N[0] + C * N[1] + g - a2])
    F = np.linalg.solve(np.array([[A, B], [B, A]]), rhs).T  # (n, 2): d'' = -A F1 - B F2 + ...
    de = np.column_stack([P * d1 + Q * d2, Q * d1 + P * d2])
    i = de * np.sqrt(F / np.array([K1, K2]))
    return RunData(t, np.column_stack([d1, d2]), i, np.zeros_like(i)), geo


def test_heave_balance_gives_m_with_K1_K2_known():
    m, K1, K2 = 13.1, 4.1e-4, 3.6e-4
    data, geo = _held_motion(m, K1, K2)
    A, b, _ = heave_rows(data, geo, 200)
    m_hat = np.linalg.lstsq(A[:, 4:], b - A[:, 2] * K1 - A[:, 3] * K2, rcond=None)[0][0]
    assert m_hat == pytest.approx(m, rel=1e-5)


@pytest.mark.parametrize("N", [(36.5, 36.5), (40.0, 30.0)])
def test_pitch_balance_holds_with_each_magnets_K_and_fixes_their_ratio(N):
    """The modulated pitch rows vanish with the true K1, K2 (the moment balance of Eq. 3 with the loads' moment),
    and are far off with one K for both."""
    m, K1, K2 = 13.1, 4.1e-4, 3.6e-4
    data, geo = _held_motion(m, K1, K2, N)
    A, b, ip = pitch_rows(data, geo, 200)
    assert np.all(A[:, [0, 1, 4]] == 0)
    F = A[:, 2] * K1 + A[:, 3] * K2
    np.testing.assert_allclose(F, b, atol=1e-6 * np.max(np.abs(A[:, 2] * K1)))
    one = A[:, 2] + A[:, 3]
    K = 0.5 * (K1 + K2)
    assert np.min(np.abs(one * K - b) / ip) > 5.0  # N: a 13 % split is a force difference of ~14 N


def test_flux_noise_estimates_white_noise_on_a_smooth_signal():
    rng = np.random.default_rng(1)
    t = np.arange(20000) * 1e-3
    gap = np.full((t.size, 2), 5e-3)
    i = 2.5 + 0.1 * np.sin(t)[:, None] + 1e-3 * rng.standard_normal((t.size, 2))
    s2 = flux_noise(RunData(t, gap, i, np.zeros_like(i)), GEO)
    assert np.sqrt(s2) == pytest.approx(1e-3 / 5e-3, rel=0.05)


def test_autocorrelation_time_of_white_and_ar1_noise():
    rng = np.random.default_rng(2)
    e = rng.standard_normal(200000)
    assert _tau(e) == pytest.approx(1.0, abs=0.1)
    x = np.empty_like(e)
    x[0] = 0
    for k in range(1, e.size):
        x[k] = 0.8 * x[k - 1] + e[k]
    assert _tau(x) == pytest.approx(9.0, rel=0.15)  # (1 + rho)/(1 - rho)


def hover(T=10.0, R=(21.0, 18.0), K=3.8e-4, m=16.0, seed=4):
    """A hover: gaps, currents and voltages constant (the equilibrium of the model), with the rig's ADC
    quantisation on the gaps (0.25 um) and currents (0.3 mA) and a little current noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(T / 1e-3)) * 1e-3
    gap = np.full((t.size, 2), 6e-3)
    F = GEO["N1"] + m * GEO["g"] / 2
    i0 = 6e-3 * np.sqrt(F / K)
    i = i0 + 2e-4 * rng.standard_normal((t.size, 2))
    i = np.round(i / (10 / 32768)) * (10 / 32768)
    u = np.column_stack([R[0] * i[:, 0], R[1] * i[:, 1]])
    u = np.vstack([u[:1], u[:-1]])
    return RunData(t, np.round(gap / 2.5e-7) * 2.5e-7, i, u)


def test_hover_only_names_K_and_m_as_not_determined_and_gives_no_number():
    res = identify(hover(), GEO, NOMINAL)
    assert res.estimates["R1"].determined and res.estimates["R1"].value == pytest.approx(21.0, rel=1e-3)
    assert res.estimates["R2"].determined and res.estimates["R2"].value == pytest.approx(18.0, rel=1e-3)
    for k in ("K", "m", "K1", "K2"):
        e = res.estimates[k]
        assert not e.determined and np.isnan(e.value) and ("flux" in e.reason or "nor is either" in e.reason)
        assert "value" not in e.to_dict()
    assert not res.complete and set(res.values()) == {"R1", "R2"}
    assert res.k_split.verdict == "not determined" and not res.k_split.split


def test_excited_coils_identify_R1_R2_K1_K2_with_truth_inside_the_intervals(coils):
    """Coils alone (random voltages: no force balance); R_j and each magnet's K_j from the excited fluxes, told
    apart (a 12 % split); K is their mean."""
    res = identify(coils, GEO, NOMINAL, holdout=0.25)
    assert res.k_split.split and res.k_split.coils == pytest.approx(-0.5 / 8.3, rel=1e-2)
    for k, v in (("R1", 17.3), ("R2", 23.9), ("K1", 3.9e-4), ("K2", 4.4e-4), ("K", 4.15e-4)):
        e = res.estimates[k]
        assert e.determined and abs(e.value / v - 1) < 1e-3 and e.ci95[0] <= v <= e.ci95[1], (k, e)
    assert res.validation is not None and max(res.validation.current_rel) < 1e-3


def test_excited_coils_of_magnets_alike_give_one_K(both):
    """K1 = K2: the interval of the split holds 0; one K is given, K1 and K2 are not (the reason says why)."""
    res = identify(both[1], GEO, NOMINAL, holdout=0.25)
    assert res.k_split.verdict == "one K: agree" and abs(res.k_split.coils) < res.k_split.coils_ci
    e = res.estimates["K"]
    assert e.determined and abs(e.value / 4.1e-4 - 1) < 1e-3 and e.ci95[0] <= 4.1e-4 <= e.ci95[1]
    for k in ("K1", "K2"):
        assert not res.estimates[k].determined and "agree within their intervals" in res.estimates[k].reason
    assert list(res.estimates) == list(NAMES)


def test_intervals_cover_the_truth_under_correlated_residuals():
    """A slowly varying regressor with AR(1) errors (integrated autocorrelation time 49 samples): the block
    sandwich's 95 % intervals (blocks of 10 of them) cover the truth about 95 % of the time; the iid formula's
    cover far less."""
    from scipy.signal import lfilter
    from scipy.stats import t as t_dist

    rng = np.random.default_rng(7)
    n, rho, reps = 20000, 0.96, 300
    t = np.arange(n) * 1e-3
    a = np.column_stack([1.0 + 0.5 * np.sin(2 * np.pi * 0.3 * t), np.cos(2 * np.pi * 0.13 * t)])
    inside = inside_iid = 0
    for _ in range(reps):
        e = lfilter([math.sqrt(1 - rho * rho)], [1.0, -rho], rng.standard_normal(n))
        b = a @ np.array([2.0, -1.0]) + 0.1 * e
        theta, contrib, J = _stage1(a, b, [slice(0, n)], np.ones(2), np.zeros_like(a), t, 0.1)
        B = contrib.shape[0]
        assert 20 <= B <= 60  # 0.1 s widened to 10 tau (estimated: 0.5 s for the true tau)
        std = math.sqrt(float(contrib[:, 0] @ contrib[:, 0]) * B / (B - 1))
        inside += abs(theta[0] - 2.0) <= t_dist.ppf(0.975, B - 1) * std
        inside_iid += abs(theta[0] - 2.0) <= Z95 * math.sqrt(np.linalg.inv(J.T @ J)[0, 0])
    assert 0.9 <= inside / reps <= 0.98  # 0.927 (the iid: 0.25)
    assert inside_iid / reps < 0.5


def test_bad_data_is_refused_with_a_reason():
    t = np.arange(100) * 1e-3
    z = np.zeros((100, 2))
    with pytest.raises(IdentError, match="too few"):
        identify(RunData(t, z + 5e-3, z + 1, z), GEO, NOMINAL)
    with pytest.raises(IdentError, match="strictly increasing"):
        RunData(t[::-1].copy(), z, z, z)
    with pytest.raises(IdentError, match="non-finite"):
        RunData(t, z + np.nan, z, z)
    assert PARAMS == ("R1", "R2", "K", "m") and NAMES == ("R1", "R2", "K1", "K2", "K", "m")
