"""Control laws (dem_ros.core.controllers): exact linearisation, augmented error, adaptation laws
(docs/manual/controllers.md, docs/manual/errata.md, docs/manual/model.md)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from _symbolic import lie_numeric, plant, values

from dem_ros.core.controllers import (
    CONTROLLERS,
    CEController,
    PIDController,
    hover_regressors,
    make_controller,
)
from dem_ros.core.controllers import kernels as K
from dem_ros.core.model import dynamics, hover_state, plant_vector, rk4, theta_of
from dem_ros.core.params import ConfigError, default_config, with_board_limit
from dem_ros.core.reference import reference_trajectory

CFG = default_config()
PC = CFG["plant_sim"]
CC = dict(CFG["controller"])
if "command_delay" in CC:  # docs/manual/controllers.md timing, as run_loop below applies it: u_k held over [t_k, t_k+1)
    CC["command_delay"] = 0
K1, K2, K3 = CC["k1"], CC["k2"], CC["k3"]
CA = PC["L"] * PC["l"] / PC["I"]
CC_ = PC["L"] ** 2 / PC["I"]


def theta_of_phys(m: float, R: float, Kc: float) -> np.ndarray:
    th = np.empty(8)
    theta_of(np.array([1 / m, R, Kc]), CA, CC_, th)
    return th


THETA_TRUE = np.r_[theta_of_phys(PC["m"], PC["R"], PC["K"]), 0.0, 0.0]  # equal coils: rho = 0
NTH = K.NTH


def run_loop(ctrl, n: int, ref_cfg: dict | None = None, pc: dict | None = None, before=None, after=None):
    """Closed loop on the true plant, noiseless, from the 8 mm hover (docs/manual/controllers.md common loop).

    The command of sample k is held over [t_k+d, t_k+d+1) with d the controller's
    ``command_delay`` (0 unless a test sets it), the pipe starting full of the hover voltage.
    ``before(k, x, ctrl)`` is called before the controller step, ``after(k, x, ctrl, u)`` after it.
    Returns the final state.
    """
    pc = pc or PC
    ref_cfg = ref_cfg or CFG["reference"]
    dt = ctrl.cfg["dt"]
    x, u0 = hover_state(pc, pc["gap0"])
    ctrl.reset(x.copy(), u0)
    _, yd = reference_trajectory({**ref_cfg, "dt": dt}, n)
    p = plant_vector(pc)
    pipe = [u0.copy() for _ in range(ctrl.cfg.get("command_delay", 0))]
    for k in range(n):
        if before:
            before(k, x, ctrl)
        u = ctrl.step(x.copy(), yd[k]).copy()
        if after:
            after(k, x, ctrl, u)
        pipe.append(u)
        rk4(x, pipe.pop(0), p, dt, pc["substeps"])
    return x


EARLY_STEPS = {**CFG["reference"], "step_time_1": 0.05, "step_time_2": 0.15}


# ---------------------------------------------------------------------------
# exact feedback linearisation with the true parameters
# ---------------------------------------------------------------------------
def test_exact_linearisation_with_true_parameters():
    """nonlinear_decoupling with the true m, R, K: the plant's y''' equals v_e (Eq. 17/21 corrected).

    y''' from the sympy model (L_f^3 h + L_g L_f^2 h u) and, independently, from central
    differences of model.dynamics along x' = f + G u.
    """
    cc = {**CC, "m_nominal": PC["m"], "R_nominal": PC["R"], "K_nominal": PC["K"]}
    sym = plant()
    vals = values(PC)
    p = plant_vector(PC)
    rng = np.random.default_rng(31)
    a = np.empty(6)
    b = np.empty(6)
    xd = np.empty(6)
    for _ in range(15):
        x = np.array([rng.uniform(4e-3, 12e-3), rng.uniform(-0.01, 0.01), rng.uniform(4e-3, 12e-3),
                      rng.uniform(-0.01, 0.01), rng.uniform(2.0, 5.0), rng.uniform(2.0, 5.0)])
        ref = np.concatenate([rng.uniform(5e-3, 8e-3, 2), rng.uniform(-1e-3, 1e-3, 2),
                              rng.uniform(-1e-3, 1e-3, 2), rng.uniform(-1e-3, 1e-3, 2)])
        ctrl = make_controller(cc, "nonlinear_decoupling")  # fresh: no history at all
        u = ctrl.step(x.copy(), ref).copy()
        assert np.all(np.isfinite(u)) and ctrl.diag[K.D_FAULT] == 0
        lie = lie_numeric(sym, x, u, vals)
        v_e = (ref[6:8] - K1 * (lie["Lf2h"] - ref[4:6]) - K2 * (x[[1, 3]] - ref[2:4])
               - K3 * (x[[0, 2]] - ref[0:2]))
        scale = np.abs(lie["Lf3h"]).max() + np.abs(lie["LgLf2h"] @ u).max()
        np.testing.assert_allclose(lie["yddd"], v_e, rtol=0, atol=1e-9 * scale)
        # independent: y''' = d/dt of (d1'', d2'') along the actual vector field, by central differences
        dynamics(x, u, p, xd)
        h = 1e-7
        dynamics(x + h * xd, u, p, a)
        dynamics(x - h * xd, u, p, b)
        yddd_fd = (a[[1, 3]] - b[[1, 3]]) / (2 * h)
        np.testing.assert_allclose(yddd_fd, v_e, rtol=0, atol=1e-5 * scale)


