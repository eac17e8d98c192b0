"""Rig conditions of the plant (#8 item 3): per-coil resistance and heating (S5), uneven hover,
off-centre load (S6), gap-sensor offset and scale; each reachable by ``--set plant_sim.NAME=...``."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from dem_ros.core import model
from dem_ros.core.controllers import make_controller
from dem_ros.core.model import SI, SM, SN1, SN2, SR1, SR2
from dem_ros.core.params import ConfigError, apply_overrides, default_config, parse_assignment
from dem_ros.core.plant import DemPlant
from dem_ros.core.scenarios import plant_schedule, sensor_model

PC = default_config()["plant_sim"]
NEW = {"R1": 18.0, "R2": 22.0, "R1_rise": 0.2, "R2_rise": 0.1, "heating_start": 5.0, "heating_end": 50.0,
       "d1_0": 0.0085, "d2_0": 0.0075, "mass_offset": 0.3, "gap_offset_1": 1e-4, "gap_offset_2": -2e-4,
       "gap_scale_1": 1.02, "gap_scale_2": 0.97, "K1": 4.0e-4, "K2": 4.8e-4}


def _pc(**changes):
    return apply_overrides(default_config(), {"plant_sim": changes})["plant_sim"]


@pytest.mark.parametrize("name", sorted(NEW))
def test_every_new_setting_reachable_by_set(name):
    group, key, value = parse_assignment(f"plant_sim.{name}={NEW[name]}")
    assert (group, key, value) == ("plant_sim", name, NEW[name])
    assert _pc(**{name: NEW[name]})[name] == NEW[name]


@pytest.mark.parametrize("changes,field,allowed", [
    ({"R1": -1.0}, "plant_sim.R1", "[0, 10000] ohm"),
    ({"R2": 0.001}, "R2", "0 (take R)"),
    ({"K1": 1e-9}, "K1", "0 (take K)"),
    ({"K2": 2.0}, "plant_sim.K2", "[0, 1] N*m^2/A^2"),
    ({"R1_rise": 5.0}, "plant_sim.R1_rise", "[-0.5, 2]"),
    ({"d1_0": 0.05}, "d1_0", "(gap_min, gap_max)"),
    ({"d2_0": 0.2}, "plant_sim.d2_0", "[0, 0.1] m"),
    ({"mass_offset": 1.5}, "plant_sim.mass_offset", "[-1, 1]"),
    ({"gap_scale_1": 3.0}, "plant_sim.gap_scale_1", "[0.5, 2]"),
    ({"gap_offset_2": 0.02}, "plant_sim.gap_offset_2", "[-0.01, 0.01] m"),
    ({"heating_start": 50.0, "heating_end": 10.0}, "heating_end", "must not precede"),
])
def test_bad_setting_rejected_with_field_and_range(changes, field, allowed):
    with pytest.raises(ConfigError) as exc:
        _pc(**changes)
    assert field in str(exc.value) and allowed in str(exc.value)


def test_R_sets_both_coils_and_R1_R2_override():
    p = model.plant_vector(_pc(R=18.0))
    assert p[model.IR1] == p[model.IR2] == 18.0
    p = model.plant_vector(_pc(R=18.0, R2=25.0))
    assert (p[model.IR1], p[model.IR2]) == (18.0, 25.0)


def test_K_sets_both_magnets_and_K1_K2_override():
    p = model.plant_vector(_pc(K=4e-4))
    assert p[model.IK] == p[model.IK2] == 4e-4
    p = model.plant_vector(_pc(K=4e-4, K2=5e-4))
    assert (p[model.IK], p[model.IK2]) == (4e-4, 5e-4)


def test_each_magnet_pulls_and_each_coil_stores_flux_with_its_own_K():
    """F_j = K_j i_j^2/delta_j^2 in Eq. 3 and i_j' = (delta_j / 2K_j)(u_j - R i_j): only magnet 2 sees K2."""
    pc = _pc(K1=4e-4, K2=5e-4)
    x = np.array([0.008, 0, 0.008, 0, 4.0, 4.0])
    dx, dx1 = np.empty(6), np.empty(6)
    model.dynamics(x, np.array([90.0, 90.0]), model.plant_vector(pc), dx)
    model.dynamics(x, np.array([90.0, 90.0]), model.plant_vector(_pc(K=4e-4)), dx1)
    A, B = 1 / pc["m"] + pc["L"] * pc["l"] / pc["I"], 1 / pc["m"] - pc["L"] * pc["l"] / pc["I"]
    dF2 = 1e-4 * 4.0 ** 2 / 0.008 ** 2
    assert dx[1] - dx1[1] == pytest.approx(-B * dF2, rel=1e-9)
    assert dx[3] - dx1[3] == pytest.approx(-A * dF2, rel=1e-9)
    assert dx[4] == dx1[4]
    assert dx[5] == pytest.approx(0.008 / (2 * 5e-4) * (90.0 - 20.0 * 4.0), rel=1e-12)


