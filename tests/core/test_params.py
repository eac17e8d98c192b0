"""Parameter schema (dem_ros.core.params): defaults, validation messages, params files, assignments."""

from __future__ import annotations

import math

import pytest

from dem_ros.core.params import (
    SCHEMA,
    TABLE2,
    ConfigError,
    apply_overrides,
    default_config,
    load_params_file,
    parse_assignment,
)


def _reject(group: str, **changes) -> str:
    with pytest.raises(ConfigError) as exc:
        apply_overrides(default_config(), {group: changes})
    return str(exc.value)


# ---------------------------------------------------------------------------
# defaults
# ---------------------------------------------------------------------------
def test_defaults_validate_and_round_trip():
    cfg = default_config()
    assert set(cfg) == {"plant_sim", "reference", "estimator", "controller", "hw_driver", "rig"}
    for group, values in cfg.items():
        assert SCHEMA.validate_group(group, values) == values
    assert apply_overrides(cfg, {}) == cfg


def test_every_spec_is_typed_bounded_and_described():
    for group, specs in SCHEMA.groups.items():
        names = [p.name for p in specs]
        assert len(names) == len(set(names)), f"{group}: duplicate names"
        for p in specs:
            assert p.description, f"{group}.{p.name} has no description"
            assert type(p.default) is p.type, f"{group}.{p.name}: default {p.default!r} is not {p.type.__name__}"
            assert p.coerce(p.default, f"{group}.{p.name}") == p.default
            if p.type in (int, float):
                assert p.min is not None and p.max is not None and p.min <= p.default <= p.max


def test_true_plant_defaults_are_table2_plus_notes_3():
    pc = default_config()["plant_sim"]
    for k in ("L", "l", "m", "I", "N1", "N2", "g", "R", "K"):
        assert pc[k] == TABLE2[k]
    assert (TABLE2["R"], TABLE2["K"]) == (20.0, 4.374e-4)
    c = default_config()["controller"]
    # paper's initial estimates and K_hat0 = 0.7 K (docs/manual/model.md)
    assert (c["m_init"], c["R_init"]) == (10.0, 15.0)
    assert c["K_init"] == pytest.approx(0.7 * TABLE2["K"], rel=1e-3)
    assert (c["k1"], c["k2"], c["k3"]) == (70.0, 1600.0, 12000.0)


# ---------------------------------------------------------------------------
# rejected values: the message names the field, the value and what is allowed
# ---------------------------------------------------------------------------
def test_negative_gain_rejected():
    msg = _reject("controller", k1=-1)
    assert "controller.k1" in msg and "-1" in msg and "[0, 1e+06]" in msg


@pytest.mark.parametrize("k1,k2,k3", [(5.0, 1600.0, 12000.0), (7.5, 1600.0, 12000.0), (0.0, 1600.0, 12000.0)])
def test_non_hurwitz_gains_rejected(k1, k2, k3):
    """Routh-Hurwitz for s^3 + k1 s^2 + k2 s + k3 needs k1 k2 > k3 (equality is marginal, rejected)."""
    msg = _reject("controller", k1=k1, k2=k2, k3=k3)
    assert f"k1={k1:g}" in msg and f"k2={k2:g}" in msg and f"k3={k3:g}" in msg
    assert "k1*k2 > k3" in msg
    assert "Hurwitz" in msg


def test_hurwitz_boundary_just_inside_is_accepted():
    cfg = apply_overrides(default_config(), {"controller": {"k1": 7.51}})
    assert cfg["controller"]["k1"] == 7.51


def test_unknown_name_rejected_with_known_list():
    msg = _reject("controller", kk1=3.0)
    assert "controller.kk1" in msg and "unknown parameter" in msg
    assert "known:" in msg and "k1" in msg and "voltage_limit" in msg


@pytest.mark.parametrize(
    "group,name,value,allowed",
    [
        ("controller", "k1", "fast", "a float in [0, 1e+06]"),
        ("controller", "k1", True, "a float in [0, 1e+06]"),
        ("controller", "hover_init", "yes", "true or false"),
        ("plant_sim", "substeps", 2.5, "a int in [1, 1000]"),
        ("controller", "type", "mrac", "one of 'adaptive'"),
        ("plant_sim", "noise_scale", math.nan, "a float in [0, 1000]"),
    ],
)
def test_wrong_type_rejected(group, name, value, allowed):
    msg = _reject(group, **{name: value})
    assert f"{group}.{name}" in msg and repr(value) in msg and allowed in msg


