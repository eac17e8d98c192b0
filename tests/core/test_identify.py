"""dem_ros.core.identify: the integrated coil equations, the modulated heave balance, the coil simulation, the
flux-noise estimate and the identifiability verdicts, on data integrated independently (scipy's solve_ivp)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from dem_ros.core.identify import (
    PARAMS,
    IdentError,
    RunData,
    _tau,
    coil_rows,
    flux_noise,
    heave_rows,
    identify,
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


def coil_data(R1=17.3, R2=23.9, K=3.9e-4, T=4.0, dt=1e-3, seed=3):
    """Coil currents integrated by solve_ivp (rtol 1e-10) from held random voltages and the prescribed gaps:
    i' = (delta/2K)(u - R i) + i delta'/delta (the model's coil equation), sampled every dt."""
    rng = np.random.default_rng(seed)
    n = round(T / dt) + 1
    t = np.arange(n) * dt
    held = 40.0 + 20.0 * rng.standard_normal((n, 2))  # u over (t_{k-1}, t_k]: row k
    held[0] = 40.0
    volts = held.tolist()

    def f(tt, i):  # on floats: solve_ivp calls it ~200 000 times
        k = min(math.ceil(tt / dt - 1e-9), n - 1)
        d1, d2 = _gaps(tt, math.sin)
        r1, r2 = _gaps_rate(tt, math.cos)
        de1, de2 = P * d1 + Q * d2, Q * d1 + P * d2
        dd1, dd2 = P * r1 + Q * r2, Q * r1 + P * r2
        u1, u2 = volts[max(k, 1)]
        i1, i2 = i.tolist()
        return [de1 / (2 * K) * (u1 - R1 * i1) + i1 * dd1 / de1, de2 / (2 * K) * (u2 - R2 * i2) + i2 * dd2 / de2]

    i = np.empty((n, 2))
    i[0] = [2.0, 2.0]
    for k in range(1, n):  # one interval at a time: the voltage steps at the samples
        sol = solve_ivp(f, (t[k - 1], t[k]), i[k - 1], rtol=1e-10, atol=1e-12, method="DOP853")
        i[k] = sol.y[:, -1]
    d1, d2 = _gaps(t)
    return RunData(t, np.column_stack([d1, d2]), i, held)


@pytest.fixture(scope="module")
def coils():
    return coil_data()


def test_integrated_coil_equations_recover_R1_R2_K_from_independently_integrated_data(coils):
    A, b, noise = coil_rows(coils, GEO, 20)
    theta = np.linalg.lstsq(A[:, :3], b, rcond=None)[0]
    # K: 0.2 %, the trapezoid rule on currents with a kink at every voltage step (20 V steps every sample)
    assert theta == pytest.approx([17.3, 23.9, 3.9e-4], rel=5e-3)
    assert np.all(noise[:, [0, 1, 3]] == 0) and np.all(noise[:, 2] >= 0)


def test_coil_simulation_matches_the_independent_integration(coils):
    i = simulate_coils(coils, GEO, 17.3, 23.9, 3.9e-4)
    assert np.max(np.abs(i - coils.current)) < 1e-4 * np.max(np.abs(coils.current))
    wrong = simulate_coils(coils, GEO, 17.3 * 1.03, 23.9, 3.9e-4)
    assert np.max(np.abs(wrong[:, 0] - coils.current[:, 0])) > 20 * np.max(np.abs(i[:, 0] - coils.current[:, 0]))


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
        assert -A[r, 3] == pytest.approx(lhs, rel=1e-6)


def test_heave_balance_gives_m_with_K_known():
    """Currents that hold the prescribed motion with mass m (K (q1 + q2) = m (g - a) + N1 + N2, split evenly):
    the heave rows with K known give m."""
    t = np.arange(0, 4.0001, 1e-3)
    d1, d2 = _gaps(t)
    w1, w2, w3 = 2 * np.pi * 0.7, 2 * np.pi * 2.3, 2 * np.pi * 0.5
    acc = 0.5 * (-1e-3 * w1 ** 2 * np.sin(w1 * t) - 0.3e-3 * w2 ** 2 * np.sin(w2 * t)
                 - 0.8e-3 * w3 ** 2 * np.sin(w3 * t + 1.0))
    m, K = 13.1, 4.1e-4
    qs = (m * (GEO["g"] - acc) + GEO["N1"] + GEO["N2"]) / K
    de = np.column_stack([P * d1 + Q * d2, Q * d1 + P * d2])
    i = de * np.sqrt(qs / 2)[:, None]
    data = RunData(t, np.column_stack([d1, d2]), i, np.zeros_like(i))
    A, b, _ = heave_rows(data, GEO, 200)
    m_hat = np.linalg.lstsq(A[:, 3:], b - A[:, 2] * K, rcond=None)[0][0]
    assert m_hat == pytest.approx(m, rel=1e-5)


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
    for k in ("K", "m"):
        e = res.estimates[k]
        assert not e.determined and np.isnan(e.value) and "flux" in e.reason
        assert "value" not in e.to_dict()
    assert not res.complete and set(res.values()) == {"R1", "R2"}


def test_excited_coils_identify_R1_R2_K_with_truth_inside_the_intervals(coils):
    """Coils alone (no heave data: m is not determined, said so); R and K from the excited fluxes."""
    res = identify(coils, GEO, NOMINAL, holdout=0.25)
    for k, v in (("R1", 17.3), ("R2", 23.9), ("K", 3.9e-4)):
        e = res.estimates[k]
        assert e.determined and abs(e.value / v - 1) < 1e-3 and e.ci95[0] <= v <= e.ci95[1], (k, e)
    assert res.validation is not None and max(res.validation.current_rel) < 1e-3


def test_bad_data_is_refused_with_a_reason():
    t = np.arange(100) * 1e-3
    z = np.zeros((100, 2))
    with pytest.raises(IdentError, match="too few"):
        identify(RunData(t, z + 5e-3, z + 1, z), GEO, NOMINAL)
    with pytest.raises(IdentError, match="strictly increasing"):
        RunData(t[::-1].copy(), z, z, z)
    with pytest.raises(IdentError, match="non-finite"):
        RunData(t, z + np.nan, z, z)
    assert PARAMS == ("R1", "R2", "K", "m")