def test_wrong_parameters_do_not_linearise():
    """Control: the same check fails with a 1 ohm R error (the test above can fail)."""
    cc = {**CC, "R_nominal": PC["R"] + 1.0}
    sym = plant()
    x = np.array([6e-3, 1e-3, 7e-3, -1e-3, 3.0, 3.5])
    ref = np.array([5e-3, 5e-3, 0, 0, 0, 0, 0, 0])
    u = make_controller(cc, "nonlinear_decoupling").step(x.copy(), ref).copy()
    lie = lie_numeric(sym, x, u, values(PC))
    v_e = -K1 * lie["Lf2h"] - K2 * x[[1, 3]] - K3 * (x[[0, 2]] - ref[:2])
    assert np.abs(lie["yddd"] - v_e).max() > 1.0  # m/s^3


# ---------------------------------------------------------------------------
# augmented error
# ---------------------------------------------------------------------------
def _augmented_error_run(dt: float, delay: int = 0, T: float = 1.5):
    """Fixed, wrong theta_hat (m 13 kg, R 20.2 ohm, K 4.5e-4): e_c from the Z bank vs xi^T (theta_hat - theta)."""
    cc = {**CC, "m_nominal": 13.0, "R_nominal": 20.2, "K_nominal": 4.5e-4, "dt": dt}
    if delay:
        cc["command_delay"] = delay
    ctrl = make_controller(cc, "nonlinear_decoupling")
    th_hat = ctrl.theta.copy()
    n = round(T / dt)
    _, yd = reference_trajectory({**EARLY_STEPS, "dt": dt}, n)
    ec = np.empty((n, 2))
    rhs = np.empty((n, 2))

    def before(k, x, c):
        xi = c.Z[0, : 2 * NTH].reshape(NTH, 2)  # F(s) W_p, channel 2r + j = W_p[r, j]
        zeta = c.Z[0, 2 * NTH :]  # F(s) (W_p^T theta_hat)
        e = x[[0, 2]] - yd[k, :2]
        ec[k] = xi.T @ th_hat - zeta - e  # docs/manual/controllers.md sign convention
        rhs[k] = xi.T @ (th_hat - THETA_TRUE)

    run_loop(ctrl, n, {**EARLY_STEPS, "dt": dt}, before=before)
    assert np.array_equal(ctrl.theta, th_hat)  # theta_hat really held constant
    t = np.arange(n) * dt
    return t, ec, rhs