def test_each_coil_obeys_its_own_resistance():
    """i_j' = (delta_j / 2K)(u_j - R_j i_j) at rest: only coil 2 sees R2."""
    pc = _pc(R1=20.0, R2=25.0)
    x = np.array([0.008, 0, 0.008, 0, 4.0, 4.0])
    dx = np.empty(6)
    model.dynamics(x, np.array([80.0, 80.0]), model.plant_vector(pc), dx)
    assert dx[4] == pytest.approx(0.0, abs=1e-12)
    assert dx[5] == pytest.approx(0.008 / (2 * pc["K"]) * (80.0 - 25.0 * 4.0), rel=1e-12)


def test_S5_heating_profile(scenarios):
    """R1 +20 %, R2 +10 %, linearly over 0-100 s."""
    pc = scenarios["S5"].config()["plant_sim"]
    t = np.array([0.0, 25.0, 50.0, 100.0, 120.0])
    S = plant_schedule(pc, t)
    np.testing.assert_allclose(S[:, SR1], 20.0 * (1 + 0.2 * np.minimum(t, 100) / 100), rtol=1e-14)
    np.testing.assert_allclose(S[:, SR2], 20.0 * (1 + 0.1 * np.minimum(t, 100) / 100), rtol=1e-14)
    np.testing.assert_array_equal(S[:, SM], pc["m"])


def test_S6_off_centre_load_is_the_weight_and_inertia_of_a_point_mass(scenarios):
    """2 kg at 0.3 L towards magnet 1: net force dm g, moment about O dm g 0.3 L, inertia dm (0.3 L)^2."""
    pc = scenarios["S6"].config()["plant_sim"]
    S = plant_schedule(pc, np.array([0.0, 30.0, 40.0, 90.0]))
    L, g = pc["L"], pc["g"]
    np.testing.assert_allclose(S[:, SM], pc["m"] + np.array([0, 1, 2, 2]))
    dN1, dN2 = S[:, SN1] - pc["N1"], S[:, SN2] - pc["N2"]
    np.testing.assert_allclose(dN1 + dN2, 0.0, atol=1e-12)  # the weight itself acts through the mass at O
    np.testing.assert_allclose((dN1 - dN2) * L, np.array([0, 1, 2, 2]) * g * 0.3 * L, rtol=1e-12)
    np.testing.assert_allclose(S[:, SI] - pc["I"], np.array([0, 1, 2, 2]) * (0.3 * L) ** 2, rtol=1e-12)


