"""One parameter schema for the whole package.

Every tunable of the plant simulator, reference generator, state estimator and
controller is declared exactly once here, with its type, default, SI unit,
bounds and description. The offline simulator, both ROS transports and the
config files all read this schema; nothing else repeats a default.

Groups are named after the nodes that own them (``plant_sim``, ``reference``,
``estimator``, ``controller``), so ``config/dem_ros.yaml`` is a plain ROS 2
params file::

    controller:
      ros__parameters:
        k1: 70.0

Validation happens in one place (:meth:`Schema.validate`): per field (type,
bounds, choices) and per group (cross-field rules such as a Hurwitz error
polynomial). Failures raise :class:`ConfigError` naming the field, the value
and what is allowed.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

__all__ = [
    "SAFETY_SPECS",
    "SCHEMA",
    "TABLE2",
    "ConfigError",
    "ParamSpec",
    "Schema",
    "default_config",
    "load_params_file",
    "read_yaml",
    "with_board_limit",
]


_FLOAT_RE = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message names the field."""


@dataclass(frozen=True)
class ParamSpec:
    """One typed parameter.

    Attributes:
        name: parameter name inside its group (a valid ROS parameter name).
        type: ``float``, ``int``, ``bool`` or ``str``.
        default: default value (already of ``type``).
        unit: SI unit, ``""`` when dimensionless.
        description: one line for humans and ROS parameter descriptors.
        min, max: inclusive numeric bounds (``None``: unbounded).
        choices: allowed values for strings.
        read_only: may not change after start-up (e.g. loop period).
    """

    name: str
    type: type
    default: Any
    unit: str = ""
    description: str = ""
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False

    def allowed(self) -> str:
        """Human description of the allowed values."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.type is bool:
            return "true or false"
        lo = "-inf" if self.min is None else f"{self.min:g}"
        hi = "inf" if self.max is None else f"{self.max:g}"
        unit = f" {self.unit}" if self.unit else ""
        return f"a {self.type.__name__} in [{lo}, {hi}]{unit}"

    def coerce(self, value: Any, where: str) -> Any:
        """Return ``value`` converted to this parameter's type, or raise ConfigError."""
        bad = ConfigError(f"{where}: got {value!r}, expected {self.allowed()}")
        if self.type is bool:
            if isinstance(value, bool):
                return value
            raise bad
        if self.type is int:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad
            if isinstance(value, float) and not value.is_integer():
                raise bad
            value = int(value)
        elif self.type is float:
            if isinstance(value, str) and _FLOAT_RE.fullmatch(value.strip()):
                value = float(value)  # YAML 1.1 reads 1e-05 as a string; rcl reads it as a double
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad
            value = float(value)
            if not math.isfinite(value):
                raise bad
        elif self.type is str:
            if not isinstance(value, str):
                raise bad
            if self.choices is not None and value not in self.choices:
                raise bad
            return value
        if self.min is not None and value < self.min:
            raise bad
        if self.max is not None and value > self.max:
            raise bad
        return value


GroupCheck = Callable[[Mapping[str, Any]], "str | None"]


@dataclass
class Schema:
    """Parameter groups (one per node) plus cross-field checks per group."""

    groups: dict[str, tuple[ParamSpec, ...]]
    checks: dict[str, tuple[GroupCheck, ...]] = field(default_factory=dict)

    def spec(self, group: str, name: str) -> ParamSpec:
        for p in self.groups[group]:
            if p.name == name:
                return p
        raise ConfigError(
            f"{group}.{name}: unknown parameter; known: "
            + ", ".join(p.name for p in self.groups[group])
        )

    def defaults(self, group: str) -> dict[str, Any]:
        return {p.name: p.default for p in self.groups[group]}

    def validate_group(self, group: str, values: Mapping[str, Any]) -> dict[str, Any]:
        """Coerce and check a complete group; return the clean dict."""
        if group not in self.groups:
            raise ConfigError(f"unknown parameter group {group!r}; known: {', '.join(self.groups)}")
        clean = {}
        for name, value in values.items():
            clean[name] = self.spec(group, name).coerce(value, f"{group}.{name}")
        missing = [p.name for p in self.groups[group] if p.name not in clean]
        if missing:
            raise ConfigError(f"{group}: missing parameters {missing}")
        for check in self.checks.get(group, ()):
            reason = check(clean)
            if reason:
                raise ConfigError(f"{group}: {reason}")
        return clean

    def merged(self, group: str, base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
        """Validate ``changes`` applied on top of ``base`` as a whole (atomic)."""
        values = dict(base)
        values.update(changes)
        return self.validate_group(group, values)


# ---------------------------------------------------------------------------
# Physical constants of the rig (paper Table 2, docs/manual/model.md).
# ---------------------------------------------------------------------------
TABLE2 = {
    "L": 0.3,  # m, centre O to load points
    "l": 0.168,  # m, centre O to magnet force points
    "m": 14.852,  # kg
    "I": 0.5648,  # kg m^2
    "N1": 36.5,  # N
    "N2": 36.5,  # N
    "g": 9.81,  # m/s^2
    "R": 20.0,  # ohm (docs/manual/model.md, recommended truth)
    "K": 4.374e-4,  # N m^2 / A^2 (docs/manual/model.md)
}


def _geometry(prefix_desc: str) -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("L", float, TABLE2["L"], "m", f"{prefix_desc}distance from centre O to the load points", 0.01, 10.0),
        ParamSpec("l", float, TABLE2["l"], "m",
                  f"{prefix_desc}distance from centre O to the magnet force points", 0.001, 10.0),
        ParamSpec("I", float, TABLE2["I"], "kg*m^2", f"{prefix_desc}pitch inertia about O", 1e-4, 1e4),
        ParamSpec("N1", float, TABLE2["N1"], "N", f"{prefix_desc}load force at end 1 (downward)", 0.0, 1e4),
        ParamSpec("N2", float, TABLE2["N2"], "N", f"{prefix_desc}load force at end 2 (downward)", 0.0, 1e4),
        ParamSpec("g", float, TABLE2["g"], "m/s^2", "gravitational acceleration", 0.0, 100.0),
    )


def _check_geometry(v: Mapping[str, Any]) -> str | None:
    if not v["l"] < v["L"]:
        return f"l = {v['l']} m must be smaller than L = {v['L']} m (magnets inside the load points)"
    return None


