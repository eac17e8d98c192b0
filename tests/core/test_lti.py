"""ZOH discretisation and the all-pole filters F(s), M(s) (dem_ros.core.lti; docs/manual/controllers.md) against
scipy.signal."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy import signal

from dem_ros.core.lti import AllPoleFilter, companion, filter_step, zoh

K1, K2, K3 = 70.0, 1600.0, 12000.0
F_COEFFS = [K3, K2, K1]  # F(s) = 1/(s^3 + 70 s^2 + 1600 s + 12000), constant term first
M_COEFFS = [0.25, 1.25, 2.0]  # M(s) = 0.25/(s^3 + 2 s^2 + 1.25 s + 0.25)
C_OUT = np.array([[1.0, 0.0, 0.0]])


@pytest.mark.parametrize("coeffs,gain", [(F_COEFFS, 1.0), (M_COEFFS, 0.25)], ids=["F", "M"])
@pytest.mark.parametrize("T", [1e-3, 0.05])
def test_zoh_matches_scipy_cont2discrete(coeffs, gain, T):
    A, B = companion(coeffs, gain)
    Ad, Bd = zoh(A, B, T)
    Ad_s, Bd_s, *_ = signal.cont2discrete((A, B[:, None], C_OUT, np.zeros((1, 1))), T, method="zoh")
    np.testing.assert_allclose(Ad, Ad_s, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(Bd, Bd_s[:, 0], rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("coeffs,gain", [(F_COEFFS, 1.0), (M_COEFFS, 0.25)], ids=["F", "M"])
def test_companion_realises_the_transfer_function(coeffs, gain):
    A, B = companion(coeffs, gain)
    num, den = signal.ss2tf(A, B[:, None], C_OUT, np.zeros((1, 1)))
    np.testing.assert_allclose(den, [1.0, coeffs[2], coeffs[1], coeffs[0]], rtol=1e-12)
    np.testing.assert_allclose(num[0][-1], gain, rtol=1e-9)
    np.testing.assert_allclose(num[0][:-1], 0.0, atol=1e-9 * gain)


def _filter_response(filt: AllPoleFilter, r: np.ndarray) -> np.ndarray:
    Z = np.zeros((3, 1))
    y = np.empty(r.size)
    for k, rk in enumerate(r):
        y[k] = Z[0, 0]
        filter_step(Z, filt.Ad, filt.Bd, np.array([rk]))
    return y


@pytest.mark.parametrize(
    "coeffs,gain,T,n",
    [(F_COEFFS, 1.0, 1e-3, 500), (M_COEFFS, 0.25, 1e-3, 20000)],
    ids=["F-0.5s", "M-20s"],
)
def test_step_response_matches_dlsim_and_lsim(coeffs, gain, T, n):
    filt = AllPoleFilter(coeffs, gain, T)
    r = np.ones(n)
    y = _filter_response(filt, r)
    den = [1.0, coeffs[2], coeffs[1], coeffs[0]]
    # discrete: scipy's own realisation of the transfer function (a different state
    # basis) discretised by scipy's ZOH and simulated by dlsim
    As, Bs, Cs, Ds = signal.tf2ss([gain], den)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((As, Bs, Cs, Ds), T, method="zoh")
    _, yd, _ = signal.dlsim((Ad, Bd, Cd, Dd, T), r)
    # continuous: a step is exactly representable by a ZOH, so samples must agree
    t = np.arange(n) * T
    _, yc, _ = signal.lsim(signal.lti([gain], den), r, t)
    peak = np.abs(yc).max()
    np.testing.assert_allclose(y, yd[:, 0], rtol=0, atol=1e-9 * peak)
    np.testing.assert_allclose(y, yc, rtol=0, atol=1e-6 * peak)
    # it approaches the DC gain
    assert filt.dc_gain == pytest.approx(gain / coeffs[0], rel=1e-15)
    assert y[-1] == pytest.approx(filt.dc_gain, rel=2e-3)


def test_dc_gains():
    assert AllPoleFilter(F_COEFFS, 1.0, 1e-3).dc_gain == pytest.approx(1 / 12000, rel=1e-15)
    assert AllPoleFilter(M_COEFFS, 0.25, 1e-3).dc_gain == pytest.approx(1.0, rel=1e-15)


def test_roots_of_error_polynomial_and_reference_model():
    """Notes 4: s^3+70s^2+1600s+12000 = (s+20)^2 (s+30); M(s) poles -1, -0.5, -0.5."""
    s = sp.Symbol("s")
    assert sp.expand((s + 20) ** 2 * (s + 30) - (s**3 + 70 * s**2 + 1600 * s + 12000)) == 0
    half = sp.Rational(1, 2)
    den_m = s**3 + 2 * s**2 + sp.Rational(5, 4) * s + sp.Rational(1, 4)
    assert sp.expand((s + 1) * (s + half) ** 2 - den_m) == 0
    # the realised filters have exactly those eigenvalues
    for coeffs, poles in ((F_COEFFS, [-30, -20, -20]), (M_COEFFS, [-1, -0.5, -0.5])):
        filt = AllPoleFilter(coeffs, 1.0, 1e-3)
        eig = np.sort(np.linalg.eigvals(filt.A).real)
        np.testing.assert_allclose(eig, poles, rtol=1e-5)  # double roots: sqrt(eps)-limited
        eig_d = np.sort(np.abs(np.linalg.eigvals(filt.Ad)))
        np.testing.assert_allclose(eig_d, np.sort(np.exp(np.array(poles) * 1e-3)), rtol=1e-7)


def test_spr_choice_of_notes_4_reduces_to_first_order():
    """(s^2 + 50 s + 600)/((s+20)^2 (s+30)) = 1/(s+20), which is SPR (not used by the algorithm)."""
    s = sp.Symbol("s")
    H = (s**2 + 50 * s + 600) / (s**3 + 70 * s**2 + 1600 * s + 12000)
    assert sp.cancel(H - 1 / (s + 20)) == 0


def test_filter_step_matches_matrix_recursion():
    rng = np.random.default_rng(21)
    filt = AllPoleFilter(F_COEFFS, 1.0, 1e-3)
    Z = rng.normal(size=(3, 18))
    Zref = Z.copy()
    for _ in range(50):
        w = rng.normal(size=18)
        filter_step(Z, filt.Ad, filt.Bd, w)
        Zref = filt.Ad @ Zref + np.outer(filt.Bd, w)
    np.testing.assert_allclose(Z, Zref, rtol=1e-12, atol=1e-14)
