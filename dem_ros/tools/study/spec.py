r"""What a study is: its axes over plant truth, its cells, and the runs they give.

A *cell* (grid) or *sample* (Monte Carlo) is a set of schema overrides, applied with
:func:`~dem_ros.core.params.apply_overrides` on top of the scenario, so every value is
checked against the schema (field, bounds, cross-field rules) before any work is sent
out. :func:`plan_runs` turns a validated :class:`StudySpec` into one job per
(cell, controller); :func:`spec_from_args` builds that spec from the command line.

Axes
----
``--axis NAME=SPEC`` (repeatable). ``NAME`` is a schema parameter
``GROUP.NAME`` (``plant_sim.m``, ``plant_sim.R``, ``plant_sim.K``,
``plant_sim.noise_scale``, ``plant_sim.command_delay``, ``estimator.R``, ...)
or a derived axis:

``hover_asymmetry`` a (m)
    uneven start: d1_0 = gap0 + a, d2_0 = gap0 - a (``plant_sim.d1_0``,
    ``plant_sim.d2_0``; the plant starts in exact equilibrium there).

``SPEC`` is ``LO:HI:N`` (N values, evenly spaced, ends included), ``LO:HI``
(Monte Carlo: uniform on [LO, HI]; integer parameters: every integer of a
grid), or ``V1,V2,...``. A value may be relative to the scenario's value of
that parameter: ``-20%:+25%:4`` on ``plant_sim.R`` is 16 ... 25 ohm.
Note that ``plant_sim.command_delay`` is the plant's true delay only; the
controller keeps ``controller.command_delay`` (a mismatch study).

Seeds
-----
Grid: every cell uses ``plant_sim.seed`` = ``--seed`` (common random numbers:
cells differ only in the plant). Monte Carlo: sample i draws its axis values
from ``default_rng([seed, i])`` and its noise from ``plant_sim.seed = seed + i``,
so ``--samples 400`` after ``--samples 200`` reuses the first 200 runs.

Run ids
-------
A run is identified by a hash of its complete configuration, controller,
estimator, duration and the simulator's source (:func:`core_digest`): the
results file keeps the rows of finished runs and never reuses rows of other
code or settings.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...core.params import SCHEMA, ConfigError, ParamSpec, apply_overrides
from ..common import CONTROLLER_TYPES, ESTIMATOR_TYPES, load_config

__all__ = [
    "DERIVED",
    "PRESETS",
    "Axis",
    "Derived",
    "StudyError",
    "StudySpec",
    "core_digest",
    "parse_axis",
    "plan_runs",
    "spec_from_args",
]

PRESETS: dict[str, tuple[str, ...]] = {
    # the grid of issue #8: m 10-25 kg x R -20..+25 % x K +-20 % x hover asymmetry up to +-0.5 mm
    "acceptance": (
        "plant_sim.m=10:25:4",
        "plant_sim.R=-20%,-10%,0%,+10%,+25%",
        "plant_sim.K=-20%:+20%:3",
        "hover_asymmetry=-0.5e-3:0.5e-3:3",
    ),
}


class StudyError(RuntimeError):
    """The study cannot run (cluster unreachable, results of another study, a worker error)."""


# ---------------------------------------------------------------------------
# axes
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Derived:
    """An axis that sets several schema parameters from one value."""

    unit: str
    description: str
    needs: tuple[tuple[str, str], ...]
    apply: Callable[[Mapping[str, Mapping[str, Any]], float], dict[str, dict[str, Any]]]
    type: type = float


def _hover_asymmetry(cfg: Mapping[str, Mapping[str, Any]], a: float) -> dict[str, dict[str, Any]]:
    g0 = cfg["plant_sim"]["gap0"]
    return {"plant_sim": {"d1_0": g0 + a, "d2_0": g0 - a}}


DERIVED: dict[str, Derived] = {
    "hover_asymmetry": Derived(
        "m", "uneven start: d1_0 = gap0 + a, d2_0 = gap0 - a",
        (("plant_sim", "d1_0"), ("plant_sim", "d2_0")), _hover_asymmetry),
}


@dataclass(frozen=True)
class Axis:
    """One axis of the study.

    Attributes:
        name: ``GROUP.NAME`` of a schema parameter or a key of :data:`DERIVED`.
        unit: SI unit of the values.
        type: the parameter's type (float, int, bool, str).
        values: grid values (already of the parameter's type); with Monte Carlo, the
            list one value is drawn from. ``None``: a Monte Carlo range.
        low, high: Monte Carlo range (inclusive), in the parameter's unit.
    """

    name: str
    unit: str
    type: type
    values: tuple[Any, ...] | None = None
    low: float | None = None
    high: float | None = None

    def draw(self, rng: np.random.Generator) -> Any:
        """One Monte Carlo value."""
        if self.values is not None:
            return self.values[int(rng.integers(len(self.values)))]
        assert self.low is not None and self.high is not None
        if self.type is int:
            return int(rng.integers(int(self.low), int(self.high) + 1))
        return float(rng.uniform(self.low, self.high))

    def overrides(self, cfg: Mapping[str, Mapping[str, Any]], value: Any) -> dict[str, dict[str, Any]]:
        if self.name in DERIVED:
            return DERIVED[self.name].apply(cfg, value)
        group, name = self.name.split(".", 1)
        return {group: {name: value}}


def _axis_target(name: str) -> tuple[ParamSpec | None, Derived | None]:
    if name in DERIVED:
        d = DERIVED[name]
        for g, n in d.needs:
            try:
                SCHEMA.spec(g, n)
            except ConfigError:
                raise ConfigError(f"axis {name}: needs {g}.{n}, "
                                  "which this build's parameter schema does not have") from None
        return None, d
    group, dot, pname = name.partition(".")
    if not dot or not pname:
        raise ConfigError(f"axis {name!r}: expected GROUP.NAME (e.g. plant_sim.m) or one of: {', '.join(DERIVED)}")
    if group not in SCHEMA.groups:
        raise ConfigError(f"axis {name}: unknown group {group!r}; known: {', '.join(SCHEMA.groups)}")
    spec = SCHEMA.spec(group, pname)
    if spec.read_only:
        raise ConfigError(f"axis {name}: a read-only parameter cannot be an axis")
    if (group, pname) == ("controller", "type") or (group, pname) == ("estimator", "type"):
        raise ConfigError(f"axis {name}: choose laws with --controllers and the estimator with --estimator")
    return spec, None


def _number(text: str, name: str, base: float | None, kind: type) -> float:
    t = text.strip()
    rel = t.endswith("%")
    if rel and (base is None or kind is not float):
        raise ConfigError(f"axis {name}: {t!r}: a relative value (%) needs a float parameter")
    if rel and base == 0.0:
        raise ConfigError(f"axis {name}: {t!r}: a relative value (%) needs a non-zero value in the scenario (it has 0)")
    try:
        v = float(t[:-1] if rel else t)
    except ValueError:
        raise ConfigError(f"axis {name}: {t!r} is not a number") from None
    return base * (1.0 + v / 100.0) if rel else v  # type: ignore[operator]


def parse_axis(text: str, base: Mapping[str, Mapping[str, Any]], monte_carlo: bool = False) -> Axis:
    """Parse ``NAME=SPEC`` (module docstring) against the scenario config ``base``."""
    if "=" not in text:
        raise ConfigError(f"axis {text!r}: expected NAME=SPEC, e.g. plant_sim.m=10:25:4 or plant_sim.R=-20%:+25%:4")
    name, spec_text = (s.strip() for s in text.split("=", 1))
    spec, derived = _axis_target(name)
    if spec is not None:
        group, pname = name.split(".", 1)
        kind, unit, base_value = spec.type, spec.unit, base[group][pname]
    else:
        assert derived is not None
        kind, unit, base_value = derived.type, derived.unit, None

    def coerce(v: Any) -> Any:
        if spec is None:
            return float(v)
        if kind is int and isinstance(v, float) and v.is_integer():
            v = int(v)
        return spec.coerce(v, f"axis {name}")

    if not spec_text:
        raise ConfigError(f"axis {name}: no values")
    if kind in (bool, str):
        words = [w.strip() for w in spec_text.split(",")]
        vals = tuple(coerce(True if w.lower() == "true" else False if w.lower() == "false" else w) for w in words)
        return Axis(name, unit, kind, values=vals)
    if ":" in spec_text:
        parts = spec_text.split(":")
        if len(parts) not in (2, 3):
            raise ConfigError(f"axis {name}: {spec_text!r}: expected LO:HI:N, LO:HI or V1,V2,...")
        lo = _number(parts[0], name, base_value, kind)
        hi = _number(parts[1], name, base_value, kind)
        if not lo <= hi:
            raise ConfigError(f"axis {name}: LO = {parts[0]} must not exceed HI = {parts[1]}")
        if monte_carlo and len(parts) == 2:
            return Axis(name, unit, kind, low=coerce(lo), high=coerce(hi))
        if len(parts) == 2:
            if kind is not int:
                raise ConfigError(f"axis {name}: a grid axis needs a count, e.g. {parts[0]}:{parts[1]}:4 "
                                  "(or use --samples)")
            vals = tuple(coerce(v) for v in range(math.ceil(lo), math.floor(hi) + 1))
        else:
            try:
                n = int(parts[2])
            except ValueError:
                raise ConfigError(f"axis {name}: count {parts[2]!r} is not an integer") from None
            if not 1 <= n <= 10000:
                raise ConfigError(f"axis {name}: count {n} must lie in [1, 10000]")
            raw = np.linspace(lo, hi, n) if n > 1 else np.array([lo])
            if kind is int:
                if not np.allclose(raw, np.round(raw)):
                    raise ConfigError(f"axis {name}: {spec_text} does not give integers for an integer parameter")
                raw = np.round(raw)
            vals = tuple(coerce(float(f"{v:.12g}")) for v in raw)
    else:
        vals = tuple(coerce(float(f"{_number(w, name, base_value, kind):.12g}")) for w in spec_text.split(","))
    if len(set(vals)) != len(vals):
        raise ConfigError(f"axis {name}: repeated values {list(vals)}")
    return Axis(name, unit, kind, values=vals)


# ---------------------------------------------------------------------------
# the plan: one job per run
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class StudySpec:
    """Everything that defines a study (the command line, validated)."""

    scenario: str
    base: Mapping[str, Mapping[str, Any]]  # scenario config with --set applied
    axes: tuple[Axis, ...]
    controllers: tuple[str, ...]
    estimator: str | None
    duration: float
    seed: int
    samples: int | None  # None: grid

    @property
    def mode(self) -> str:
        return "grid" if self.samples is None else "monte_carlo"


def core_digest() -> str:
    """SHA-1 of the simulator's source (``dem_ros/core/**/*.py``): results of other code are not reused."""
    global _CORE_DIGEST
    if _CORE_DIGEST is None:
        root = Path(__file__).resolve().parents[2] / "core"
        h = hashlib.sha1()
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
        _CORE_DIGEST = h.hexdigest()
    return _CORE_DIGEST


_CORE_DIGEST: str | None = None


def _run_id(cfg: Mapping, controller: str, estimator: str, duration: float) -> str:
    blob = json.dumps({"cfg": cfg, "controller": controller, "estimator": estimator, "duration": duration,
                       "core": core_digest()}, sort_keys=True, default=str)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def _merge(a: dict[str, dict[str, Any]], b: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    for g, v in b.items():
        a.setdefault(g, {}).update(v)
    return a


def _cells(spec: StudySpec) -> list[tuple[tuple[Any, ...], int]]:
    """(axis values, noise seed) of every cell / sample."""
    if spec.samples is None:
        import itertools

        # (a grid axis always has its values: an axis without a count is refused unless --samples)
        return [(vals, spec.seed) for vals in itertools.product(*(a.values or () for a in spec.axes))]
    out = []
    for i in range(spec.samples):
        rng = np.random.default_rng([spec.seed, i])
        out.append((tuple(a.draw(rng) for a in spec.axes), (spec.seed + i) % 2**31))
    return out


def plan_runs(spec: StudySpec) -> list[dict[str, Any]]:
    """One job per (cell, controller): validated full config, run id and axis values."""
    jobs = []
    estimator = spec.estimator or spec.base["estimator"]["type"]
    for vals, seed in _cells(spec):
        over: dict[str, dict[str, Any]] = {"plant_sim": {"seed": seed}}
        for ax, v in zip(spec.axes, vals, strict=True):
            _merge(over, ax.overrides(spec.base, v))
        label = ", ".join(f"{a.name}={v}" for a, v in zip(spec.axes, vals, strict=True))
        cfg = apply_overrides(spec.base, over, f"study cell ({label})")
        for ctl in spec.controllers:
            jobs.append({
                "run_id": _run_id(cfg, ctl, estimator, spec.duration),
                "controller": ctl, "estimator": estimator, "seed": seed, "duration": spec.duration,
                "scenario": spec.scenario, "values": dict(zip((a.name for a in spec.axes), vals, strict=True)),
                "cfg": cfg,
            })
    return jobs


# ---------------------------------------------------------------------------
# the command line, validated
# ---------------------------------------------------------------------------
def _num(text: str | None, what: str, kind: type, lo: float, hi: float | None = None) -> Any:
    try:
        v = kind(text)
    except (TypeError, ValueError):
        v = None
    if v is None or (isinstance(v, float) and not math.isfinite(v)) or v < lo or (hi is not None and v > hi):
        rng = f"[{lo:g}, {hi:g}]" if hi is not None else f">= {lo:g}"
        raise ConfigError(f"{what}: got {text!r}, expected {'an integer' if kind is int else 'a number'} {rng}")
    return v


def spec_from_args(args: argparse.Namespace) -> StudySpec:
    """Validate the command line into a :class:`StudySpec` (ConfigError with one line on bad input)."""
    base, sc = load_config(args.scenario, args.params, args.set or ())
    samples = None if args.samples is None else _num(args.samples, "--samples", int, 1, 10**7)
    if args.preset is not None and args.preset not in PRESETS:
        raise ConfigError(f"--preset: unknown {args.preset!r}; known: {', '.join(PRESETS)}")
    axes_text = list(PRESETS[args.preset]) if args.preset else []
    axes_text += args.axis
    if not axes_text:
        raise ConfigError("give at least one --axis NAME=SPEC or a --preset (e.g. --preset acceptance)")
    axes = tuple(parse_axis(t, base, samples is not None) for t in axes_text)
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise ConfigError(f"--axis: an axis is given twice ({', '.join(n for n in names if names.count(n) > 1)})")
    if samples is None:
        bad = [a.name for a in axes if a.values is None]
        assert not bad
    ctls = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
    if not ctls:
        raise ConfigError("--controllers: empty")
    for c in ctls:
        if c not in CONTROLLER_TYPES:
            raise ConfigError(f"--controllers: unknown {c!r}; known: {', '.join(CONTROLLER_TYPES)}")
    if args.estimator is not None and args.estimator not in ESTIMATOR_TYPES:
        raise ConfigError(f"--estimator: got {args.estimator!r}, expected one of {', '.join(ESTIMATOR_TYPES)}")
    duration = sc.duration if args.duration is None else _num(args.duration, "--duration", float, 1e-3, 1e6)
    seed = base["plant_sim"]["seed"] if args.seed is None else _num(args.seed, "--seed", int, 0, 2**31 - 1)
    return StudySpec(sc.name, base, axes, ctls, args.estimator, float(duration), int(seed), samples)
