"""Plant model (dem_ros.core.model) against an independent sympy derivation (docs/manual/errata.md,
docs/manual/model.md)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from _symbolic import lie_numeric, plant, values

from dem_ros.core import model
from dem_ros.core.params import TABLE2, default_config

PC = default_config()["plant_sim"]
# Table 2 + the recommended truth R = 20 ohm, K = 4.374e-4 N m^2/A^2 (docs/manual/model.md)
TRUE = dict(TABLE2)
assert TRUE["R"] == 20.0 and TRUE["K"] == 4.374e-4


def random_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """Non-equilibrium states: gaps 3-15 mm, rates +-20 mm/s, currents 1-6 A."""
    x = np.empty((n, 6))
    x[:, 0] = rng.uniform(3e-3, 15e-3, n)
    x[:, 2] = rng.uniform(3e-3, 15e-3, n)
    x[:, 1] = rng.uniform(-0.02, 0.02, n)
    x[:, 3] = rng.uniform(-0.02, 0.02, n)
    x[:, 4] = rng.uniform(1.0, 6.0, n)
    x[:, 5] = rng.uniform(1.0, 6.0, n)
    return x


def theta_true(cfg: dict) -> np.ndarray:
    cA = cfg["L"] * cfg["l"] / cfg["I"]
    cC = cfg["L"] ** 2 / cfg["I"]
    th = np.empty(8)
    model.theta_of(np.array([1 / cfg["m"], cfg["R"], cfg["K"]]), cA, cC, th)
    return th


# ---------------------------------------------------------------------------
# dynamics vs first principles
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "changes",
    [{}, {"m": 17.852, "N1": 30.0, "N2": 45.0}, {"R": 15.0, "K": 3.0e-4, "L": 0.4, "l": 0.1}],
    ids=["table2", "heavier-asymmetric-load", "other-coil-geometry"],
)
def test_dynamics_matches_newton_and_circuit_law(changes):
    """model.dynamics == sympy d1'', d2'', i' from Eq. 1a/1b, Eq. 2, F = K i^2/delta^2, u = R i + d(2Ki/delta)/dt."""
    cfg = {**TRUE, **changes}
    sym = plant()
    p = model.plant_vector(cfg)
    rng = np.random.default_rng(11)
    xs = random_states(rng, 25)
    us = rng.uniform(-100.0, 200.0, (25, 2))
    dx = np.empty(6)
    for x, u in zip(xs, us, strict=True):
        model.dynamics(x, u, p, dx)
        ref = np.asarray(sym.xdot_fn(*x, *u, *values(cfg)), float).reshape(6)
        np.testing.assert_allclose(dx, ref, rtol=1e-10, atol=1e-12)


def test_derived_constants_match_notes_section_1():
    P, Q, A, B, C, D = model.derived(TRUE["L"], TRUE["l"], TRUE["m"], TRUE["I"])
    assert pytest.approx(0.78, abs=1e-12) == P
    assert pytest.approx(0.22, abs=1e-12) == Q
    assert pytest.approx(0.156566, abs=5e-7) == A
    assert pytest.approx(-0.021904, abs=5e-7) == B
    assert pytest.approx(0.226679, abs=5e-7) == C
    assert pytest.approx(-0.092017, abs=5e-7) == D
    # B changes sign at m = I/(L l) = 11.2 kg
    m_star = TRUE["I"] / (TRUE["L"] * TRUE["l"])
    assert m_star == pytest.approx(11.2, abs=0.05)
    assert model.derived(TRUE["L"], TRUE["l"], m_star * 0.99, TRUE["I"])[3] > 0
    assert model.derived(TRUE["L"], TRUE["l"], m_star * 1.01, TRUE["I"])[3] < 0


def test_set_mass_matches_plant_vector():
    p = model.plant_vector(TRUE)
    model.set_mass(p, 17.852, TRUE["L"], TRUE["l"], TRUE["I"])
    np.testing.assert_allclose(p, model.plant_vector(TRUE, m=17.852), rtol=1e-15)


# ---------------------------------------------------------------------------
# Lie derivatives and the linear parameterisation (docs/manual/model.md a-c)
# ---------------------------------------------------------------------------
def test_relative_degree_three_symbolically():
    """L_g h = 0 and L_g L_f h = 0 identically (so the relative degree is (3, 3))."""
    sym = plant()
    assert all(sp.cancel(e) == 0 for e in sym.Lgh)
    assert all(sp.cancel(e) == 0 for e in sym.LgLfh)
    # ... and L_f h = [x2, x4]
    x = sym.x
    assert sp.cancel(sym.Lfh[0] - x[1]) == 0
    assert sp.cancel(sym.Lfh[1] - x[3]) == 0


