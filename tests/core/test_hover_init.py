"""Hover initialisation from a pre-roll window (dem_ros.core.controllers.hover) against exact equilibria."""

from __future__ import annotations

import numpy as np
import pytest
from test_rig_conditions import _equilibrium_sympy

from dem_ros.core import model
from dem_ros.core.controllers import make_controller
from dem_ros.core.controllers.hover import hover_residuals
from dem_ros.core.model import initial_state
from dem_ros.core.params import apply_overrides, default_config
from dem_ros.core.scenarios import NOISE_UNIT

CFG = default_config()


def _window(pc, n, noise_scale=0.0, seed=3):
    x0, u0 = initial_state(pc)
    rng = np.random.default_rng(seed)
    Z = x0 + rng.uniform(-1, 1, (n, 6)) * noise_scale * NOISE_UNIT
    return Z, np.repeat(u0[None], n, axis=0), x0, u0


@pytest.mark.parametrize("d1,d2,R1,R2", [(0.0085, 0.0075, 20.0, 20.0), (0.006, 0.0095, 18.0, 23.0),
                                         (0.008, 0.008, 21.0, 19.0)])
@pytest.mark.parametrize("name", ["adaptive", "adaptive_enhanced"])
def test_tilted_hover_solved_exactly(name, d1, d2, R1, R2):
    """At an exact equilibrium (derived again with sympy): R1,2 = R_hat +- rho_hat, K_hat (q1 + q2) = N1 + N2 + m_hat g,
    and the law holds that hover at its first step (u = u0)."""
    pc = apply_overrides(CFG, {"plant_sim": {"d1_0": d1, "d2_0": d2, "R1": R1, "R2": R2}})["plant_sim"]
    Z, U, x0, u0 = _window(pc, 100)
    i1, i2, v1, v2 = _equilibrium_sympy(pc, d1, d2)
    np.testing.assert_allclose(np.r_[x0[4:], u0], [i1, i2, v1, v2], rtol=1e-12)
    ctrl = make_controller(CFG["controller"], name)
    ctrl.reset(Z, U)
    fit = ctrl.hover_fit
    mu, R, K, rho = fit.phi
    assert fit.determined == 3
    assert (R + rho, R - rho) == (pytest.approx(R1, rel=1e-9), pytest.approx(R2, rel=1e-9))
    P, Q = 0.5 + pc["l"] / (2 * pc["L"]), 0.5 - pc["l"] / (2 * pc["L"])
    q = (i1 / (P * d1 + Q * d2)) ** 2 + (i2 / (Q * d1 + P * d2)) ** 2
    assert K * q == pytest.approx(pc["N1"] + pc["N2"] + pc["g"] / mu, rel=1e-9)
    assert 5.0 < 1 / mu < 50.0
    u = ctrl.step(x0.copy(), np.array([d1, d2, 0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(u, u0, rtol=1e-6)


def test_noisy_window_does_not_solve_the_pitch_equation():
    """S3c-level noise: one raw sample (the old initialisation) vs a 200-sample window. The window keeps
    mass and K off their bounds and R within 0.1 %; the pitch direction is never solved."""
    pc = CFG["plant_sim"]
    Z, U, _, _ = _window(pc, 200, noise_scale=0.1)
    ctrl = make_controller(CFG["controller"], "adaptive")
    ctrl.reset(Z, U)
    m_hat, R_hat, K_hat = ctrl.diag[:3]
    assert R_hat == pytest.approx(20.0, rel=1e-3)
    assert 7.0 < m_hat < 11.0 and 2.5e-4 < K_hat < 4e-4  # the prior's split of the heave combination
    assert ctrl.hover_fit.determined == 3
    for k in range(5):  # any single noisy sample: same directions, estimates stay sane
        ctrl.reset(Z[k], U[k])
        assert 5.0 < ctrl.diag[0] < 50.0 and ctrl.hover_fit.determined == 3


def test_a_window_of_zero_current_determines_nothing():
    pc = CFG["plant_sim"]
    Z, U, _, _ = _window(pc, 10)
    Z[:, 4:] = 0.0
    U[:] = 0.0
    ctrl = make_controller(CFG["controller"], "adaptive")
    ctrl.reset(Z, U)
    assert ctrl.hover_fit.determined < 3
    assert np.all(np.isfinite(ctrl.diag[:3]))


@pytest.mark.parametrize("name", ["adaptive", "adaptive_enhanced"])
def test_a_plate_leaving_its_support_is_fitted_with_its_acceleration(name):
    """A plate just off its support: the currents 1 % above the hover's, so the plant (model.dynamics) accelerates it
    up. Fitted as a hover, the law's model would take that net force for a bias (the lift-off rose 1 mm above its
    reference, the error's steady state k1 a / k3); fitted with the measured accelerations, the model's heave
    acceleration at that state is the plant's, and the coil equations are solved as before."""
    pc = CFG["plant_sim"]
    x0, u0 = initial_state(pc)
    x = x0.copy()
    x[4:] *= 1.01
    u = u0 * 1.01
    dx = np.empty(6)
    model.dynamics(x, u, model.plant_vector(pc), dx)
    a = dx[[1, 3]]
    assert np.all(a < -0.1)  # m/s^2: up (gaps shrink), as a plate leaving its support
    cc = CFG["controller"]
    geo = _geo(cc)
    for accel, expected in ((None, 0.0), (a, a)):
        ctrl = make_controller(cc, name)
        ctrl.reset(x, u, accel)
        r, _ = hover_residuals(ctrl.hover_fit.phi, x[None], u[None], geo)  # r[:, 2:]: the model's y'' at x, u
        assert r[0, 2:].sum() == pytest.approx(np.sum(expected), abs=1e-9)
        _, R, _, rho = ctrl.hover_fit.phi
        assert (R + rho, R - rho) == (pytest.approx(pc["R"], rel=1e-9), pytest.approx(pc["R"], rel=1e-9))


def _geo(cc):
    P, Q = model.gap_weights(cc["L"], cc["l"])
    return {"P": P, "Q": Q, "cA": cc["L"] * cc["l"] / cc["I"], "cC": cc["L"] ** 2 / cc["I"], "N1": cc["N1"],
            "N2": cc["N2"], "g": cc["g"], "floor": cc["gap_floor"]}
