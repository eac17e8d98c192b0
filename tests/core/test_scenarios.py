"""Scenario definitions (config/scenarios.yaml, dem_ros.core.scenarios) against docs/manual/scenarios.md."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.core.params import ConfigError, default_config
from dem_ros.core.scenarios import (
    NOISE_UNIT,
    config_dir,
    get_scenario,
    load_scenarios,
    mass_profile,
    noise_samples,
    perturbation_samples,
)
from dem_ros.core.simulate import prepare

NAMES = ["S1", "S2", "S3a", "S3b", "S3c", "S4a", "S4b", "S4c", "S5", "S6"]
DT = 1e-3


def test_all_scenarios_load_and_validate(scenarios):
    assert (config_dir() / "scenarios.yaml").is_file()
    assert sorted(scenarios) == sorted(NAMES)
    for name in NAMES:
        sc = scenarios[name]
        assert sc.duration == 100.0  # docs/manual/scenarios.md: T = 100 s
        cfg = sc.config()
        assert {"plant_sim", "reference", "estimator", "controller"} <= set(cfg)
    assert get_scenario("S2").overrides == scenarios["S2"].overrides


def test_common_settings_of_notes_7(scenarios):
    for name in NAMES:
        cfg = scenarios[name].config()
        pc, rc = cfg["plant_sim"], cfg["reference"]
        assert pc["gap0"] == 0.008 and rc["initial"] == 0.008
        assert (rc["target_1"], rc["step_time_1"]) == (0.005, 1.0)
        assert (rc["target_2"], rc["step_time_2"]) == (0.005, 10.0)
        assert (pc["gap_min"], pc["gap_max"]) == (1e-4, 0.030)  # failure: <= 0.1 mm or > 30 mm
        assert pc["dt"] == DT and pc["substeps"] == 10  # 1 ms ZOH, RK4 at 0.1 ms (docs/manual/controllers.md)


def test_S1_is_nominal(scenarios):
    assert scenarios["S1"].config() == default_config()


def test_S2_mass_profile(scenarios):
    """m(t) = 14.852 + 3 clip((t - 20)/20, 0, 1) kg."""
    pc = scenarios["S2"].config()["plant_sim"]
    t = np.arange(100_000) * DT
    m = mass_profile(pc, t)
    expected = 14.852 + 3.0 * np.clip((t - 20.0) / 20.0, 0.0, 1.0)
    np.testing.assert_allclose(m, expected, rtol=1e-14)
    assert m[t < 20].max() == 14.852 and m[t >= 40].min() == pytest.approx(17.852)
    assert np.all(np.diff(m) >= 0)
    # nothing else changes in S2
    d = default_config()["plant_sim"]
    assert {k: v for k, v in pc.items() if d[k] != v} == {"mass_delta": 3.0}
    # other scenarios keep the mass constant
    np.testing.assert_array_equal(mass_profile(scenarios["S1"].config()["plant_sim"], t), 14.852)


def test_mass_step_when_ramp_is_instantaneous():
    pc = {**default_config()["plant_sim"], "mass_delta": 2.0, "mass_ramp_start": 5.0, "mass_ramp_end": 5.0}
    m = mass_profile(pc, np.array([4.999, 5.0, 6.0]))
    np.testing.assert_allclose(m, [14.852, 16.852, 16.852])


@pytest.mark.parametrize("name,X", [("S3a", 1.0), ("S3b", 10.0), ("S3c", 0.1)])
def test_noise_amplitudes_uniform_and_seeded(scenarios, name, X):
    pc = scenarios[name].config()["plant_sim"]
    assert pc["noise_scale"] == X
    a = X * np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-2, 1e-2])
    np.testing.assert_allclose(pc["noise_scale"] * NOISE_UNIT, a)
    n = 200_000
    z = noise_samples(pc, n, np.random.default_rng(5))
    assert z.shape == (n, 6)
    # support [-a, a], filled to the edges, flat: mean 0, variance a^2/3
    assert np.all(np.abs(z) <= a)
    np.testing.assert_allclose(np.abs(z).max(0), a, rtol=1e-3)
    np.testing.assert_allclose(z.mean(0) / a, 0.0, atol=0.01)
    np.testing.assert_allclose(z.var(0) / a**2, 1 / 3, rtol=0.01)
    hist, _ = np.histogram(z[:, 0] / a[0], bins=10, range=(-1, 1))
    np.testing.assert_allclose(hist / (n / 10), 1.0, atol=0.03)
    # i.i.d.: no correlation between samples or channels
    assert abs(np.corrcoef(z[:-1, 0], z[1:, 0])[0, 1]) < 0.01
    assert abs(np.corrcoef(z[:, 0], z[:, 2])[0, 1]) < 0.01
    # seeded and reproducible
    np.testing.assert_array_equal(z, noise_samples(pc, n, np.random.default_rng(5)))
    assert not np.array_equal(z[:100], noise_samples(pc, 100, np.random.default_rng(6)))
    # the estimator's assumed sigma is the std of that uniform law, a/sqrt(3)
    ec = scenarios[name].config()["estimator"]
    assert ec["sigma_gap"] == pytest.approx(a[0] / np.sqrt(3), rel=1e-3)
    assert ec["sigma_rate"] == pytest.approx(a[1] / np.sqrt(3), rel=1e-3)
    assert ec["sigma_current"] == pytest.approx(a[4] / np.sqrt(3), rel=1e-3)


def test_prepare_noise_is_seeded_from_plant_seed(scenarios):
    cfg = scenarios["S3c"].config()
    n1 = prepare(cfg, 1.0)[4]
    n2 = prepare(cfg, 1.0)[4]
    np.testing.assert_array_equal(n1, n2)
    assert np.abs(n1).max() > 0
    cfg2 = {**cfg, "plant_sim": {**cfg["plant_sim"], "seed": 2}}
    assert not np.array_equal(n1, prepare(cfg2, 1.0)[4])
    np.testing.assert_array_equal(prepare(cfg, 1.0, seed=2)[4], prepare(cfg2, 1.0)[4])
    # without velocity sensors the rate channels carry no noise
    cfg3 = {**cfg, "plant_sim": {**cfg["plant_sim"], "measure_velocity": False}}
    n3 = prepare(cfg3, 1.0)[4]
    assert np.all(n3[:, [1, 3]] == 0) and np.abs(n3[:, [0, 2]]).max() > 0


def test_noise_free_scenarios(scenarios):
    for name in ("S1", "S2", "S4a", "S4b", "S4c"):
        assert np.all(prepare(scenarios[name].config(), 0.5)[4] == 0)


@pytest.mark.parametrize("name,amp", [("S4a", 20.0), ("S4c", 2.0)])
def test_uniform_perturbation(scenarios, name, amp):
    pc = scenarios[name].config()["plant_sim"]
    assert (pc["perturbation"], pc["perturbation_amplitude"]) == ("uniform", amp)
    t = np.arange(200_000) * DT
    d = perturbation_samples(pc, t, np.random.default_rng(3))
    assert d.shape == (t.size, 2)
    assert np.all(np.abs(d) <= amp)
    np.testing.assert_allclose(np.abs(d).max(0), amp, rtol=1e-3)
    np.testing.assert_allclose(d.mean(0) / amp, 0.0, atol=0.01)
    np.testing.assert_allclose(d.var(0) / amp**2, 1 / 3, rtol=0.01)
    assert abs(np.corrcoef(d[:, 0], d[:, 1])[0, 1]) < 0.01  # independent per coil
    assert abs(np.corrcoef(d[:-1, 0], d[1:, 0])[0, 1]) < 0.01  # and per sample
    np.testing.assert_array_equal(d, perturbation_samples(pc, t, np.random.default_rng(3)))
    ec = scenarios[name].config()["estimator"]
    assert ec["sigma_voltage"] == pytest.approx(amp / np.sqrt(3), rel=1e-3)


def test_sine_perturbation(scenarios):
    """S4b: d = 20 sin(2 pi 50 t + [0, pi/2]) V -- coils 90 deg apart."""
    pc = scenarios["S4b"].config()["plant_sim"]
    assert (pc["perturbation"], pc["perturbation_amplitude"], pc["perturbation_frequency"]) == ("sine", 20.0, 50.0)
    t = np.arange(2000) * DT
    d = perturbation_samples(pc, t, np.random.default_rng(0))
    np.testing.assert_allclose(d[:, 0], 20.0 * np.sin(2 * np.pi * 50.0 * t), atol=1e-10)
    np.testing.assert_allclose(d[:, 1], 20.0 * np.cos(2 * np.pi * 50.0 * t), atol=1e-10)
    # 90 deg: d1^2 + d2^2 = 20^2 at every sample
    np.testing.assert_allclose(d[:, 0] ** 2 + d[:, 1] ** 2, 400.0, rtol=1e-12)
    ec = scenarios["S4b"].config()["estimator"]
    assert ec["sigma_voltage"] == pytest.approx(20.0 / np.sqrt(2), rel=1e-3)  # RMS of the sine


def test_unperturbed_scenarios(scenarios):
    t = np.arange(100) * DT
    for name in ("S1", "S2", "S3a", "S3b", "S3c"):
        assert np.all(perturbation_samples(scenarios[name].config()["plant_sim"], t, np.random.default_rng(0)) == 0)


def test_bad_scenario_files(tmp_path):
    p = tmp_path / "sc.yaml"
    p.write_text("X1:\n  duration: -5\n")
    with pytest.raises(ConfigError, match=r"X1\.duration"):
        load_scenarios(p)
    p.write_text("X2:\n  overrides:\n    plant_sim: {noise_scale: -1.0}\n")
    with pytest.raises(ConfigError, match=r"scenario X2.*plant_sim\.noise_scale"):
        load_scenarios(p)
    p.write_text("X3: 5\n")
    with pytest.raises(ConfigError, match="X3"):
        load_scenarios(p)
    with pytest.raises(ConfigError, match="unknown scenario 'S9'"):
        get_scenario("S9")