def test_augmented_error_equals_xi_theta_error():
    """e_c = xi^T (theta_hat - theta) (Eqs. 30-32 with erratum 10) once the filters settle.

    Exact in continuous time; with the 1 ms ZOH the mismatch is O(T) in the transient
    (halving T halves it) and vanishes as the loop settles.
    """
    t, ec, rhs = _augmented_error_run(1e-3)
    assert np.abs(ec).max() > 3e-3  # a real (3.6 mm) error from the wrong parameters
    settled = np.abs(ec[-1] - rhs[-1]).max() / np.abs(ec[-1]).max()
    assert settled < 5e-3
    late = t >= 0.3
    mis_1ms = np.abs(ec - rhs)[late].max() / np.abs(ec).max()
    assert mis_1ms < 0.1
    t, ec4, rhs4 = _augmented_error_run(2.5e-4)
    mis_250us = np.abs(ec4 - rhs4)[t >= 0.3].max() / np.abs(ec4).max()
    assert 3.0 < mis_1ms / mis_250us < 5.0  # first order in T
    assert np.abs(ec4[-1] - rhs4[-1]).max() / np.abs(ec4[-1]).max() < 1e-3


def test_augmented_error_under_a_command_delay():
    """The same identity when the command is held one sample late and the law knows it (command_delay=1):
    the error filter is fed with the applied voltage, so e_c = xi^T (theta_hat - theta) still holds."""
    t, ec, rhs = _augmented_error_run(1e-3, delay=1)
    assert np.abs(ec).max() > 3e-3
    assert np.abs(ec[-1] - rhs[-1]).max() / np.abs(ec[-1]).max() < 5e-3
    assert np.abs(ec - rhs)[t >= 0.3].max() / np.abs(ec).max() < 0.15


def test_kernel_augmented_error_uses_the_notes_sign():
    """The e_c reported by the adaptive kernel is xi^T theta_hat - zeta - e, with the theta_hat before the update."""
    ctrl = make_controller(CC, "adaptive")
    _, yd = reference_trajectory(EARLY_STEPS, 300)
    seen = []

    def before(k, x, c):
        xi = c.Z[0, : 2 * NTH].reshape(NTH, 2)
        seen.append(xi.T @ c.theta - c.Z[0, 2 * NTH :] - (x[[0, 2]] - yd[k, :2]))

    def after(k, x, c, u):
        np.testing.assert_allclose(c.diag[[K.D_EC1, K.D_EC2]], seen[k], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(c.diag[[K.D_E1, K.D_E2]], x[[0, 2]] - yd[k, :2], rtol=1e-12, atol=1e-18)

    run_loop(ctrl, 300, EARLY_STEPS, before=before, after=after)
    assert np.abs(np.array(seen)).max() > 0


# ---------------------------------------------------------------------------
# hover initialisation (docs/manual/controllers.md A1, A2 iv)
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["adaptive", "adaptive_enhanced"])
@pytest.mark.parametrize("gap,u_factor", [(0.008, 1.0), (0.005, 1.0), (0.008, 1.02)])
def test_A2_hover_initialisation(name, gap, u_factor):
    """R_hat = u0/i0 and K_hat i0^2/delta0^2 = N + m_hat g/2, from the *measured* hover.

    "Exactly" in docs/manual/controllers.md means: to the convergence of 3 Gauss-Newton steps (3e-9 relative in R).
    """
    x0, u0 = hover_state(PC, gap)
    u0 = u0 * u_factor  # a measured voltage that disagrees with the true R: R_hat follows the data
    ctrl = make_controller(CC, name)
    ctrl.reset(x0, u0)
    m_hat, R_hat, K_hat = ctrl.diag[:3]
    i0 = x0[4]
    assert R_hat == pytest.approx(u0[0] / i0, rel=1e-8)
    assert K_hat * i0**2 / gap**2 == pytest.approx(PC["N1"] + m_hat * PC["g"] / 2, rel=1e-9)
    assert 5.0 <= m_hat <= 50.0 and m_hat != CC["m_init"]
    # theta_hat is theta(phi_hat)
    np.testing.assert_allclose(ctrl.theta[:8], theta_of_phys(m_hat, R_hat, K_hat), rtol=1e-12)
    np.testing.assert_allclose(ctrl.theta[8:], 0.0, atol=1e-12)  # both coils at the same u0/i0: rho_hat = 0
    # so the CE law holds the hover exactly at the first step (ref = hover, all derivatives 0)
    ref = np.array([gap, gap, 0, 0, 0, 0, 0, 0])
    u = ctrl.step(x0.copy(), ref)
    np.testing.assert_allclose(u, u0, rtol=1e-7)