def _check_hurwitz(v: Mapping[str, Any]) -> str | None:
    k1, k2, k3 = v["k1"], v["k2"], v["k3"]
    # Routh-Hurwitz for s^3 + k1 s^2 + k2 s + k3
    if not (k1 > 0 and k2 > 0 and k3 > 0 and k1 * k2 > k3):
        return (
            f"k1={k1:g}, k2={k2:g}, k3={k3:g} do not make s^3+k1 s^2+k2 s+k3 Hurwitz "
            "(need k1, k2, k3 > 0 and k1*k2 > k3)"
        )
    return None


def _check_bounds(v: Mapping[str, Any]) -> str | None:
    for sym in ("m", "R", "K"):
        lo, hi, init = v[f"{sym}_min"], v[f"{sym}_max"], v[f"{sym}_init"]
        if not lo < hi:
            return f"{sym}_min = {lo:g} must be below {sym}_max = {hi:g}"
        if not lo <= init <= hi:
            return f"{sym}_init = {init:g} lies outside [{sym}_min, {sym}_max] = [{lo:g}, {hi:g}]"
    return None


def _check_controller_safety(v: Mapping[str, Any]) -> str | None:
    """Settings that would drop the plate however the rest is tuned.

    The law's limit, min(``voltage_limit``, ``u_max``): holding the nominal module at a gap delta takes, on the
    more loaded magnet, F_j = (W + (L/l)|N1 - N2|)/2 with W = m g + N1 + N2
    (force and moment balance about O), i_j = delta sqrt(F_j/K) (F = K i^2/delta^2)
    and u_j = R i_j. Below that voltage at ``gap_floor`` - the smallest gap the
    law acts on - no gap can be held.

    ``max_age``: 0 turns the check off; a positive value shorter than
    max(1, command_delay) dt - the age an estimate can have on time when the plant
    runs command_delay samples ahead (``core/controllers/checks.py``) - would reject
    estimates that arrive on time.
    """
    w = v["m_nominal"] * v["g"] + v["N1"] + v["N2"]
    f = 0.5 * (w + v["L"] / v["l"] * abs(v["N1"] - v["N2"]))
    u_min = v["R_nominal"] * v["gap_floor"] * math.sqrt(f / v["K_nominal"])
    limit = "voltage_limit" if v["voltage_limit"] <= v["u_max"] else "u_max"  # the law clips at the smaller
    if v[limit] < u_min:
        return (f"{limit} = {v[limit]:g} V cannot hold the module at any gap: the hover voltage "
                f"of the nominal model is {u_min:.3g} V already at gap_floor = {v['gap_floor']:g} m")
    on_time = max(1, v["command_delay"]) * v["dt"]  # the oldest an on-time estimate can be (checks.py)
    if 0.0 < v["max_age"] < on_time:
        return (f"max_age = {v['max_age']:g} s is shorter than max(1, command_delay) dt = {on_time:g} s, the age "
                f"an estimate can have on time (command_delay = {v['command_delay']}): on-time estimates would "
                f"be refused; use 0 (no check) or at least {on_time:g} s ((command_delay + 1) dt = "
                f"{(v['command_delay'] + 1) * v['dt']:g} s is the natural value)")
    if not v["reference_gap_min"] < v["reference_gap_max"]:
        return (f"reference_gap_min = {v['reference_gap_min']:g} m must be below reference_gap_max = "
                f"{v['reference_gap_max']:g} m")
    return None


def _check_plant(v: Mapping[str, Any]) -> str | None:
    r = _check_geometry(v)
    if r:
        return r
    if not v["gap_min"] < v["gap0"] < v["gap_max"]:
        return f"gap0 = {v['gap0']:g} m must lie inside (gap_min, gap_max) = ({v['gap_min']:g}, {v['gap_max']:g})"
    if not v["mass_ramp_end"] >= v["mass_ramp_start"]:
        return "mass_ramp_end must not precede mass_ramp_start"
    if not v["heating_end"] >= v["heating_start"]:
        return "heating_end must not precede heating_start"
    for name in ("R1", "R2"):
        if 0.0 < v[name] < 0.01:
            return f"{name} = {v[name]:g} ohm: expected 0 (take R) or a resistance in [0.01, 1e4] ohm"
    for name in ("K1", "K2"):
        if 0.0 < v[name] < 1e-7:
            return f"{name} = {v[name]:g} N*m^2/A^2: expected 0 (take K) or a force coefficient in [1e-07, 1]"
    for name in ("d1_0", "d2_0"):
        if v[name] != 0.0 and not v["gap_min"] < v[name] < v["gap_max"]:
            return (f"{name} = {v[name]:g} m must be 0 (take gap0) or lie inside (gap_min, gap_max) = "
                    f"({v['gap_min']:g}, {v['gap_max']:g})")
    return None


def _check_reference(v: Mapping[str, Any]) -> str | None:
    a2, a1, a0 = v["a2"], v["a1"], v["a0"]
    if not (a2 > 0 and a1 > 0 and a0 > 0 and a2 * a1 > a0):
        return f"reference model denominator s^3+{a2:g}s^2+{a1:g}s+{a0:g} is not Hurwitz"
    return None


#: default gap-sensor calibration: 16-bit ADC over ~0..20 mm, mildly nonlinear (c0..c3; m, m/count, ...)
_GAP_POLY = (0.0, 2.5e-7, 8.0e-13, 0.0)

# The board's hard limits and watchdog (dem_ros.board.Supervisor): one list, included in every
# group whose node is (or simulates) the board that drives the coils: plant_sim, hw_driver.
SAFETY_SPECS = (
    ParamSpec("u_max", float, 200.0, "V",
              "coil driver bus: applied voltages are clipped to +-this (hover 50-80 V, transients ~120 V, scenario S4b "
              "asks 155 V)", 1.0, 1e4),
    ParamSpec("i_max", float, 10.0, "A",
              "coil current trip: above this the board latches a fault and lands the plate", 0.1, 1e3),
    ParamSpec("trip_gap_min", float, 0.0015, "m",
              "gap trip toward the rail: the board brakes, latches a fault and lands when the gap where the plate "
              "would stop if it braked now (docs/manual/board.md, the braking bound) falls below this; the driver "
              "trips on measured gaps below it", 0.0, 0.1),
    ParamSpec("trip_gap_max", float, 0.013, "m",
              "gap trip away from the rail: an estimated gap above this latches a fault (the plate is on its support "
              "or falling)", 1e-4, 1.0),
    ParamSpec("hold_timeout", float, 0.05, "s",
              "a sample without a fresh command holds the last voltage at most this long, then the board lands the "
              "plate (unstable poles: e-folding 17-20 ms)", 1e-3, 1.0),
    ParamSpec("landing_gap", float, 0.011, "m",
              "landing position: the plate rests on its support at this load-point gap (larger gap = away from "
              "the rail)", 1e-4, 0.1),
    ParamSpec("landing_speed", float, 0.01, "m/s", "a landing descends no faster than this", 1e-4, 1.0),
)


