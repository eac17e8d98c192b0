"""Scenarios of notes section 7 (S1, S2, S3a-c, S4a-c): named overrides of the schema.

The definitions live in ``config/scenarios.yaml``; this module finds and
validates them and builds the time profiles (mass, noise, perturbation) a
scenario implies, all seeded.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .params import ConfigError, apply_overrides, default_config

__all__ = ["Scenario", "config_dir", "get_scenario", "load_scenarios", "mass_profile", "noise_samples", "perturbation_samples"]


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
    raise ConfigError("cannot find the dem_ros config directory (scenarios.yaml); looked in " + ", ".join(map(str, candidates)))


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
            raise ConfigError(f"{path}: scenario {name}.duration: got {duration!r}, expected a positive number of seconds")
        sc = Scenario(str(name), str(body.get("description", "")), float(duration), body.get("overrides") or {})
        sc.config()  # validate now, naming the scenario
        out[sc.name] = sc
    return out


def get_scenario(name: str, path: str | Path | None = None) -> Scenario:
    scenarios = load_scenarios(path)
    if name not in scenarios:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(scenarios)}")
    return scenarios[name]


def mass_profile(pc: Mapping, t: np.ndarray) -> np.ndarray:
    """m(t) = m + dm clip((t - t0)/(t1 - t0), 0, 1) (kg): a poise added at O."""
    t0, t1 = pc["mass_ramp_start"], pc["mass_ramp_end"]
    if t1 > t0:
        frac = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    else:
        frac = (t >= t0).astype(float)
    return pc["m"] + pc["mass_delta"] * frac


NOISE_UNIT = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-2, 1e-2])  # paper Eq. 47 for X = 1


def noise_samples(pc: Mapping, n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform measurement noise +-X [1e-3 m, 1e-3 m/s, ..., 1e-2 A], i.i.d. per sample (n, 6)."""
    a = pc["noise_scale"] * NOISE_UNIT
    if pc["noise_scale"] == 0.0:
        return np.zeros((n, 6))
    return rng.uniform(-1.0, 1.0, size=(n, 6)) * a


def perturbation_samples(pc: Mapping, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Additive input perturbation d (n, 2) in V."""
    kind, amp = pc["perturbation"], pc["perturbation_amplitude"]
    if kind == "none" or amp == 0.0:
        return np.zeros((t.size, 2))
    if kind == "uniform":
        return rng.uniform(-amp, amp, size=(t.size, 2))
    w = 2 * np.pi * pc["perturbation_frequency"]
    return amp * np.sin(w * t[:, None] + np.array([0.0, np.pi / 2]))