def test_A1_hover_initialisation():
    """Notes 6 A1: W_p(x0, u0)^T theta_hat = -k1 g, and P = 1e5 (I - projection on the hover directions)."""
    x0, u0 = hover_state(PC, 0.008)
    ctrl = make_controller(CC, "paper_fixed")
    ctrl.reset(x0, u0)
    W3, W2 = hover_regressors(ctrl.cp, x0, u0)
    np.testing.assert_allclose((W3 + K1 * W2).T @ ctrl.theta[:8], -K1 * PC["g"], rtol=1e-9)
    assert np.all(ctrl.theta[8:] == 0.0) and np.all(ctrl.P[8:] == 0.0)  # A1 keeps the paper's 8 thetas
    Xh = (W3 + K1 * W2) * ctrl.scale[:8, None]
    np.testing.assert_allclose(ctrl.P[:8, :8] @ Xh, 0.0, atol=1e-6 * np.abs(Xh).max())
    eig = np.linalg.eigvalsh(ctrl.P[:8, :8])
    assert np.sum(eig > 1e4) == 7 and abs(eig[0]) < 1e-3  # one hover direction (symmetric hover: equal columns)


def test_no_hover_init_keeps_initial_estimates():
    ctrl = make_controller({**CC, "hover_init": False}, "adaptive")
    x0, u0 = hover_state(PC, 0.008)
    ctrl.reset(x0, u0)
    np.testing.assert_allclose(ctrl.diag[:3], [CC["m_init"], CC["R_init"], CC["K_init"]], rtol=1e-12)


def test_physical_estimates_invert_theta():
    out = np.empty(3)
    for m, R, Kc in [(14.852, 20.0, 4.374e-4), (9.0, 15.0, 3e-4), (30.0, 40.0, 1e-3)]:
        K.physical_estimates(theta_of_phys(m, R, Kc), out)
        np.testing.assert_allclose(out, [m, R, Kc], rtol=1e-12)


# ---------------------------------------------------------------------------
# A1 cone projection
# ---------------------------------------------------------------------------
def _a1_state():
    ctrl = make_controller(CC, "paper_fixed")
    P = np.eye(8) * 1e-300  # no RLS step: only the projection acts
    xi = np.zeros((8, 2))
    ec = np.zeros(2)
    return ctrl, P, xi, ec


def _project(v45):
    ctrl, P, xi, ec = _a1_state()
    v = ctrl.v.copy()
    v[4], v[5] = v45
    theta = np.zeros(NTH)
    K._update_paper_fixed(ctrl.cp, theta, v, ctrl.scale, P, xi, ec)
    np.testing.assert_allclose(theta, ctrl.scale * v)
    return v


def test_A1_cone_projection_inside_is_untouched():
    v = _project((-1.0, -0.05))
    assert (v[4], v[5]) == (-1.0, -0.05)


@pytest.mark.parametrize("v45", [(-0.3, 0.5), (-0.3, -0.5), (-1.0, 1.2), (0.2, -0.4)])
def test_A1_cone_projection_restores_invertibility(v45):
    """-theta5 >= |theta6| + 0.01 in scaled units after every update; the closest such point."""
    v = _project(v45)
    assert -v[4] >= abs(v[5]) + 0.01 - 1e-12
    assert -v[4] == pytest.approx(abs(v[5]) + 0.01, abs=1e-12)  # lands on the boundary
    # Euclidean projection onto the boundary: the move is along the cone normal (1, sign(theta6))/sqrt 2
    d = np.array([v[4] - v45[0], v[5] - v45[1]])
    assert abs(d[1] - np.sign(v45[1]) * d[0]) < 1e-12


def test_A1_cone_projection_sweep_including_wrong_sign():
    rng = np.random.default_rng(41)
    for v45 in rng.uniform(-2.0, 2.0, (200, 2)):
        v = _project(tuple(v45))
        assert -v[4] >= abs(v[5]) + 0.01 - 1e-12, (v45, v[4:6])