_SAFETY_DEFAULTS = {p.name: p.default for p in SAFETY_SPECS}
#: the board's u_max as the control law knows it: the same spec (default, unit, bounds), set from the board's group
_LAW_U_MAX = replace(
    next(p for p in SAFETY_SPECS if p.name == "u_max"),
    description="the board's u_max (its plant_sim / hw_driver value; simulate and the launcher set it from there): "
                "the law clips its command at +-min(voltage_limit, u_max), so its augmented error and integrator "
                "see the voltage the board applies")


# The command source lock of the nodes that drive the coils (plant_sim, hw_driver): they take /dem/command
# only from the writers of this node (docs/manual/topics.md "Command source lock").
COMMAND_SOURCE = ParamSpec(
    "command_source", str, "controller", "",
    "accept /dem/command only from this node's writers (a node name in this node's namespace, or /ns/name); others are "
    "dropped, counted and reported",
    read_only=True,  # the parameter services are open to any process: no redirecting the lock at run time
)
_NODE_NAME = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


def _check_command_source(v: Mapping[str, Any]) -> str | None:
    if not _NODE_NAME.match(v["command_source"]):
        return (f"command_source = {v['command_source']!r} is not a ROS node name (e.g. controller or "
                "/rig1/controller)")
    return None


def _check_gap_range(v: Mapping[str, Any]) -> str | None:
    if not v["gap_range_min"] < v["gap_range_max"]:
        return f"need gap_range_min < gap_range_max; got {v['gap_range_min']:g}, {v['gap_range_max']:g} m"
    return None


def _check_safety(v: Mapping[str, Any]) -> str | None:
    if not v["trip_gap_min"] < v["landing_gap"] <= v["trip_gap_max"]:
        return (f"need trip_gap_min < landing_gap <= trip_gap_max; got {v['trip_gap_min']:g}, "
                f"{v['landing_gap']:g}, {v['trip_gap_max']:g} m")
    if "gap_min" in v and not v["gap_min"] < v["trip_gap_min"]:
        return f"trip_gap_min = {v['trip_gap_min']:g} m must lie above the rail-contact gap_min = {v['gap_min']:g} m"
    if "gap_max" in v and not v["trip_gap_max"] < v["gap_max"]:
        return f"trip_gap_max = {v['trip_gap_max']:g} m must lie below gap_max = {v['gap_max']:g} m"
    for name in ("gap0", "d1_0", "d2_0"):  # d1_0, d2_0: 0 takes gap0
        if v.get(name) and not v["trip_gap_min"] < v[name] < v["landing_gap"]:
            return (f"{name} = {v[name]:g} m must lie between trip_gap_min = {v['trip_gap_min']:g} m and "
                    f"landing_gap = {v['landing_gap']:g} m (the plate hovers above its support)")
    return None


_CONTROLLERS = ("adaptive", "adaptive_enhanced", "paper", "paper_fixed", "nonlinear_decoupling", "decentralized_pid")