def test_Lf2h_equals_W2_theta_plus_g():
    sym = plant()
    cfg = TRUE
    th = theta_true(cfg)
    P, Q = model.derived(cfg["L"], cfg["l"], cfg["m"], cfg["I"])[:2]
    ab = np.empty(6)
    W3 = np.empty((8, 2))
    W2 = np.empty((8, 2))
    rng = np.random.default_rng(12)
    for x in random_states(rng, 20):
        model.lie_terms(x[0], x[2], x[4], x[5], P, Q, ab)
        model.regressors(ab, np.zeros(2), cfg["N1"], cfg["N2"], W3, W2)
        ref = lie_numeric(sym, x, (0.0, 0.0), values(cfg))["Lf2h"]
        np.testing.assert_allclose(W2.T @ th + cfg["g"], ref, rtol=1e-10, atol=1e-10)


def test_ydddot_equals_W3_theta():
    """L_f^3 h + L_g L_f^2 h u = W3(x, u)^T theta at random states and inputs."""
    sym = plant()
    cfg = TRUE
    th = theta_true(cfg)
    P, Q = model.derived(cfg["L"], cfg["l"], cfg["m"], cfg["I"])[:2]
    ab = np.empty(6)
    W3 = np.empty((8, 2))
    W2 = np.empty((8, 2))
    rng = np.random.default_rng(13)
    for x in random_states(rng, 20):
        u = rng.uniform(-50.0, 150.0, 2)
        model.lie_terms(x[0], x[2], x[4], x[5], P, Q, ab)
        model.regressors(ab, u, cfg["N1"], cfg["N2"], W3, W2)
        lie = lie_numeric(sym, x, u, values(cfg))
        scale = np.abs(lie["Lf3h"]).max() + np.abs(lie["LgLf2h"] @ u).max()
        np.testing.assert_allclose(W3.T @ th, lie["yddd"], rtol=0, atol=1e-10 * scale)
        # L_f^3 h alone (u = 0) = R [A a1 + B a2, B a1 + A a2]: the theta1/theta3 rows
        np.testing.assert_allclose(2 * th[0] * ab[:2] + 2 * th[2] * ab[1::-1], lie["Lf3h"], rtol=1e-9)


def test_flux_conservation_along_f6():
    """L_f6 (i1^2/delta1^2) = 0 (erratum 16), f6 the kinematic drift vector of Eq. 37,
    and dF/dt = (i/delta)(u - R i)."""
    sym = plant()
    x1, x2, x3, x4, x5, x6 = sym.x
    _m, _I, _L, _l, K, R, _N1, _N2, g = sym.params
    de1, de2 = sym.de1, sym.de2
    dde1 = sp.diff(de1, x1) * x2 + sp.diff(de1, x3) * x4
    dde2 = sp.diff(de2, x1) * x2 + sp.diff(de2, x3) * x4
    f6 = sp.Matrix([x2, g, x4, g, x5 * dde1 / de1, x6 * dde2 / de2])
    for q in (x5**2 / de1**2, x6**2 / de2**2):
        assert sp.cancel((sp.Matrix([q]).jacobian(sym.X) * f6)[0]) == 0
    # docs/manual/model.md (a): dF_j/dt along f + G u is exactly (i_j/delta_j)(u_j - R i_j); K drops out
    for F, i, de, u in ((K * x5**2 / de1**2, x5, de1, sym.u[0]), (K * x6**2 / de2**2, x6, de2, sym.u[1])):
        dF = (sp.Matrix([F]).jacobian(sym.X) * sym.xdot)[0]
        assert sp.cancel(dF - i / de * (u - R * i)) == 0