# ---------------------------------------------------------------------------
# covariance: A0 grows (printed sign), A1/A2 non-increasing without process noise
# ---------------------------------------------------------------------------
def _covariance_increments(name: str, cc: dict, n: int, dims: int):
    ctrl = make_controller(cc, name)
    Ps = []
    run_loop(ctrl, n, EARLY_STEPS, after=lambda k, x, c, u: Ps.append(c.P[:dims, :dims].copy()))
    return Ps


def test_A0_covariance_grows():
    """A0 (paper): P' = +P xi xi^T P/(1 + |xi^T P xi|) (erratum 13): every increment is PSD and P grows."""
    Ps = _covariance_increments("paper", CC, 60, 8)
    for P0, P1 in itertools.pairwise(Ps):
        assert np.linalg.eigvalsh(P1 - P0).min() >= -1e-12 * np.abs(P1).max()
    assert np.trace(Ps[-1]) > np.trace(Ps[0]) * (1 + 1e-9)


@pytest.mark.parametrize("name,dims", [("paper_fixed", 8), ("adaptive", 3), ("adaptive_enhanced", 3)])
def test_least_squares_covariance_is_non_increasing(name, dims):
    cc = {**CC, "q_m": 0.0, "q_R": 0.0, "q_K": 0.0, "q_rho": 0.0}
    Ps = _covariance_increments(name, cc, 400, dims)
    for P0, P1 in itertools.pairwise(Ps):
        assert np.linalg.eigvalsh(P1 - P0).max() <= 1e-9 * np.abs(P0).max()
    assert np.trace(Ps[-1]) < np.trace(Ps[0])


def test_A2_process_noise_lets_the_mass_covariance_grow():
    """Control for the test above: with q_m > 0 (the default) P_mm is not monotone."""
    Ps = _covariance_increments("adaptive", CC, 400, 3)
    assert any(P1[0, 0] > P0[0, 0] for P0, P1 in itertools.pairwise(Ps))


# ---------------------------------------------------------------------------
# construction, limits and faults
# ---------------------------------------------------------------------------
def test_make_controller_builds_every_law():
    for name in CONTROLLERS:
        ctrl = make_controller(CC, name)
        assert ctrl.name == name
        assert isinstance(ctrl, PIDController if name == "decentralized_pid" else CEController)
    assert make_controller({**CC, "type": "paper"}).name == "paper"


def test_make_controller_rejects_unknown_names():
    with pytest.raises(ConfigError) as exc:
        make_controller(CC, "mrac")
    assert "'mrac'" in str(exc.value) and "adaptive" in str(exc.value)
    with pytest.raises(ConfigError):
        CEController(CC, "decentralized_pid")
    with pytest.raises(ConfigError, match=r"controller\.k1"):
        make_controller({**CC, "k1": -1.0}, "adaptive")


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_voltage_limit_clips(name):
    cc = {**CC, "voltage_limit": 50.0}
    x0, u0 = hover_state(PC, 0.008)  # holding 8 mm needs 80 V
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])
    ctrl = make_controller(cc, name)
    ctrl.reset(x0, u0)
    u = ctrl.step(x0.copy(), ref)
    np.testing.assert_array_equal(u, [50.0, 50.0])
    unlimited = make_controller(CC, name)
    unlimited.reset(x0, u0)
    assert np.all(unlimited.step(x0.copy(), ref) > 50.0)
    # plate rushing towards the rail (10 m/s up): every law wants well below -50 V
    x = x0.copy()
    x[[1, 3]] = -10.0
    assert np.all(unlimited.step(x.copy(), ref) < -55.0)
    ctrl = make_controller(cc, name)
    ctrl.reset(x0, u0)
    np.testing.assert_array_equal(ctrl.step(x, ref), [-50.0, -50.0])


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_the_law_clips_at_the_boards_u_max(name):
    """The board clips at u_max: the law clips there too (min(voltage_limit, u_max)), so what it feeds its
    augmented error and integrator is what the board applies; simulate gives it the board's u_max."""
    x0, u0 = hover_state(PC, 0.008)  # holding 8 mm needs 80 V
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])
    ctrl = make_controller({**CC, "voltage_limit": 1e4, "u_max": 60.0}, name)
    ctrl.reset(x0, u0)
    np.testing.assert_array_equal(ctrl.step(x0.copy(), ref), [60.0, 60.0])
    cfg = with_board_limit({**CFG, "plant_sim": {**CFG["plant_sim"], "u_max": 150.0}})
    assert cfg["controller"]["u_max"] == 150.0 and CFG["controller"]["u_max"] == CFG["plant_sim"]["u_max"]