SCHEMA = Schema(
    groups={
        "plant_sim": (
            *_geometry("true "),
            ParamSpec("m", float, TABLE2["m"], "kg", "true mass of the suspended module", 0.1, 1e4),
            ParamSpec("R", float, TABLE2["R"], "ohm", "true coil resistance", 0.01, 1e4),
            ParamSpec("K", float, TABLE2["K"], "N*m^2/A^2", "true force coefficient, F = K i^2/delta^2", 1e-7, 1.0),
            ParamSpec("gap0", float, 0.008, "m", "initial hover gap of both magnets", 1e-4, 0.1),
            ParamSpec("gap_min", float, 1e-4, "m",
                      "rail contact: a gap or delta at or below this is a failure", 0.0, 0.01),
            ParamSpec("gap_max", float, 0.030, "m", "a gap above this is a failure (plate dropped)", 0.001, 1.0),
            ParamSpec("dt", float, 1e-3, "s", "control / sample period (zero-order hold)", 1e-5, 0.1, read_only=True),
            ParamSpec("substeps", int, 10, "", "RK4 sub-steps per sample period", 1, 1000, read_only=True),
            ParamSpec("mass_delta", float, 0.0, "kg", "added mass at O (unknown to the controllers)", -1e3, 1e3),
            ParamSpec("mass_ramp_start", float, 20.0, "s", "time the added mass starts ramping in", 0.0, 1e6),
            ParamSpec("mass_ramp_end", float, 40.0, "s", "time the added mass is fully on", 0.0, 1e6),
            ParamSpec("mass_offset", float, 0.0, "",
                      "where the added mass sits: fraction of L from O towards magnet 1 (0: at O; 0.3: S6)", -1.0, 1.0),
            ParamSpec("R1", float, 0.0, "ohm", "true resistance of coil 1 at t = 0 (0: R)", 0.0, 1e4),
            ParamSpec("R2", float, 0.0, "ohm", "true resistance of coil 2 at t = 0 (0: R)", 0.0, 1e4),
            ParamSpec("K1", float, 0.0, "N*m^2/A^2",
                      "true force coefficient of magnet 1 (its F and its coil's flux 2 K1 i/delta; 0: K)", 0.0, 1.0),
            ParamSpec("K2", float, 0.0, "N*m^2/A^2", "true force coefficient of magnet 2 (0: K)", 0.0, 1.0),
            ParamSpec("R1_rise", float, 0.0, "",
                      "coil heating: relative rise of R1 reached at heating_end, linear from heating_start "
                      "(0.2: +20 %)", -0.5, 2.0),
            ParamSpec("R2_rise", float, 0.0, "",
                      "coil heating: relative rise of R2 reached at heating_end, linear from heating_start", -0.5, 2.0),
            ParamSpec("heating_start", float, 0.0, "s", "time the coil resistances start rising", 0.0, 1e6),
            ParamSpec("heating_end", float, 100.0, "s",
                      "time the coil resistances reach R_j (1 + Rj_rise) and stay", 0.0, 1e6),
            ParamSpec("d1_0", float, 0.0, "m",
                      "initial hover gap of magnet 1 (0: gap0); the plant starts in exact equilibrium there", 0.0, 0.1),
            ParamSpec("d2_0", float, 0.0, "m", "initial hover gap of magnet 2 (0: gap0)", 0.0, 0.1),
            ParamSpec("gap_offset_1", float, 0.0, "m",
                      "gap sensor 1 reads scale_1 d1 + offset_1 (+ noise)", -0.01, 0.01),
            ParamSpec("gap_offset_2", float, 0.0, "m", "gap sensor 2 offset", -0.01, 0.01),
            ParamSpec("gap_scale_1", float, 1.0, "",
                      "gap sensor 1 scale (gain) error, 1 = exact; also scales the measured rate", 0.5, 2.0),
            ParamSpec("gap_scale_2", float, 1.0, "", "gap sensor 2 scale (gain) error", 0.5, 2.0),
            ParamSpec("noise_scale", float, 0.0, "",
                      "measurement noise X: uniform +-X*[1e-3 m, 1e-3 m/s, 1e-2 A] (paper Eq. 47)", 0.0, 1e3),
            ParamSpec("measure_velocity", bool, True, "", "the sensors also deliver the gap rates"),
            ParamSpec("perturbation", str, "none", "",
                      "additive input perturbation waveform", choices=("none", "uniform", "sine")),
            ParamSpec("perturbation_amplitude", float, 0.0, "V",
                      "perturbation amplitude (uniform: +-a, sine: a)", 0.0, 1e4),
            ParamSpec("perturbation_frequency", float, 50.0, "Hz", "sine perturbation frequency", 0.0, 1e5),
            ParamSpec("seed", int, 1, "", "seed of the noise and perturbation generators", 0, 2**31 - 1),
            ParamSpec("command_delay", int, 1, "samples",
                      "the command computed from sample k is held over [t_k+d, t_k+d+1): d = 1 gives the graph a full "
                      "period to deliver it", 0, 8),
            ParamSpec("duration", float, 0.0, "s",
                      "graph: stop after this much simulated time (0: run until stopped)", 0.0, 1e7),
            ParamSpec("lockstep", bool, True, "",
                      "graph: wait for the command a sample needs (simulated clock may fall behind wall time); false: "
                      "free-running, hardware-like timing (a late command is held at most hold_timeout, then the board "
                      "lands the plate)"),
            ParamSpec("lockstep_timeout", float, 1.0, "s",
                      "lockstep: wait this long for a command, then the board lands the plate (a dead controller)",
                      1e-3, 600.0),
            ParamSpec("preroll", float, 1.0, "s",
                      "graph: levitate in closed loop this long before t = 0 (frame_id dem/preroll)", 0.0, 600.0),
            ParamSpec("start_delay", float, 3.0, "s",
                      "graph: wait at least this long after start-up before t = 0 (discovery)", 0.0, 600.0),
            ParamSpec("min_subscribers", int, 2, "",
                      "graph: wait (up to 30 s) until this many readers match /dem/measurement (estimator, reference)",
                      0, 100),
            COMMAND_SOURCE,
            *SAFETY_SPECS,
        ),
        "reference": (
            ParamSpec("b0", float, 0.25, "s^-3",
                      "reference model numerator, M(s) = b0/(s^3+a2 s^2+a1 s+a0) (Eq. 46)", 1e-9, 1e9),
            ParamSpec("a2", float, 2.0, "s^-1", "reference model denominator coefficient", 1e-9, 1e9),
            ParamSpec("a1", float, 1.25, "s^-2", "reference model denominator coefficient", 1e-9, 1e9),
            ParamSpec("a0", float, 0.25, "s^-3", "reference model denominator coefficient", 1e-9, 1e9),
            ParamSpec("initial", float, 0.008, "m", "command before the steps, both magnets", 1e-4, 0.1),
            ParamSpec("target_1", float, 0.005, "m", "command of magnet 1 after its step", 1e-4, 0.1),
            ParamSpec("target_2", float, 0.005, "m", "command of magnet 2 after its step", 1e-4, 0.1),
            ParamSpec("step_time_1", float, 1.0, "s", "time of the step of magnet 1", 0.0, 1e6),
            ParamSpec("step_time_2", float, 10.0, "s", "time of the step of magnet 2", 0.0, 1e6),
            ParamSpec("dt", float, 1e-3, "s", "sample period", 1e-5, 0.1, read_only=True),
        ),
        "estimator": (
            ParamSpec("type", str, "kf", "",
                      "state estimator: kf (Kalman filter on the plant model) or none (pass-through)",
                      choices=("kf", "none")),
            ParamSpec("sigma_gap", float, 1e-5, "m",
                      "gap sensor noise standard deviation assumed by the filter", 1e-9, 1.0),
            ParamSpec("sigma_rate", float, 1e-3, "m/s",
                      "gap-rate sensor noise standard deviation assumed by the filter", 1e-9, 100.0),
            ParamSpec("sigma_current", float, 1e-3, "A",
                      "current sensor noise standard deviation assumed by the filter", 1e-9, 100.0),
            ParamSpec("sigma_accel", float, 0.5, "m/s^2",
                      "process noise: per-sample (held) unmodelled acceleration, standard deviation", 1e-9, 1e3),
            ParamSpec("sigma_voltage", float, 1.0, "V",
                      "process noise: per-sample (held) unmodelled input voltage, standard deviation", 1e-9, 1e4),
            ParamSpec("sigma_bias", float, 30.0, "m/s^3",
                      "process noise: rate of the acceleration-bias random walk (sigma_bias T per sample)", 1e-9, 1e6),
            ParamSpec("sigma_voltage_bias", float, 20.0, "V/s",
                      "process noise: rate of the per-coil voltage-bias random walk (resistance error, heating, "
                      "driver offset)", 1e-9, 1e6),
            ParamSpec("voltage_bias_prior", float, 20.0, "V",
                      "initial standard deviation of the per-coil voltage bias (R tolerance x hover current)",
                      1e-9, 1e4),
            ParamSpec("gap_range_min", float, 0.0, "m",
                      "gap sensors' physical range: a reading at or below this is rejected (dead sensor; no gap "
                      "is <= 0)", -1.0, 1.0),
            ParamSpec("gap_range_max", float, 0.02, "m",
                      "gap sensors' physical range: a reading at or above this is rejected (saturated or disconnected; "
                      "the rig's ADC spans ~0-20 mm)", 1e-4, 10.0),
            ParamSpec("gate_false_alarm", float, 1e-5, "",
                      "chi^2 innovation gate on each gap: probability of rejecting a good sample (1e-5: NIS > 19.5, "
                      "4.4 sigma)", 1e-12, 0.5),
            ParamSpec("bias_max", float, 5.0, "m/s^2",
                      "an acceleration bias beyond this for fault_samples samples declares a gap sensor (stuck) or "
                      "load fault (5: an unknown load of +50 % of the module's mass)", 0.1, 1e4),
            ParamSpec("fault_samples", int, 20, "samples",
                      "this many rejected samples of one gap sensor in a row declare it faulty (latched; ERROR on "
                      "/diagnostics)", 1, 100000),
            ParamSpec("support_gap", float, _SAFETY_DEFAULTS["landing_gap"], "m",
                      "the plate rests on its support at or beyond this gap (default: the board's landing_gap; "
                      "hovering references lie below it): a hard stop in the filter's prediction "
                      "(core/estimator.py); 0: no support", 0.0, 1.0),
            ParamSpec("converge_samples", int, 30, "samples",
                      "gap rates not measured: after a (re)start the node publishes no estimate until this many "
                      "samples in a row passed the gates (the rate from the gaps settles in ~20; inside the board's "
                      "hold_timeout); rates measured: the start is the measurement, published once the next sample "
                      "confirms it (2 samples; core/estimator.py)", 1, 100000),
            ParamSpec("dt", float, 1e-3, "s", "sample period", 1e-5, 0.1, read_only=True),
            *_geometry("model "),
            ParamSpec("m", float, TABLE2["m"], "kg", "model mass used by the filter", 0.1, 1e4),
            ParamSpec("R", float, TABLE2["R"], "ohm", "model coil resistance used by the filter", 0.01, 1e4),
            ParamSpec("K", float, TABLE2["K"], "N*m^2/A^2", "model force coefficient used by the filter", 1e-7, 1.0),
        ),
        "controller": (
            ParamSpec("type", str, "adaptive", "", "control law", choices=_CONTROLLERS),
            ParamSpec("dt", float, 1e-3, "s", "control period", 1e-5, 0.1, read_only=True),
            ParamSpec("k1", float, 70.0, "s^-1", "error dynamics s^3+k1 s^2+k2 s+k3 (coefficient of e'')", 0.0, 1e6),
            ParamSpec("k2", float, 1600.0, "s^-2", "error dynamics coefficient of e'", 0.0, 1e9),
            ParamSpec("k3", float, 12000.0, "s^-3", "error dynamics coefficient of e", 0.0, 1e12),
            ParamSpec("coil_weight", float, 1.0, "",
                      "adaptive / adaptive_enhanced: weight of the coil equations u_j = R_j i_j + 2K d(i_j/delta_j)/dt "
                      "in the least squares, relative to the tracking error a coil-voltage misfit causes "
                      "(0: off)", 0.0, 1e6),
            ParamSpec("coil_bandwidth", float, 10.0, "rad/s",
                      "low-pass bw/(s + bw) of the coil equations' signals (no differentiated current; slow: averages "
                      "out unknown fast voltages such as a 50 Hz disturbance, which would bias R)", 0.1, 1e4),
            ParamSpec("ki", float, 10.0, "s^-1",
                      "integral action of adaptive / adaptive_enhanced: "
                      "error dynamics (s + ki)(s^3 + k1 s^2 + k2 s + k3) on int e (0: off)", 0.0, 1e4),
            *_geometry("model "),
            ParamSpec("m_init", float, 10.0, "kg", "initial mass estimate (paper: 10)", 0.1, 1e4),
            ParamSpec("R_init", float, 15.0, "ohm", "initial resistance estimate (paper: 15)", 0.01, 1e4),
            ParamSpec("K_init", float, 3.0618e-4, "N*m^2/A^2",
                      "initial force-coefficient estimate (docs/manual/model.md: 0.7 K)", 1e-7, 1.0),
            ParamSpec("m_nominal", float, TABLE2["m"], "kg",
                      "fixed mass of nonlinear_decoupling / decentralized_pid", 0.1, 1e4),
            ParamSpec("R_nominal", float, TABLE2["R"], "ohm",
                      "fixed resistance of nonlinear_decoupling / decentralized_pid", 0.01, 1e4),
            ParamSpec("K_nominal", float, TABLE2["K"], "N*m^2/A^2",
                      "fixed force coefficient of nonlinear_decoupling / decentralized_pid", 1e-7, 1.0),
            ParamSpec("m_min", float, 5.0, "kg", "lower bound of the mass estimate", 0.1, 1e4),
            ParamSpec("m_max", float, 50.0, "kg", "upper bound of the mass estimate", 0.1, 1e4),
            ParamSpec("R_min", float, 5.0, "ohm", "lower bound of the resistance estimate", 0.01, 1e4),
            ParamSpec("R_max", float, 60.0, "ohm", "upper bound of the resistance estimate", 0.01, 1e4),
            ParamSpec("K_min", float, 1e-4, "N*m^2/A^2", "lower bound of the force-coefficient estimate", 1e-7, 1.0),
            ParamSpec("K_max", float, 2e-3, "N*m^2/A^2", "upper bound of the force-coefficient estimate", 1e-7, 1.0),
            ParamSpec("P0_m", float, 1.0, "", "initial covariance of 1/m (scaled by its initial value)", 0.0, 1e12),
            ParamSpec("P0_R", float, 1.0, "", "initial covariance of R (scaled)", 0.0, 1e12),
            ParamSpec("P0_K", float, 0.1, "", "initial covariance of K (scaled)", 0.0, 1e12),
            ParamSpec("q_m", float, 10.0, "s^-1", "random-walk rate of the scaled 1/m (tracks load changes)", 0.0, 1e9),
            ParamSpec("q_R", float, 1.0, "s^-1", "random-walk rate of the scaled R (coil heating)", 0.0, 1e9),
            ParamSpec("q_K", float, 0.0, "s^-1", "random-walk rate of the scaled K", 0.0, 1e9),
            ParamSpec("P0_rho", float, 0.01, "",
                      "initial covariance of the coil-resistance difference rho = (R1 - R2)/2 (scaled by R_init)",
                      0.0, 1e12),
            ParamSpec("q_rho", float, 1.0, "s^-1",
                      "random-walk rate of the scaled rho (coils heating at different rates)", 0.0, 1e9),
            ParamSpec("rho_max", float, 10.0, "ohm",
                      "bound of |rho|, half the largest resistance difference of the coils", 0.0, 1e4),

            ParamSpec("hover_init", bool, True, "",
                      "initialise the estimates from the measured hover before start "
                      "(docs/manual/controllers.md A2 iv)"),
            ParamSpec("hover_window", float, 0.2, "s",
                      "hover initialisation: average this much of the pre-roll (the law holds the applied voltage "
                      "meanwhile)", 0.0, 60.0),
            ParamSpec("w", float, 50.0, "", "leakage weight of Eq. 48 (adaptive_enhanced)", 0.0, 1e9),
            ParamSpec("R0", float, 10.0, "s^-1",
                      "dead zone of Eq. 48: adapt only while ||dP/dt|| > R0 (adaptive_enhanced, deadzone=pdot)",
                      0.0, 1e12),
            ParamSpec("deadzone", str, "pdot", "",
                      "dead-zone rule of adaptive_enhanced", choices=("pdot", "error", "off")),
            ParamSpec("e0", float, 5e-6, "m", "dead zone on ||e_c|| (deadzone=error): noise bound", 0.0, 1.0),
            ParamSpec("gap_floor", float, 5e-4, "m",
                      "measured gaps are floored at this inside the control law", 1e-6, 0.01),
            ParamSpec("pid_kp", float, 850.3, "A/m", "decentralized_pid proportional gain (gap to current)", 0.0, 1e9),
            ParamSpec("pid_kd", float, 8.76, "A*s/m", "decentralized_pid derivative gain", 0.0, 1e9),
            ParamSpec("pid_ki", float, 4672.0, "A/(m*s)", "decentralized_pid integral gain", 0.0, 1e12),
            ParamSpec("pid_kc", float, 87.5, "V/A", "decentralized_pid inner current-loop gain", 0.0, 1e9),
            ParamSpec("command_delay", int, 1, "samples",
                      "samples between a measurement and the period its command is held over (the plant's "
                      "command_delay); the law predicts over it", 0, 8),
            ParamSpec("max_age", float, 0.002, "s",
                      "never act on an estimate older than this on the experiment clock (newest /dem/applied_voltage "
                      "stamp - its stamp), nor on one stamped this far ahead: (command_delay + 1) dt, beyond which its "
                      "command can no longer be applied (dem_ros.core.controllers.checks); "
                      "0: no stamp checks", 0.0, 10.0),
            ParamSpec("reference_gap_min", float, _SAFETY_DEFAULTS["trip_gap_min"], "m",
                      "a received reference gap below this is refused (the last good reference is held): the board's "
                      "trip_gap_min", 0.0, 0.1),
            ParamSpec("reference_gap_max", float, _SAFETY_DEFAULTS["landing_gap"], "m",
                      "a received reference gap above this is refused: the board's landing_gap, where the plate rests "
                      "on its support (it cannot hover beyond it, and the estimator treats a gap there as resting: "
                      "estimator.support_gap)", 1e-4, 1.0),
            ParamSpec("reference_max_speed", float, 1.55e-3, "m/s",
                      "a received reference faster than this (|y_d'|, or its gaps moving faster since the last "
                      "accepted one) is refused: (gap max - min)/2 ||h'||_1 of the reference model M(s), 1.54 mm/s for "
                      "the defaults (dem_ros.core.controllers.checks.reference_speed_bound)", 1e-6, 10.0),
            ParamSpec("voltage_limit", float, 1e4, "V",
                      "commands are clipped to +-min(this, u_max) before publishing", 0.0, 1e6),
            _LAW_U_MAX,
        ),
        "hw_driver": (
            ParamSpec("url", str, "udp://127.0.0.1:9870", "",
                      "device link: udp://HOST:PORT (the board's address) or serial:///dev/PATH[?baud=N]"),
            ParamSpec("dt", float, 1e-3, "s",
                      "the board's sample period (its hello must agree)", 1e-5, 0.1, read_only=True),
            ParamSpec("command_delay", int, 1, "samples",
                      "the board holds the command for sample k over [t_k+d, t_k+d+1) (the controller's command_delay)",
                      1, 8, read_only=True),
            *(
                ParamSpec(f"gap{j}_c{p}", float, _GAP_POLY[p], f"m/count^{p}" if p else "m",
                          f"gap sensor {j} calibration: gap = sum_p c_p n^p (n: ADC counts), coefficient of n^{p}",
                          -1e3, 1e3)
                for j in (1, 2) for p in range(4)
            ),
            ParamSpec("gap_table", str, "", "",
                      "CSV of 'counts, gap1_m, gap2_m' rows (interpolated) instead of the polynomials; "
                      "'' = polynomials"),
            ParamSpec("current1_gain", float, 10.0 / 32768, "A/count",
                      "coil current sensor 1: i = gain (n - offset)", -1e3, 1e3),
            ParamSpec("current1_offset", float, 32768.0, "count",
                      "coil current sensor 1: counts at zero current", -1e6, 1e6),
            ParamSpec("current2_gain", float, 10.0 / 32768, "A/count",
                      "coil current sensor 2: i = gain (n - offset)", -1e3, 1e3),
            ParamSpec("current2_offset", float, 32768.0, "count",
                      "coil current sensor 2: counts at zero current", -1e6, 1e6),
            ParamSpec("voltage_input", str, "volts", "",
                      "the link's voltage fields are volts, or duty ratios in [-1, 1] of the measured bus voltage",
                      choices=("volts", "duty")),
            # the board's limits, reused by the driver: commands clipped to u_max; a measured current above
            # i_max or a measured gap outside [trip_gap_min, trip_gap_max] for trip_samples samples trips
            # (the board lands); no controller command for hold_timeout (steady clock) -> fault, LAND
            *SAFETY_SPECS,
            # the board's nominal plant (its landing law and braking bound): with the limits, dt, command_delay and
            # the calibration above, the configuration the driver sends the board (docs/hardware-link.md, "Config")
            *_geometry("the board's nominal "),
            ParamSpec("m", float, TABLE2["m"], "kg", "the board's nominal mass of the suspended module (its landing "
                      "law and braking bound; sent in the link's CONFIG frame)", 0.1, 1e4),
            ParamSpec("R", float, TABLE2["R"], "ohm",
                      "the board's nominal coil resistance (its landing law's coil model)", 0.01, 1e4),
            ParamSpec("K", float, TABLE2["K"], "N*m^2/A^2", "the board's nominal force coefficient, F = K i^2/delta^2 "
                      "(its braking bound assumes the true K within +-25 %)", 1e-7, 1.0),
            COMMAND_SOURCE,
            ParamSpec("trip_samples", int, 3, "samples",
                      "consecutive out-of-limit samples that trip (a single spike is counted, not tripped on)",
                      1, 1000),
            ParamSpec("command_timeout", float, 0.0, "s",
                      "the driver's own command watchdog: active with no controller command this long -> fault, LAND;"
                      " 0: hold_timeout (which is also the board's: the driver sends it in the link's CONFIG frame)."
                      " Longer on a loaded host keeps the PC from faulting at the board's hold_timeout", 0.0, 10.0),
            ParamSpec("link_timeout", float, 0.05, "s",
                      "no sensor frame this long while active -> fault (the board's own watchdog lands it); while"
                      " armed, not yet active: a host stall, counted (stalls), the driver handshakes again",
                      1e-3, 10.0),
            ParamSpec("late_threshold", float, 1e-3, "s",
                      "a sensor frame received later than this after its sample is counted late", 1e-6, 1.0),
            ParamSpec("clock_sync_frames", int, 200, "",
                      "frames whose minimum (receive - board time) sets the fixed board -> ROS time offset", 1, 100000),
            ParamSpec("arm_samples", int, 200, "samples",
                      "armed -> active after this many consecutive controller commands in time (the loop proves itself "
                      "live before the board gets a command)", 1, 100000),
            ParamSpec("auto_arm", bool, False, "",
                      "arm at start-up (the launcher's emulated runs): the managed node goes on from inactive to active"
                      " once the board answered; false: wait for 'dem-ros hw arm' or a lifecycle activate"),
            ParamSpec("transition_timeout", float, 5.0, "s",
                      "a requested lifecycle transition that waits on the board fails after this: configure (its hello)"
                      " goes back to unconfigured, deactivate and shutdown (its LANDED) go through errorprocessing; the"
                      " start-up configure waits as long as it takes", 0.1, 600.0),
            ParamSpec("preroll", float, 1.0, "s",
                      "levitate in closed loop this long after becoming active before t = 0 (frame_id dem/preroll)",
                      0.0, 600.0),
            ParamSpec("duration", float, 0.0, "s",
                      "land and stop this long after t = 0 (0: run until stopped)", 0.0, 1e7),
        ),
        "rig": (
            ParamSpec("url", str, "udp://127.0.0.1:9870", "",
                      "dem-ros rig: where the emulated board listens: udp://HOST:PORT, or pty:// (a new "
                      "pseudo-terminal; its serial:// path is printed)"),
            ParamSpec("board_id", int, 1, "", "the board id its hello reports", 1, 2**31 - 1),
            ParamSpec("adc_bits", int, 16, "bits", "ADC resolution of the gap and current channels", 8, 16),
            ParamSpec("adc_vref", float, 10.0, "V", "ADC full-scale voltage (reported in the hello)", 0.1, 100.0),
            ParamSpec("gap_gain_error", float, 0.0, "",
                      "gap sensors: relative gain error against their data-sheet calibration", -0.5, 0.5),
            ParamSpec("gap_offset_error", float, 0.0, "m",
                      "gap sensors: offset error against their data-sheet calibration", -0.01, 0.01),
            ParamSpec("gap_curve", float, 0.0, "m",
                      "gap sensors: size of their nonlinearity against the data sheet over 4-12 mm, a different curve "
                      "per sensor (hardware/sensors.py; 0: none); dem-ros calibrate gaps finds it", 0.0, 1e-3),
            ParamSpec("gap_noise", float, 0.0, "m",
                      "gap sensors: Gaussian noise standard deviation (on top of the scenario's noise)", 0.0, 0.01),
            ParamSpec("current_noise", float, 0.0, "A",
                      "current sensors: Gaussian noise standard deviation (on top of the scenario's noise)", 0.0, 10.0),
            ParamSpec("pwm_bits", int, 16, "bits",
                      "coil drivers: PWM resolution (signed duty in steps of 2^-(bits-1)); the adaptive law has no "
                      "current loop: 12 bits at 200 V (0.1 V steps) limit-cycle at ~95 um RMS, 14 bits ~17 um, 16 bits "
                      "~4.5 um (S1 in lockstep)", 2, 24),
            ParamSpec("bus_voltage", float, 200.0, "V", "coil drivers: DC bus voltage without load", 0.0, 1e4),
            ParamSpec("bus_resistance", float, 0.5, "ohm",
                      "coil drivers: bus source resistance (sag = R_bus (|i1| + |i2|))", 0.0, 1e3),
            ParamSpec("bus_min", float, 100.0, "V", "below this the board reports bus undervoltage", 0.0, 1e4),
            ParamSpec("current_limit", float, 9.0, "A",
                      "coil drivers: hardware current limit (no positive voltage above it)", 0.0, 1e3),
            ParamSpec("support_gap", float, 0.0112, "m",
                      "the plate's mechanical support: gaps never exceed it", 1e-3, 0.1),
            ParamSpec("start", str, "hover", "",
                      "hover: clamped at the scenario's hover until the first RUN command; landed: on the support, "
                      "no current", choices=("hover", "landed")),
            ParamSpec("seed", int, 7, "", "seed of the rig's sensor noise and frame corruption", 0, 2**31 - 1),
            ParamSpec("board", str, "python", "",
                      "the board's safety supervisor: python (dem_ros.board) or c (the firmware, "
                      "firmware/supervisor.c, built on the host at first use)", choices=("python", "c")),
        ),
    },
    checks={
        "plant_sim": (_check_plant, _check_safety, _check_command_source),
        "reference": (_check_reference,),
        "estimator": (_check_geometry, _check_gap_range),
        "controller": (_check_geometry, _check_hurwitz, _check_bounds, _check_controller_safety),
        "hw_driver": (_check_safety, _check_geometry, _check_command_source),
    },
)


