"""The adaptive law on a rig's slow changes (#8): coil heating (S5), an off-centre load (S6), a gap-sensor
offset; the coil-equation rows and the integral action that carry them (core/controllers/kernels.py);
the coil driver's limit in the offline loop. 100 s runs, estimator kf, delay 1 (the acceptance's defaults)."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.core.controllers import kernels as K
from dem_ros.core.controllers import make_controller
from dem_ros.core.params import apply_overrides, default_config
from dem_ros.core.simulate import simulate

CC = default_config()["controller"]


def test_S5_coil_heating_tracked_below_10um(scenarios):
    """R1 +20 %, R2 +10 % over 100 s: RMS < 10 um on both outputs, and R_hat follows the mean resistance."""
    res = simulate(scenarios["S5"].config(), controller="adaptive", duration=100.0)
    m = res.metrics()
    assert not res.failed
    assert max(m["rms_error_um"]) < 10.0, m["rms_error_um"]
    R1, R2 = res.schedule[-1, 4], res.schedule[-1, 5]
    assert res.diag[-1, K.D_R] == pytest.approx((R1 + R2) / 2, abs=0.02)  # R_hat (ohm) at the end


def test_S5_fixed_law_shows_the_drift(scenarios):
    """nonlinear_decoupling (fixed nominal R, no integral action) is carried away by the heating."""
    res = simulate(scenarios["S5"].config(), controller="nonlinear_decoupling", duration=100.0)
    assert res.failed or max(res.metrics()["rms_error_um"]) > 100.0


def test_S6_off_centre_load_no_failure(scenarios):
    res = simulate(scenarios["S6"].config(), controller="adaptive", duration=100.0)
    m = res.metrics()
    assert not res.failed
    assert max(m["rms_error_after_40s_um"]) < 10.0, m


def test_gap_sensor_offset_is_a_bounded_offset_not_a_drift(scenarios):
    """A 0.1 mm offset on sensor 1: the law makes the *measured* gap track the reference, so the true gap
    is off by the offset (the only reference the rig has), constant after the transients; no drift."""
    cfg = apply_overrides(scenarios["S1"].config(), {"plant_sim": {"gap_offset_1": 1e-4}})
    res = simulate(cfg, controller="adaptive", duration=100.0)
    assert not res.failed
    late = res.error[res.t >= 40.0]
    np.testing.assert_allclose(late[:, 0], -1e-4, atol=2e-6)  # true gap = measured - offset
    np.testing.assert_allclose(late[:, 1], 0.0, atol=2e-6)


def test_coil_rows_vanish_at_rest_and_measure_a_resistance_error():
    """At rest (u = R i, b' = 0) the weighted coil residual is kappa (R_hat - R) i per coil, and
    d rc / dv is kappa lp(i) times the scales in R and +-rho (the rows' only non-zero derivatives)."""
    ctrl = make_controller(CC, "adaptive")
    cp, scale = ctrl.cp, ctrl.scale
    R_true = (21.0, 19.0)
    i = (4.0, 3.9)
    d = 0.008
    b = (i[0] / d, i[1] / d)
    coil = np.full((5, 2), np.nan)
    u = np.array([R_true[0] * i[0], R_true[1] * i[1]])
    assert K._coil_rows(cp, scale, ctrl.v, coil, u, i[0], i[1], b[0], b[1]) == K.NO_COIL_ROWS  # starts the filters
    for _ in range(2):  # the next calls measure
        rows = K._coil_rows(cp, scale, ctrl.v, coil, u, i[0], i[1], b[0], b[1])
    rc, dR, drho = rows[0:2], rows[2:4], rows[4:6]
    phi = scale[:4] * ctrl.v[:4]
    R_hat = (phi[1] + phi[3], phi[1] - phi[3])
    for j in range(2):
        kappa = CC["coil_weight"] * (phi[0] + cp[K.CP_CA]) * b[j] / CC["k3"]
        assert rc[j] == pytest.approx(kappa * (R_hat[j] - R_true[j]) * i[j], rel=1e-12)
        assert dR[j] == pytest.approx(kappa * scale[1] * i[j], rel=1e-12)
        assert drho[j] == pytest.approx((1 if j == 0 else -1) * kappa * scale[3] * i[j], rel=1e-12)


def test_offline_loop_clips_at_the_boards_u_max(scenarios):
    """S4b asks > 100 V; with plant_sim.u_max = 95 V the applied voltage never exceeds it (the board's limit)."""
    cfg = scenarios["S4b"].config()
    free = simulate(cfg, controller="adaptive", duration=2.0)
    assert np.max(np.abs(free.u)) > 95.0
    clipped = simulate(apply_overrides(cfg, {"plant_sim": {"u_max": 95.0}}), controller="adaptive", duration=2.0)
    assert np.max(np.abs(clipped.u)) == pytest.approx(95.0, abs=1e-12)