@pytest.mark.parametrize("name", list(CONTROLLERS))
@pytest.mark.parametrize("channel", range(6))
def test_nan_measurement_gives_finite_u_and_fault(name, channel):
    x0, u0 = hover_state(PC, 0.008)
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])
    ctrl = make_controller(CC, name)
    ctrl.reset(x0, u0)
    ctrl.step(x0.copy(), ref)
    assert ctrl.diag[K.D_FAULT] == 0
    bad = x0.copy()
    bad[channel] = np.nan
    u = ctrl.step(bad, ref)
    assert np.all(np.isfinite(u))
    assert ctrl.diag[K.D_FAULT] == 1



@pytest.mark.parametrize("name", [
    "adaptive",
    "adaptive_enhanced",
    "paper_fixed",
    "paper",
    "decentralized_pid",
    "nonlinear_decoupling",
])
def test_controller_recovers_after_one_nan_gap_sample(name):
    """One NaN gap sample must not disable the controller: the next good samples give the hover voltage again."""
    x0, u0 = hover_state(PC, 0.008)
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0])
    ctrl = make_controller(CC, name)
    ctrl.reset(x0, u0)
    u_good = ctrl.step(x0.copy(), ref).copy()
    bad = x0.copy()
    bad[0] = np.nan
    ctrl.step(bad, ref)
    for _ in range(3):
        u = ctrl.step(x0.copy(), ref).copy()
    assert np.all(np.isfinite(ctrl.diag[:3])) or name == "decentralized_pid"
    np.testing.assert_allclose(u, u_good, rtol=0.05)
    assert ctrl.diag[K.D_FAULT] == 0


def test_set_params_rediscretises_the_error_filter():
    ctrl = make_controller(CC, "adaptive")
    Ad = ctrl.F.Ad.copy()
    ctrl.set_params({**CC, "k1": 60.0, "k2": 1200.0, "k3": 8000.0})
    assert ctrl.cp[K.CP_K1] == 60.0
    assert not np.allclose(ctrl.F.Ad, Ad)
    np.testing.assert_allclose(ctrl.F.c, [8000.0, 1200.0, 60.0])
    with pytest.raises(ConfigError):
        ctrl.set_params({**CC, "k1": 1.0})
    assert ctrl.cp[K.CP_K1] == 60.0  # a rejected change leaves the controller as it was


def test_enhanced_dead_zone_gates_the_whole_least_squares_step():
    """Inside the dead zone neither the estimate nor the covariance moves (only the random walk adds q Ts);
    outside it both do. (Shrinking P inside the dead zone killed adaptation for good: S2 failed at 40.8 s.)"""
    rng = np.random.default_rng(7)
    xi = rng.normal(size=(K.NTH, 2)) * 1e-3
    ec = np.array([2e-6, -1e-6])
    for e0, adapting in ((1.0, False), (0.0, True)):
        ctrl = make_controller({**CC, "deadzone": "error", "e0": e0, "w": 0.0}, "adaptive_enhanced")
        v, P = ctrl.v.copy(), ctrl.P.copy()
        flag = K._update_adaptive(ctrl.cp, ctrl.theta, v, ctrl.scale, ctrl.v0, P, xi, ec, True, K.DZ_ERROR,
                                  K.NO_COIL_ROWS)
        q = np.diag([CC["q_m"], CC["q_R"], CC["q_K"], CC["q_rho"]]) * CC["dt"]
        assert flag == float(adapting)
        if adapting:
            assert not np.array_equal(v, ctrl.v) and np.trace(P[:4, :4]) < np.trace(ctrl.P[:4, :4] + q)
        else:
            np.testing.assert_array_equal(v, ctrl.v)
            np.testing.assert_allclose(P[:4, :4], ctrl.P[:4, :4] + q, rtol=1e-15)