def with_board_limit(cfg: Mapping[str, Mapping[str, Any]], board: str = "plant_sim") -> dict[str, dict[str, Any]]:
    """A copy of ``cfg`` whose ``controller.u_max`` is the board's (``board``: the group of the node that drives the
    coils, ``plant_sim`` or ``hw_driver``): the law clips where the board does (one limit, one place)."""
    out = {g: dict(v) for g, v in cfg.items()}
    out["controller"]["u_max"] = out[board]["u_max"]
    return out


def default_config() -> dict[str, dict[str, Any]]:
    """All groups at their schema defaults."""
    return {g: SCHEMA.defaults(g) for g in SCHEMA.groups}


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file; ConfigError naming the file when it cannot be read or parsed.

    Also refused: text that is not UTF-8 (a binary file) and a key repeated in
    one mapping (YAML would silently keep the last one).
    """
    path = Path(path)
    import yaml

    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}: {raw[exc.start]:#04x}); a binary file?") from None
    try:
        return yaml.load(text, Loader=_unique_key_loader())  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    except (ValueError, TypeError, RecursionError) as exc:  # e.g. a malformed !!timestamp, unhashable key
        raise ConfigError(f"{path}: not valid YAML ({type(exc).__name__}: {exc})") from None


@functools.cache
def _unique_key_loader() -> type:
    import yaml

    class Loader(yaml.SafeLoader):
        """SafeLoader that refuses a key repeated in one mapping (the second would win silently)."""

        def construct_mapping(self, node: Any, deep: bool = False) -> Any:
            if isinstance(node, yaml.MappingNode):
                seen: dict[Any, Any] = {}
                for key_node, _ in node.value:
                    key = self.construct_object(key_node, deep=True)
                    try:
                        first = seen.setdefault(key, key_node)
                    except TypeError:
                        continue  # unhashable: the base class reports it
                    if first is not key_node:
                        raise yaml.constructor.ConstructorError(
                            "while constructing a mapping", node.start_mark,
                            f"found duplicate key {key!r} (first at line {first.start_mark.line + 1})",
                            key_node.start_mark)
            return super().construct_mapping(node, deep=deep)

    return Loader


def _flatten(prefix: str, tree: Mapping[str, Any]) -> dict[str, Any]:
    """ROS params files nest dotted names: {a: {b: 1}} -> {'a.b': 1}."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(key + ".", v))
        else:
            out[key] = v
    return out