def _equilibrium_sympy(pc, d1v, d2v):
    """Eq. 3 and the coil equation at rest, solved again with sympy for (i1, i2, u1, u2)."""
    i1, i2, u1, u2 = sp.symbols("i1 i2 u1 u2", positive=True)
    L, l, m, I = (sp.nsimplify(pc[k]) for k in ("L", "l", "m", "I"))
    K1, K2 = (sp.nsimplify(k) for k in model.force_coefficients(pc))
    N1, N2, g = sp.nsimplify(pc["N1"]), sp.nsimplify(pc["N2"]), sp.nsimplify(pc["g"])
    d1, d2 = sp.nsimplify(d1v), sp.nsimplify(d2v)
    P, Q = (L + l) / (2 * L), (L - l) / (2 * L)
    A, B, C, D = 1 / m + L * l / I, 1 / m - L * l / I, 1 / m + L**2 / I, 1 / m - L**2 / I
    de1, de2 = P * d1 + Q * d2, Q * d1 + P * d2
    F1, F2 = K1 * i1**2 / de1**2, K2 * i2**2 / de2**2
    R1, R2 = model.coil_resistances(pc)
    sol = sp.solve([-A * F1 - B * F2 + C * N1 + D * N2 + g, -B * F1 - A * F2 + D * N1 + C * N2 + g,
                    u1 - sp.nsimplify(R1) * i1, u2 - sp.nsimplify(R2) * i2], [i1, i2, u1, u2], dict=True)
    assert len(sol) == 1
    return np.array([float(sol[0][s]) for s in (i1, i2, u1, u2)])


@pytest.mark.parametrize("d1,d2,extra", [(0.0085, 0.0075, {}), (0.006, 0.010, {"R1": 17.0, "R2": 23.0}),
                                         (0.008, 0.008, {"N1": 40.0, "N2": 33.0}),
                                         (0.007, 0.0075, {"K1": 3.8e-4, "K2": 5.1e-4, "R2": 24.0})])
def test_uneven_hover_starts_in_exact_equilibrium(d1, d2, extra):
    pc = _pc(d1_0=d1, d2_0=d2, **extra)
    x0, u0 = model.initial_state(pc)
    np.testing.assert_allclose(np.r_[x0[4:], u0], _equilibrium_sympy(pc, d1, d2), rtol=1e-12)
    assert (x0[0], x0[2]) == (d1, d2)
    dx = np.empty(6)
    model.dynamics(x0, u0, model.plant_vector(pc), dx)
    np.testing.assert_allclose(dx, 0.0, atol=1e-9)
    # and it stays there: 0.2 s under the held voltage moves it by less than a nanometre
    plant = DemPlant(pc)
    for _ in range(200):
        plant.hold(plant.u0)
    np.testing.assert_allclose(plant.x[[0, 2]], [d1, d2], atol=1e-9)


def test_no_hover_when_a_magnet_would_have_to_push():
    with pytest.raises(ConfigError, match="magnet can only attract"):
        model.initial_state(_pc(N1=0.0, N2=200.0))


def test_gap_sensor_offset_and_scale():
    pc = _pc(gap_offset_1=1e-4, gap_offset_2=-2e-4, gap_scale_1=1.02, gap_scale_2=0.97)
    G, b = sensor_model(pc)
    plant = DemPlant(pc)
    z = plant.measurement()
    x = plant.x
    np.testing.assert_allclose(z[[0, 2]], [1.02 * x[0] + 1e-4, 0.97 * x[2] - 2e-4], rtol=1e-14)
    np.testing.assert_allclose(z[4:], x[4:])
    np.testing.assert_array_equal(G * x + b, z)


def test_sensor_offset_is_seen_by_the_hover_fit_as_a_pitch_mismatch():
    """A level hover read through a +0.1 mm offset on sensor 1 looks tilted while the currents are equal:
    the hover fit reports the pitch equation's residual (never solves it) and still finds R exactly."""
    fits = {}
    for off in (0.0, 1e-4):
        cfg = apply_overrides(default_config(), {"plant_sim": {"gap_offset_1": off}})
        plant = DemPlant(cfg["plant_sim"])
        Z = np.array([plant.measurement_preroll() for _ in range(50)])
        ctrl = make_controller(cfg["controller"], "adaptive")
        ctrl.reset(Z, np.repeat(plant.u0[None], 50, axis=0))
        fits[off] = ctrl.hover_fit
    assert abs(fits[0.0].pitch) < 1e-9
    assert abs(fits[1e-4].pitch) > 0.1  # m/s^2: 2.5 % of the force per magnet, through the pitch lever
    for fit in fits.values():
        assert fit.determined == 3  # R, rho and the heave combination of (1/m, K)
        assert fit.phi[1] == pytest.approx(20.0, rel=1e-9) and abs(fit.phi[3]) < 1e-9
