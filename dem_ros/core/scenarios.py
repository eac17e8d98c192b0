r"""Scenarios of docs/manual/scenarios.md (S1, S2, S3a-c, S4a-c) and rig conditions (S5, S6):
named overrides of the schema.

The definitions live in ``config/scenarios.yaml``; this module finds and
validates them and builds what a scenario implies, all seeded:

* the plant schedule (time-varying truth, one row per sample, layout ``model.S*``):
  mass m(t) = m + dm f(t), f = clip((t - t0)/(t1 - t0), 0, 1) (added mass ramped in);
  an added mass at s L from O towards magnet 1 (``mass_offset`` s) adds the couple of
  its weight as loads N1 += dm f g s/2, N2 -= dm f g s/2 and its inertia
  I(t) = I + dm f (s L)^2 (the shift of the centre of mass, dm s L, is neglected);
  coil heating R_j(t) = R_j (1 + rise_j h(t)), h the linear ramp over
  [heating_start, heating_end] (copper: +0.39 %/K);
* the sensors: z = G x + b + n with G = diag(s1, s1, s2, s2, 1, 1) (gap scale, also
  on the measured rate), b = (o1, 0, o2, 0, 0, 0) (gap offsets), n the noise of Eq. 47;
* the input perturbation d (V).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .params import ConfigError, apply_overrides, default_config, load_params_file, parse_assignment

__all__ = [
    "Disturbances",
    "Scenario",
    "config_dir",
    "disturbances",
    "get_scenario",
    "load_scenarios",
    "mass_profile",
    "noise_samples",
    "perturbation_samples",
    "plant_schedule",
    "scenario_config",
    "sensor_model",
]


def config_dir() -> Path:
    """Directory of the shipped config files (checkout, pip data_files or ament share)."""
    import sys

    candidates = [Path(__file__).resolve().parents[2] / "config", Path(sys.prefix) / "share" / "dem_ros" / "config"]
    try:  # pragma: no cover - only under ROS
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("dem_ros")) / "config")
    except Exception:
        pass
    for c in candidates:
        if (c / "scenarios.yaml").is_file():
            return c
    raise ConfigError("cannot find the dem_ros config directory (scenarios.yaml); looked in "
                      + ", ".join(map(str, candidates)))


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    duration: float
    overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def config(self, base: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
        """The full validated configuration of this scenario on top of ``base``."""
        return apply_overrides(base or default_config(), self.overrides, f"scenario {self.name}")


def load_scenarios(path: str | Path | None = None) -> dict[str, Scenario]:
    import yaml

    path = Path(path) if path else config_dir() / "scenarios.yaml"
    try:
        tree = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read scenarios ({exc})") from None
    out = {}
    for name, body in (tree or {}).items():
        if not isinstance(body, Mapping):
            raise ConfigError(f"{path}: scenario {name!r} must be a mapping")
        duration = body.get("duration", 100.0)
        if not isinstance(duration, (int, float)) or duration <= 0:
            raise ConfigError(f"{path}: scenario {name}.duration: got {duration!r}, expected a positive number "
                              "of seconds")
        sc = Scenario(str(name), str(body.get("description", "")), float(duration), body.get("overrides") or {})
        sc.config()  # validate now, naming the scenario
        out[sc.name] = sc
    return out


def get_scenario(name: str, path: str | Path | None = None) -> Scenario:
    scenarios = load_scenarios(path)
    if name not in scenarios:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(scenarios)}")
    return scenarios[name]


def scenario_config(scenario: str, params: str | Path | None = None, sets: Sequence[str] = (),
                    default_group: str = "controller") -> dict[str, dict[str, Any]]:
    """Scenario ``scenario``'s configuration, a params file on top, then ``GROUP.NAME=VALUE`` assignments
    (``NAME=VALUE`` alone: ``default_group``'s). ConfigError on any mistake."""
    base = load_params_file(params) if params else None
    cfg = get_scenario(scenario).config(base)
    over: dict[str, dict[str, Any]] = {}
    for text in sets:
        g, n, v = parse_assignment(text, default_group=default_group)
        over.setdefault(g, {})[n] = v
    return apply_overrides(cfg, over, "--set") if over else cfg


def _ramp(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """0 before t0, 1 after t1, linear in between (a step at t0 when t1 == t0)."""
    if t1 > t0:
        return np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return (t >= t0).astype(float)


def mass_profile(pc: Mapping[str, Any], t: np.ndarray) -> np.ndarray:
    """m(t) = m + dm clip((t - t0)/(t1 - t0), 0, 1) (kg): the added mass ramped in."""
    m: np.ndarray = pc["m"] + pc["mass_delta"] * _ramp(np.asarray(t, float), pc["mass_ramp_start"], pc["mass_ramp_end"])
    return m


def plant_schedule(pc: Mapping[str, Any], t: np.ndarray) -> np.ndarray:
    """The time-varying truth at times ``t`` (s): shape (n, NSCHED), columns m, I, N1, N2, R1, R2 (module docstring)."""
    from .model import NSCHED, SI, SM, SN1, SN2, SR1, SR2, coil_resistances  # here: loading scenarios needs no numba

    t = np.asarray(t, float)
    out = np.empty((t.size, NSCHED))
    dm = pc["mass_delta"] * _ramp(t, pc["mass_ramp_start"], pc["mass_ramp_end"])
    s = pc.get("mass_offset", 0.0)
    out[:, SM] = pc["m"] + dm
    out[:, SI] = pc["I"] + dm * (s * pc["L"]) ** 2
    out[:, SN1] = pc["N1"] + 0.5 * dm * pc["g"] * s
    out[:, SN2] = pc["N2"] - 0.5 * dm * pc["g"] * s
    h = _ramp(t, pc.get("heating_start", 0.0), pc.get("heating_end", 0.0))
    R1, R2 = coil_resistances(pc)
    out[:, SR1] = R1 * (1.0 + pc.get("R1_rise", 0.0) * h)
    out[:, SR2] = R2 * (1.0 + pc.get("R2_rise", 0.0) * h)
    return out


def sensor_model(pc: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(G, b), each (6,): the sensors read z = G x + b (+ noise); module docstring."""
    s1, s2 = pc.get("gap_scale_1", 1.0), pc.get("gap_scale_2", 1.0)
    G = np.array([s1, s1, s2, s2, 1.0, 1.0])
    b = np.array([pc.get("gap_offset_1", 0.0), 0.0, pc.get("gap_offset_2", 0.0), 0.0, 0.0, 0.0])
    return G, b


@dataclass(frozen=True)
class Disturbances:
    """What the plant sees during a run of n samples (t_k = k dt).

    Attributes:
        schedule (n, NSCHED): time-varying truth (m, I, N1, N2, R1, R2).
        noise (n, 6): measurement noise [m, m/s, m, m/s, A, A] (rates 0 when not measured).
        pert (n, 2): input perturbation (V).
    """

    schedule: np.ndarray
    noise: np.ndarray
    pert: np.ndarray


def disturbances(pc: Mapping[str, Any], n: int, seed: int | None = None) -> Disturbances:
    """The seeded disturbances of a run (one generator: noise first, then perturbation)."""
    t = np.arange(n) * pc["dt"]
    rng = np.random.default_rng(pc["seed"] if seed is None else seed)
    noise = noise_samples(pc, n, rng)
    if not pc["measure_velocity"]:
        noise[:, [1, 3]] = 0.0
    pert = perturbation_samples(pc, t, rng)
    return Disturbances(plant_schedule(pc, t), noise, pert)


NOISE_UNIT = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-2, 1e-2])  # paper Eq. 47 for X = 1


def noise_samples(pc: Mapping[str, Any], n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform measurement noise +-X [1e-3 m, 1e-3 m/s, ..., 1e-2 A], i.i.d. per sample (n, 6)."""
    a = pc["noise_scale"] * NOISE_UNIT
    if pc["noise_scale"] == 0.0:
        return np.zeros((n, 6))
    z: np.ndarray = rng.uniform(-1.0, 1.0, size=(n, 6)) * a
    return z


def perturbation_samples(pc: Mapping[str, Any], t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Additive input perturbation d (n, 2) in V."""
    kind, amp = pc["perturbation"], pc["perturbation_amplitude"]
    if kind == "none" or amp == 0.0:
        return np.zeros((t.size, 2))
    if kind == "uniform":
        return rng.uniform(-amp, amp, size=(t.size, 2))
    w = 2 * np.pi * pc["perturbation_frequency"]
    d: np.ndarray = amp * np.sin(w * t[:, None] + np.array([0.0, np.pi / 2]))
    return d
