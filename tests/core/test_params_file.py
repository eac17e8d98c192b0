"""Params files: every key is known or the load fails naming it; unreadable files give one ConfigError line;
settings that would drop the plate are refused with the reason."""

from __future__ import annotations

import math

import pytest

from dem_ros.core.params import SCHEMA, ConfigError, apply_overrides, default_config, load_params_file


def _load(tmp_path, text: str | bytes):
    path = tmp_path / "p.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return load_params_file(path), str(path)


@pytest.mark.parametrize(("text", "names"), [
    ("/**:\n  ros__parameters:\n    k11: 60.0\n", ["/**", "'k11'", "no node declares it"]),
    ("'*':\n  ros__parameters:\n    noise_scael: 1.0\n", ["'noise_scael'"]),
    ("controller:\n  ros__parameters:\n    k11: 60.0\n", ["controller", "'k11'", "declares: type, dt, k1"]),
    ("/dem/plant_sim:\n  ros__parameters:\n    nested:\n      mass: 1.0\n", ["'nested.mass'"]),
    ("controller:\n  ros__parameters:\n    k1: 60.0\n  ros_parameters:\n    k2: 1.0\n", ["'ros_parameters'"]),
    ("controller:\n  ros__parameters:\n    k1: 60.0\n    k1: 61.0\n", ["duplicate key 'k1'", "line 3"]),
])
def test_unknown_or_repeated_key_is_an_error_that_names_it(tmp_path, text, names):
    with pytest.raises(ConfigError) as e:
        _load(tmp_path, text)
    msg = str(e.value)
    assert str(tmp_path / "p.yaml") in msg and "\n" not in msg.split(" (")[0]
    for n in names:
        assert n in msg, msg


def test_wildcard_name_declared_by_some_node_still_reaches_it(tmp_path):
    cfg, _ = _load(tmp_path, "/**:\n  ros__parameters:\n    gap_floor: 0.0006\n    dt: 0.001\n")
    assert cfg["controller"]["gap_floor"] == 0.0006
    with_dt = [g for g, specs in SCHEMA.groups.items() if any(s.name == "dt" for s in specs)]
    assert len(with_dt) >= 4
    assert all(cfg[g]["dt"] == 0.001 for g in with_dt)


@pytest.mark.parametrize(("data", "says"), [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "not UTF-8 text (byte 0: 0x89)"),
    (b"a: !!timestamp 2020-99-99\n", "not valid YAML"),
    (b"controller: {ros__parameters: {k1: [", "not valid YAML"),
])
def test_unreadable_file_is_one_config_error(tmp_path, data, says):
    with pytest.raises(ConfigError, match=r"p\.yaml") as e:
        _load(tmp_path, data)
    assert says in str(e.value)


@pytest.mark.parametrize(("change", "says"), [
    ({"voltage_limit": 0.0}, "voltage_limit = 0 V cannot hold the module at any gap"),
    ({"voltage_limit": 4.9}, "hover voltage of the nominal model is 5 V"),
    ({"max_age": 1e-4}, r"max_age = 0.0001 s is shorter than max\(1, command_delay\) dt = 0.001 s"),
    # the default max_age (2 ms) with a plant 3 samples ahead: on-time estimates are 3 ms old
    ({"command_delay": 3}, r"max_age = 0.002 s is shorter than .* = 0.003 s"),
])
def test_dangerous_controller_settings_are_refused_with_the_reason(change, says):
    with pytest.raises(ConfigError, match=says):
        apply_overrides(default_config(), {"controller": change})
    # the same check guards live changes: SCHEMA.merged is what the nodes' set-parameter path calls
    with pytest.raises(ConfigError, match=says):
        SCHEMA.merged("controller", default_config()["controller"], change)


def test_voltage_floor_is_the_hover_voltage_at_gap_floor():
    c = default_config()["controller"]
    w = c["m_nominal"] * c["g"] + c["N1"] + c["N2"]
    i = c["gap_floor"] * math.sqrt(0.5 * w / c["K_nominal"])  # N1 = N2: both magnets carry W/2
    u = c["R_nominal"] * i
    assert 4.9 < u < 5.1
    for limit, ok in ((u * 1.001, True), (u * 0.999, False)):
        if ok:
            apply_overrides(default_config(), {"controller": {"voltage_limit": limit}})
        else:
            with pytest.raises(ConfigError):
                apply_overrides(default_config(), {"controller": {"voltage_limit": limit}})
    apply_overrides(default_config(), {"controller": {"max_age": c["dt"]}})  # one period: allowed
    apply_overrides(default_config(), {"controller": {"max_age": 0.0}})  # off: allowed
    apply_overrides(default_config(), {"controller": {"command_delay": 2}})  # on-time age 2 ms = the default
    apply_overrides(default_config(), {"controller": {"command_delay": 3, "max_age": 0.004}})  # (d + 1) dt
