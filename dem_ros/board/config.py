"""The board's configuration: which schema values it reads, its tuning constants, and the parameter vector
its numba kernels share (docs/manual/board.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..core.model import gap_weights
from ..core.params import SAFETY_SPECS
from .modes import SafetyError

__all__ = [
    "BIAS_BANDWIDTH",
    "BOUND_MARGIN",
    "CURRENT_BANDWIDTH",
    "HOLD_DESCENT_FRACTION",
    "HOLD_GUARD_AFTER",
    "HOLD_RISE_FRACTION",
    "HOLD_SPEEDUP_FRACTION",
    "INNOVATION_LIMIT",
    "LANDING_OVERSHOOT",
    "OBS_BANDWIDTH",
    "OUTER_BANDWIDTH",
    "PLANT_KEYS",
    "REF_ACCEL",
    "SAFETY_KEYS",
    "SENSOR_BLIND_SAMPLES",
    "SPEED_FRACTION",
    "hold_guard_text",
    "kernel_vector",
]

#: the safety specs (core/params.py ``SAFETY_SPECS``) a Supervisor reads from its cfg
SAFETY_KEYS = tuple(spec.name for spec in SAFETY_SPECS)
#: nominal plant parameters a Supervisor reads from its cfg
PLANT_KEYS = ("m", "R", "K", "L", "l", "I", "N1", "N2", "g")

OUTER_BANDWIDTH = 30.0  # rad/s, w of the landing law's gap loop
OBS_BANDWIDTH = 150.0  # rad/s, observer error poles of gap and rate at exp(-w_obs T)
BIAS_BANDWIDTH = 30.0  # rad/s, observer error pole of the missed acceleration (slower: less noise)
CURRENT_BANDWIDTH = 500.0  # 1/s, current loop gain kc (kc T = 0.5: fast against the plate, slow against the sample)
SPEED_FRACTION = 0.4  # the reference descends at this fraction of landing_speed (margin for noise)
REF_ACCEL = 0.2  # m/s^2, the reference's acceleration to v_ref
CAPTURE_ACCEL = 5.0  # m/s^2, the reference's largest deceleration of a plate rising when the landing starts
CAPTURE_TIME = 0.01  # s: it decelerates a rising plate's speed v at |v| / CAPTURE_TIME (at least REF_ACCEL)
# the hold's speed guard (docs/manual/board.md, "Modes", HOLD): a held plate whose estimated rate at either end
# exceeds these fractions of landing_speed (descending, rising) lands at once instead of being held on
HOLD_DESCENT_FRACTION = 0.7  # the rest of landing_speed: the observer's lag and the law's reaction (measured)
HOLD_RISE_FRACTION = 1.0  # a rising plate is captured by the landing law; above the rate noise of S3c's sensors
HOLD_SPEEDUP_FRACTION = 0.5  # ... each only once the plate moves this much faster that way than at the hold's first
#                              sample: a plate the controller moves fast is held through a late command like any
#                              other; what lands is a plate the held voltage speeds up
HOLD_GUARD_AFTER = 3.0 / BIAS_BANDWIDTH  # s: the guard acts once the observer has run this long (its slowest
#                                            pole, three time constants: its start-up transient is not a motion)


def hold_guard_text(rise: float, descent: float) -> str:
    """The hold's speed guard in words, from its limits [m/s] (rise negative, up): both boards' landing reason."""
    gain = descent * HOLD_SPEEDUP_FRACTION / HOLD_DESCENT_FRACTION
    return (f"a held plate lands descending beyond {descent * 1e3:g} mm/s or rising beyond {-rise * 1e3:g} mm/s, "
            f"{gain * 1e3:g} mm/s faster than at its hold's start")


LANDING_OVERSHOOT = 3e-4  # m: the reference stops this far beyond landing_gap (the support)
I_OFF = 0.02  # A: below this, LANDED applies 0 V
BOUND_MARGIN = 0.25  # the braking bound's model margin e: K, 1/m, 1/I each within a factor 1 -+ e
INNOVATION_LIMIT = 5e-4  # m: a single sample this far off the observer's prediction is set aside as wild
R_LEARN_TIME = 0.05  # s: the coil model learns each coil's resistance with this time constant
SENSOR_BLIND_SAMPLES = 5  # samples a gap/current channel may give nothing finite before the board lands
FLUX_GAP_MIN_CURRENT = 0.5  # A: below this a coil's flux tells too little of its gap (a lost gap sensor: FAULT)
SENSOR_NAMES = ("gap sensor 1", "gap sensor 2", "current sensor 1", "current sensor 2")
# the gap sensors' plausibility against the coils' fluxes (docs/manual/board.md, "A plausible but wrong gap reading")
FLUX_CHECK_TIME = 0.05  # s: the flux estimate follows the measured flux 2K i/delta with this time constant
FLUX_CHECK_R_TIME = 0.2  # s: its coil resistance follows the coil model's (R_LEARN_TIME) this slowly, and only
#                            while the differences are small (the coil model's follows a wrong reading in 50 ms)
FLUX_CHECK_ARM = 0.3  # s: valid samples before a coil's check counts (the flux estimate settles)
FLUX_CHECK_FILTER = 0.003  # s: low-pass of the gap differences
FLUX_CHECK_NOISE_TIME = 1.0  # s: the differences' noise level is learned over this time
FLUX_CHECK_MIN = 3e-4  # m: the smallest difference that counts
FLUX_CHECK_SIGMAS = 6.0  # the tolerance is at least this many times the learned noise level
FLUX_CHECK_SETTLE = 50  # samples: the check arms after this many in a row with both differences small
FLUX_CHECK_SAMPLES = 3  # samples in a row beyond the tolerance declare the sensor implausible

# the kernels' parameter vector p (one layout for observer, landing law, braking bound)
_P, _Q, _A, _B, _C, _D, _K, _R, _N1, _N2, _G = range(11)  # the nominal model (Eqs. 4, 7)
_T, _KP, _KD, _KC, _UMAX, _ILIM, _DMIN, _VREF, _AREF, _RSTOP, _KI = range(11, 22)  # the landing law
_KB, _AB, _BB, _NB1, _NB2 = range(22, 27)  # the braking bound's widened model (docs/manual/board.md)
_EMAX = 27  # observer innovation limit [m]
_KBL = 28  # the braking bound's weakest magnet (1 - e) K
_ACAP = 29  # the landing reference's largest deceleration of a rising plate [m/s^2]
_TCAP = 30  # ... at |r'| / CAPTURE_TIME [s]
_NP = 31


def kernel_vector(cfg: Mapping[str, Any], dt: float) -> tuple[dict[str, float], np.ndarray]:
    """Validate the board's configuration and build its kernels' parameter vector.

    Args:
        cfg: the safety specs (``SAFETY_KEYS``, SI units) and the nominal plant parameters (``PLANT_KEYS``);
            extra keys are ignored.
        dt: sample period T [s].

    Returns:
        (c, p): the values read, as floats, and p (_NP,) in the layout above.

    Raises:
        SafetyError: a missing, non-numeric or inconsistent value (the message names it).
    """
    missing = [k for k in SAFETY_KEYS + PLANT_KEYS if k not in cfg]
    if missing:
        raise SafetyError(f"supervisor configuration lacks {missing}")
    try:
        c = {k: float(cfg[k]) for k in SAFETY_KEYS + PLANT_KEYS}
    except (TypeError, ValueError):
        bad = {k: cfg[k] for k in SAFETY_KEYS + PLANT_KEYS if not isinstance(cfg[k], (int, float))}
        raise SafetyError(f"supervisor configuration: not numbers: {bad}") from None
    for k in ("u_max", "i_max", "hold_timeout", "landing_gap", "landing_speed", "m", "R", "K", "L", "l", "I"):
        if not (math.isfinite(c[k]) and c[k] > 0):
            raise SafetyError(f"{k} = {c[k]!r} must be a positive finite number")
    if not 0 <= c["trip_gap_min"] < c["landing_gap"] <= c["trip_gap_max"]:
        raise SafetyError(
            f"need 0 <= trip_gap_min < landing_gap <= trip_gap_max; got {c['trip_gap_min']:g}, "
            f"{c['landing_gap']:g}, {c['trip_gap_max']:g} m")
    if not c["l"] < c["L"]:
        raise SafetyError(f"l = {c['l']:g} m must be smaller than L = {c['L']:g} m")
    if not (math.isfinite(dt) and dt > 0):
        raise SafetyError(f"dt = {dt!r} must be a positive finite number [s]")
    L, l, m, In = c["L"], c["l"], c["m"], c["I"]
    p = np.zeros(_NP)
    p[_P], p[_Q] = gap_weights(L, l)
    p[_A] = 1 / m + L * l / In
    p[_B] = 1 / m - L * l / In
    p[_C] = 1 / m + L * L / In
    p[_D] = 1 / m - L * L / In
    p[_K], p[_R], p[_N1], p[_N2], p[_G] = c["K"], c["R"], c["N1"], c["N2"], c["g"]
    p[_T] = dt
    p[_KP] = OUTER_BANDWIDTH**2
    p[_KD] = 2.0 * OUTER_BANDWIDTH
    p[_KC] = CURRENT_BANDWIDTH
    p[_UMAX] = c["u_max"]
    p[_ILIM] = 0.95 * c["i_max"]
    p[_DMIN] = 1e-4
    p[_VREF] = SPEED_FRACTION * c["landing_speed"]
    p[_AREF] = REF_ACCEL
    p[_ACAP] = CAPTURE_ACCEL
    p[_TCAP] = CAPTURE_TIME
    p[_RSTOP] = c["landing_gap"] + LANDING_OVERSHOOT
    p[_KI] = CURRENT_BANDWIDTH**2 / 5.0
    e = BOUND_MARGIN
    p[_EMAX] = INNOVATION_LIMIT
    p[_KB] = (1 + e) * c["K"]
    p[_KBL] = (1 - e) * c["K"]
    p[_AB] = (1 + e) * (1 / m + L * l / In)
    p[_BB] = max((1 + e) / m - (1 - e) * L * l / In, 0.0)
    p[_NB1] = c["g"] + min(0.0, (1 + e) * L * L / In * (c["N1"] - c["N2"]))
    p[_NB2] = c["g"] + min(0.0, (1 + e) * L * L / In * (c["N2"] - c["N1"]))
    if not min(p[_NB1], p[_NB2]) > 0:
        raise SafetyError(f"no braking away from the rail: with N1 = {c['N1']:g} N, N2 = {c['N2']:g} N the pull "
                          f"away from the rail at the ends is {p[_NB1]:.3g}, {p[_NB2]:.3g} m/s^2 (must be > 0)")
    return c, p