def test_decoupling_matrix_and_its_determinant():
    """L_g L_f^2 h = -[[A, B], [B, A]] diag(b1, b2) and A^2 - B^2 = 4 L l/(m I).

    Its determinant is **+**(A^2 - B^2) b1 b2 (det of a 2x2 is unchanged by the
    overall minus sign). Notes 1 (b) print -(A^2 - B^2) b1 b2; the sign there is
    wrong, the conclusion (invertible whenever both currents are non-zero) holds.
    """
    sym = plant()
    _x1, _x2, _x3, _x4, x5, x6 = sym.x
    m, I, L, l = sym.params[:4]
    A = 1 / m + L * l / I
    B = 1 / m - L * l / I
    b1, b2 = x5 / sym.de1, x6 / sym.de2
    M = sym.LgLf2h
    target = -sp.Matrix([[A, B], [B, A]]) * sp.diag(b1, b2)
    assert all(sp.cancel(M[i, j] - target[i, j]) == 0 for i in range(2) for j in range(2))
    assert sp.cancel(A**2 - B**2 - 4 * L * l / (m * I)) == 0
    det = M.det()
    assert sp.cancel(det - (A**2 - B**2) * b1 * b2) == 0
    assert sp.cancel(det + (A**2 - B**2) * b1 * b2) != 0  # the printed sign does not hold


def test_theta_of_matches_eq44():
    cfg = TRUE
    A, B, C, D = model.derived(cfg["L"], cfg["l"], cfg["m"], cfg["I"])[2:]
    R, K = cfg["R"], cfg["K"]
    expected = [A * R / 2, -A * K, B * R / 2, -B * K, -A / 2, -B / 2, C, D]
    np.testing.assert_allclose(theta_true(cfg), expected, rtol=1e-14)


def test_theta_jacobian_matches_finite_differences():
    cA = TRUE["L"] * TRUE["l"] / TRUE["I"]
    cC = TRUE["L"] ** 2 / TRUE["I"]
    rng = np.random.default_rng(14)
    J = np.empty((8, 3))
    tp = np.empty(8)
    tm = np.empty(8)
    for _ in range(10):
        phi = np.array([1 / rng.uniform(5, 50), rng.uniform(5, 60), rng.uniform(1e-4, 2e-3)])
        model.theta_jacobian(phi, cA, J)
        Jfd = np.empty((8, 3))
        for j in range(3):
            h = 1e-6 * phi[j]
            e = np.zeros(3)
            e[j] = h
            model.theta_of(phi + e, cA, cC, tp)
            model.theta_of(phi - e, cA, cC, tm)
            Jfd[:, j] = (tp - tm) / (2 * h)
        np.testing.assert_allclose(J, Jfd, rtol=1e-7, atol=1e-12 * np.abs(Jfd).max())


# ---------------------------------------------------------------------------
# hover and integration
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("gap,i_expected,u_expected", [(0.005, 2.5, 50.0), (0.008, 4.0, 80.0)])
def test_hover_state_is_an_exact_equilibrium(gap, i_expected, u_expected):
    x0, u0 = model.hover_state(PC, gap)
    dx = np.empty(6)
    model.dynamics(x0, u0, model.plant_vector(PC), dx)
    np.testing.assert_allclose(dx, 0.0, atol=1e-12)
    i0 = x0[4]
    assert x0[5] == i0
    # force balance K i^2/delta^2 = N + m g/2 per magnet (symmetric hover: delta = gap)
    assert PC["K"] * i0**2 / gap**2 == pytest.approx(PC["N1"] + PC["m"] * PC["g"] / 2, rel=1e-12)
    assert i0 == pytest.approx(i_expected, abs=1e-3)  # docs/manual/model.md: 2.5 A at 5 mm, 4 A at 8 mm
    np.testing.assert_allclose(u0, u_expected, atol=0.02)
    np.testing.assert_allclose(u0, PC["R"] * i0, rtol=1e-15)


def test_hover_current_rejects_asymmetric_load():
    with pytest.raises(ValueError):
        model.hover_current({**PC, "N2": 40.0}, 0.008)


def test_rk4_converges_at_fourth_order():
    """Open loop, 20 ms from a perturbed hover: halving the step divides the error by ~16."""
    p = model.plant_vector(PC)
    x0, u0 = model.hover_state(PC, 0.008)
    x0 = x0 + np.array([1e-4, 2e-3, -1e-4, -1e-3, 0.05, -0.03])
    u = u0 + np.array([3.0, -2.0])
    T = 0.02
    ref = x0.copy()
    model.rk4(ref, u, p, T, 8192)
    assert np.abs(ref - x0)[[0, 2]].max() > 5e-5  # the run really moves
    scale = np.array([1e-3, 1e-2, 1e-3, 1e-2, 1.0, 1.0])
    errs = []
    for n in (32, 64, 128):
        x = x0.copy()
        model.rk4(x, u, p, T, n)
        errs.append(np.linalg.norm((x - ref) / scale))
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    for r in ratios:
        assert 14.0 < r < 18.5, (errs, ratios)