def params_from_tree(tree: Any, source: str) -> dict[str, dict[str, Any]]:
    """Extract ``{group: {name: value}}`` from a parsed ROS 2 params file.

    Accepts node keys with or without a leading slash or namespace
    (``controller``, ``/controller``, ``/dem/controller``) and the wildcard
    ``/**`` (applied to every group, for the names the group knows).
    """
    if tree is None:
        return {}
    if not isinstance(tree, Mapping):
        raise ConfigError(f"{source}: expected a mapping of node names to 'ros__parameters'")
    out: dict[str, dict[str, Any]] = {}
    wildcard: dict[str, Any] = {}
    for node_key, body in tree.items():
        if not isinstance(body, Mapping) or "ros__parameters" not in body:
            raise ConfigError(f"{source}: entry {node_key!r} has no 'ros__parameters' mapping")
        extra = [k for k in body if k != "ros__parameters"]
        if extra:
            raise ConfigError(f"{source}: {node_key}: unknown key {extra[0]!r} beside 'ros__parameters'")
        params = body["ros__parameters"]
        if not isinstance(params, Mapping):
            raise ConfigError(f"{source}: {node_key}.ros__parameters must be a mapping")
        flat = _flatten("", params)
        name = str(node_key).rstrip("/").split("/")[-1]
        if name in ("**", "*"):
            wildcard.update(flat)
            continue
        if name not in SCHEMA.groups:
            raise ConfigError(f"{source}: unknown node {node_key!r}; known: {', '.join(SCHEMA.groups)}")
        for k in flat:
            if k not in {p.name for p in SCHEMA.groups[name]}:
                raise ConfigError(f"{source}: {node_key}: unknown parameter {k!r}; {name} declares: "
                                  + ", ".join(p.name for p in SCHEMA.groups[name]))
        out.setdefault(name, {}).update(flat)
    for k in wildcard:  # a wildcard name no node declares is a typo, not "for some other node"
        if not any(k == p.name for specs in SCHEMA.groups.values() for p in specs):
            raise ConfigError(f"{source}: /**: unknown parameter {k!r}; no node declares it")
    for group in SCHEMA.groups:
        known = {p.name for p in SCHEMA.groups[group]}
        for k, v in wildcard.items():
            if k in known:
                out.setdefault(group, {}).setdefault(k, v)
    return out