@pytest.mark.parametrize(
    "group,name,value,allowed",
    [
        ("plant_sim", "m", 0.01, "[0.1, 10000] kg"),
        ("plant_sim", "g", 200.0, "[0, 100] m/s^2"),
        ("controller", "gap_floor", 0.5, "[1e-06, 0.01] m"),
        ("reference", "initial", 0.0, "[0.0001, 0.1] m"),
    ],
)
def test_out_of_range_rejected(group, name, value, allowed):
    msg = _reject(group, **{name: value})
    assert f"{group}.{name}" in msg and repr(value) in msg and allowed in msg


@pytest.mark.parametrize("sym,value", [("m", 60.0), ("R", 4.0), ("K", 5e-3)])
def test_initial_estimate_outside_bounds_rejected(sym, value):
    msg = _reject("controller", **{f"{sym}_init": value})
    lo = SCHEMA.defaults("controller")[f"{sym}_min"]
    hi = SCHEMA.defaults("controller")[f"{sym}_max"]
    assert f"{sym}_init = {value:g}" in msg
    assert f"[{sym}_min, {sym}_max] = [{lo:g}, {hi:g}]" in msg


def test_cross_field_plant_checks():
    assert "must be smaller than L" in _reject("plant_sim", l=0.5)
    assert "gap0" in _reject("plant_sim", gap0=0.05)
    assert "mass_ramp_end" in _reject("plant_sim", mass_ramp_start=50.0)
    assert "not Hurwitz" in _reject("reference", a2=0.1)


def test_rejection_is_atomic():
    base = default_config()
    with pytest.raises(ConfigError):
        apply_overrides(base, {"controller": {"k2": 1600.0, "k1": 1.0}})
    assert base == default_config()  # nothing half-applied to the input


# ---------------------------------------------------------------------------
# params files
# ---------------------------------------------------------------------------
GOOD_YAML = """\
controller:
  ros__parameters:
    k1: 60
    type: paper_fixed
/dem/plant_sim:
  ros__parameters:
    m: 16.0
    noise_scale: 0.1
/**:
  ros__parameters:
    gap_floor: 0.0006
"""


def test_load_params_file_good(tmp_path):
    path = tmp_path / "good.yaml"
    path.write_text(GOOD_YAML)
    cfg = load_params_file(path)
    assert cfg["controller"]["k1"] == 60.0 and isinstance(cfg["controller"]["k1"], float)
    assert cfg["controller"]["type"] == "paper_fixed"
    assert cfg["plant_sim"]["m"] == 16.0 and cfg["plant_sim"]["noise_scale"] == 0.1
    assert cfg["controller"]["gap_floor"] == 0.0006  # wildcard reaches the group that knows the name
    # everything else stays at its default
    d = default_config()
    assert cfg["controller"]["k2"] == d["controller"]["k2"]
    assert cfg["estimator"] == d["estimator"] and cfg["reference"] == d["reference"]


@pytest.mark.parametrize(
    "text,needle",
    [
        ("controller: [unclosed\n", "not valid YAML"),
        ("controller:\n  k1: 60\n", "ros__parameters"),
        ("[1, 2, 3]\n", "expected a mapping"),
        ("planner:\n  ros__parameters:\n    k1: 1\n", "unknown node 'planner'"),
        ("controller:\n  ros__parameters:\n    k1: -3\n", "controller.k1"),
        ("controller:\n  ros__parameters:\n    k1: 5.0\n", "Hurwitz"),
    ],
    ids=["syntax", "no-ros__parameters", "not-a-mapping", "unknown-node", "bad-value", "cross-field"],
)
def test_load_params_file_malformed(tmp_path, text, needle):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_params_file(path)
    assert needle in str(exc.value)
    assert str(path) in str(exc.value)  # says which file


def test_load_params_file_missing(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_params_file(tmp_path / "nope.yaml")


# ---------------------------------------------------------------------------
# NAME=VALUE assignments
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text,expected",
    [
        ("k1=60", ("controller", "k1", 60.0)),
        ("plant_sim.m=16", ("plant_sim", "m", 16.0)),
        ("hover_init=false", ("controller", "hover_init", False)),
        ("type=paper", ("controller", "type", "paper")),
        ("plant_sim.substeps=20", ("plant_sim", "substeps", 20)),
        (" estimator.sigma_gap = 1e-4", ("estimator", "sigma_gap", 1e-4)),
    ],
)
def test_parse_assignment(text, expected):
    got = parse_assignment(text)
    assert got == expected
    assert type(got[2]) is type(expected[2])


@pytest.mark.parametrize(
    "text,needle",
    [("k1", "expected NAME=VALUE"), ("planner.k1=3", "unknown group 'planner'"), ("kk=3", "controller.kk"),
     ("k1=-5", "controller.k1"), ("hover_init=maybe", "true or false")],
)
def test_parse_assignment_rejects(text, needle):
    with pytest.raises(ConfigError) as exc:
        parse_assignment(text)
    assert needle in str(exc.value)