def load_params_file(path: str | Path,
                     base: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """Load and validate a ROS 2 params file on top of ``base`` (default: schema defaults)."""
    path = Path(path)
    overrides = params_from_tree(read_yaml(path), str(path))
    return apply_overrides(base or default_config(), overrides, str(path))


def apply_overrides(
    base: Mapping[str, Mapping[str, Any]],
    overrides: Mapping[str, Mapping[str, Any]],
    source: str = "overrides",
) -> dict[str, dict[str, Any]]:
    """Return a validated copy of ``base`` with ``overrides`` applied, group by group."""
    cfg = {g: dict(v) for g, v in base.items()}
    for group, values in overrides.items():
        if group not in SCHEMA.groups:
            raise ConfigError(f"{source}: unknown group {group!r}; known: {', '.join(SCHEMA.groups)}")
        for name in values:
            SCHEMA.spec(group, name)  # unknown names fail with the known list
        try:
            cfg[group] = SCHEMA.merged(group, cfg[group], values)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
    for group in SCHEMA.groups:
        cfg[group] = SCHEMA.validate_group(group, cfg[group])
    return cfg


def parse_assignment(text: str, default_group: str = "controller") -> tuple[str, str, Any]:
    """Parse ``k1=60`` or ``plant_sim.m=16`` (YAML-typed value) into (group, name, value)."""
    import yaml

    if "=" not in text:
        raise ConfigError(f"{text!r}: expected NAME=VALUE, e.g. k1=60 or plant_sim.m=16")
    key, raw = text.split("=", 1)
    group, _, name = key.strip().rpartition(".")
    group = group or default_group
    if group not in SCHEMA.groups:
        raise ConfigError(f"{text!r}: unknown group {group!r}; known: {', '.join(SCHEMA.groups)}")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        value = raw
    spec = SCHEMA.spec(group, name)
    return group, name, spec.coerce(value, f"{group}.{name}")

