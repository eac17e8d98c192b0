r"""The coil driver's safety supervisor: the board's hard limits, command watchdog and safe landing.

A plate must never hit the rail because of software, so the limits live where the
hardware is: in the board that drives the coils (the simulated board of ``plant_sim``
and the rig emulator's board of ``hw_driver`` both run this class), never in the
controller. Pure Python + numba, no middleware.

Modes (:class:`Mode`, the values of the device link's mode byte)::

    OFF --fresh command--> RUN --no fresh command--> HOLD --held > hold_timeout--> LAND --gaps >= landing_gap--> LANDED
                           RUN <--fresh command----- HOLD
    RUN/HOLD --limit trip, estop(), land(), requested LAND/OFF--> LAND        (latched)
    any --non-finite sensor--> FAULT (0 V: nothing left to control with)     (latched)
    LAND/LANDED/FAULT --clear()--> OFF

* **RUN**: the applied voltage is the command clipped to ``[-u_max, u_max]`` (the
  coil driver's bus; counted in ``clipped``). A coil current above ``i_max`` or a
  load-point gap outside ``[trip_gap_min, trip_gap_max]`` (on the observer's
  estimate, so sensor noise alone does not trip) latches a fault and lands.
* **HOLD**: a sample without a fresh command (late, lost, non-finite) holds the
  last applied voltage. Holding the voltage of an unstable plant is a small
  perturbation for a few samples only: with the voltages held the DEM has two real
  poles at +47..+62 rad/s (notes: hardware-and-realtime), a deviation grows by e
  every 17-20 ms. ``hold_timeout`` bounds it (default 50 ms: x ~15); then LAND.
* **LAND**: the landing law below lowers the plate away from the rail (a larger
  gap; y is positive down, ``dem_ros.core.model``) to ``landing_gap`` at no more
  than ``landing_speed``; commands are ignored until ``clear()``.
* **LANDED**: the plate is on its support at ``landing_gap``; the current is
  driven to zero (a 0 V cut is safe only here, never at hover).
* **FAULT**: a non-finite gap or current: the board cannot control, 0 V.

Faults latch with a reason (``fault``); ``reason`` explains the current mode;
``counters`` count samples and events (``holds``, ``hold_events``, ``clipped``,
``rejected``, ``landings``, ``trips``, ``estops``, ``landed``) and keep ``longest_hold_us``
(the longest hold that ended without a landing, or is still going).

The landing law (uses only what a board has: measured gaps y (2,) [m] and coil
currents i (2,) [A], nominal parameters m, R, K, L, l, I, N1, N2, g)
-----------------------------------------------------------------------------
Per load point j, the model acceleration at the measured currents (Eqs. 3-8)::

    delta = [P y1 + Q y2, Q y1 + P y2]          F_j = K i_j^2 / delta_j^2
    a_m   = n - M F,   M = [[A, B], [B, A]],   n = [C N1 + D N2 + g, D N1 + C N2 + g]

1. *Observer* (runs in every mode, so LAND starts from converged estimates): per load
   point the states ``s = [p, v, b]`` (gap [m], gap rate [m/s], acceleration the
   nominal model misses [m/s^2]: mass, K, R errors, added load)::

       predict:  p- = p + T v + T^2/2 (a_m + b),  v- = v + T (a_m + b),  b- = b
       correct:  s  = s- + Lo (y - p-)

   ``Lo`` (3,) places the error poles of (I - Lo C) A at exp(-w_obs T) (double,
   ``OBS_BANDWIDTH``) and exp(-w_b T) (``BIAS_BANDWIDTH``, slower: b is a second
   derivative of the sensor noise); b makes v unbiased under constant model errors
   and is the disturbance the outer loop cancels. At LAND entry b already holds
   the hover's model error, so the transfer is bumpless.
2. *Reference*: from the estimate at LAND entry, r_j accelerates at ``REF_ACCEL`` to
   ``v_ref = SPEED_FRACTION * landing_speed`` (down, away from the rail) and stops
   ``LANDING_OVERSHOOT`` beyond ``landing_gap`` (each load point: a tilted plate
   levels on the way); it starts with the plate's own downward speed (clipped to
   [0, v_ref]). SPEED_FRACTION = 0.4 leaves the rest of the bound to the motion the
   sensor noise drives through the loop (measured: tests).
3. *Outer loop* (disturbance-observer feedback linearisation)::

       a*_j = r''_j + kd (r'_j - v_j) + kp (r_j - p_j),   kp = w^2, kd = 2 w  (w = OUTER_BANDWIDTH)
       F*   = M^-1 (n - a*_j + b),  clipped to [0, K i_lim^2/delta^2]     (attraction only)
       i*_j = delta_j sqrt(F*_j / K)

4. *Current loop* (inverts u = R i + d(2K i/delta)/dt)::

       u_j = R i_j + ui_j + (2K/delta_j) (kc (i*_j - i_j) - i_j delta_j'/delta_j),   kc = CURRENT_BANDWIDTH
       ui_j += T (kc^2/5) (2K/delta_j) (i*_j - i_j)     (integral: the R error; frozen while saturated)

   clipped to ``u_max``; ui starts at (last applied voltage - R i) so the voltage does not jump. The plate reaches its support (min(p) >= landing_gap) at
   about v_ref; LANDED then drives the currents to zero with the same loop (i* = 0).

With w = 30 rad/s, w_obs = 150 rad/s, w_b = 30 rad/s, kc = 500 /s at T = 1 ms, the law lands from
hovers at 4-10 mm, tilted, with m, R, K off by +-25 %, 3 kg added and measurement
noise (+-30 um, +-0.3 mA), descending at <= landing_speed and never closer to the rail
than it started (tests/core/test_safety.py); with +-100 um gap noise the noise-driven
motion takes the peak descent speed to 0.94-1.17 landing_speed (measured; tested <= 1.5).
It needs the bus to hold the plate near ``landing_gap``: R i <= u_max with
i = (landing_gap + LANDING_OVERSHOOT) sqrt((N + m g/2)/K) (nominal: 113 V at 11.3 mm;
the 200 V default covers m +25 % and +3 kg, R +25 %, K -25 % all at once: 186 V).

Names refined from PLAN.md: the gap trips are ``trip_gap_min``/``trip_gap_max`` (the
plant_sim group already has ``gap_min``/``gap_max``: the plant's failure limits);
``Supervisor(cfg, dt, mode=Mode.OFF, u0=None)``; attributes ``fault`` (latched reason),
``u`` and ``estimate`` and method ``snapshot()`` are additions.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "BIAS_BANDWIDTH",
    "CURRENT_BANDWIDTH",
    "LANDING_OVERSHOOT",
    "OBS_BANDWIDTH",
    "OUTER_BANDWIDTH",
    "PLANT_KEYS",
    "REF_ACCEL",
    "SAFETY_KEYS",
    "SPEED_FRACTION",
    "Mode",
    "SafetyError",
    "Supervisor",
    "observer_gains",
]

#: the safety specs (core/params.py ``SAFETY_SPECS``) a Supervisor reads from its cfg
SAFETY_KEYS = ("u_max", "i_max", "trip_gap_min", "trip_gap_max", "hold_timeout", "landing_gap", "landing_speed")
#: nominal plant parameters a Supervisor reads from its cfg
PLANT_KEYS = ("m", "R", "K", "L", "l", "I", "N1", "N2", "g")

OUTER_BANDWIDTH = 30.0  # rad/s, w of the landing law's gap loop
OBS_BANDWIDTH = 150.0  # rad/s, observer error poles of gap and rate at exp(-w_obs T)
BIAS_BANDWIDTH = 30.0  # rad/s, observer error pole of the missed acceleration (slower: less noise)
CURRENT_BANDWIDTH = 500.0  # 1/s, current loop gain kc (kc T = 0.5: fast against the plate, slow against the sample)
SPEED_FRACTION = 0.4  # the reference descends at this fraction of landing_speed (margin for noise)
REF_ACCEL = 0.2  # m/s^2, the reference's acceleration to v_ref
LANDING_OVERSHOOT = 3e-4  # m: the reference stops this far beyond landing_gap (the support)
I_OFF = 0.02  # A: below this, LANDED applies 0 V


class Mode(enum.IntEnum):
    """Board mode; the values are the device link's mode byte (``dem_ros.hardware.link`` imports this)."""

    OFF = 0  # no current in the coils (plate resting on its support, or not started)
    RUN = 1  # applying the commanded voltages, clipped to u_max
    HOLD = 2  # a command is late: the last one is held, at most hold_timeout
    LAND = 3  # the landing law lowers the plate away from the rail at <= landing_speed (also after a trip or e-stop)
    LANDED = 4  # on the support at landing_gap, current removed
    FAULT = 5  # a non-finite gap or current: nothing left to control with, 0 V (latched)


class SafetyError(ValueError):
    """An invalid supervisor configuration; the message names the field."""


def observer_gains(T: float, w: float, w_bias: float) -> np.ndarray:
    """Lo (3,) of the current-estimator form: the eigenvalues of (I - Lo C) A are exp(-w T) (double)
    and exp(-w_bias T) (the missed-acceleration estimate, slower: it is a second derivative of noise).

    A = [[1, T, T^2/2], [0, 1, T], [0, 0, 1]], C = [1, 0, 0]. Ackermann on the pair
    (A, C A): Lo = phi(A) [CA; CA^2; CA^3]^-1 e3, phi(z) = (z - exp(-w T))^2 (z - exp(-w_bias T)).
    """
    A = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    C = np.array([[1.0, 0.0, 0.0]])
    lam = math.exp(-w * T)
    lam_b = math.exp(-w_bias * T)
    eye = np.eye(3)
    phi = (A - lam * eye) @ (A - lam * eye) @ (A - lam_b * eye)
    O = np.vstack([C @ A, C @ A @ A, C @ A @ A @ A])
    return (phi @ np.linalg.solve(O, np.array([0.0, 0.0, 1.0]))).ravel()


# kernel parameter vector
_P, _Q, _A, _B, _C, _D, _K, _R, _N1, _N2, _G, _T, _KP, _KD, _KC, _UMAX, _ILIM, _DMIN, _VREF, _AREF, _RSTOP, _KI = range(22)
_NP = 22


@njit(cache=True)
def _model_accel(p: np.ndarray, de1: float, de2: float, i1: float, i2: float, a: np.ndarray) -> None:
    """a = n - M F at gaps delta and currents i (nominal model)."""
    F1 = p[_K] * i1 * i1 / (de1 * de1)
    F2 = p[_K] * i2 * i2 / (de2 * de2)
    a[0] = p[_C] * p[_N1] + p[_D] * p[_N2] + p[_G] - p[_A] * F1 - p[_B] * F2
    a[1] = p[_D] * p[_N1] + p[_C] * p[_N2] + p[_G] - p[_B] * F1 - p[_A] * F2


@njit(cache=True)
def _deltas(p: np.ndarray, y1: float, y2: float) -> tuple[float, float]:
    de1 = max(p[_P] * y1 + p[_Q] * y2, p[_DMIN])
    de2 = max(p[_Q] * y1 + p[_P] * y2, p[_DMIN])
    return de1, de2


@njit(cache=True)
def _observe(p: np.ndarray, Lo: np.ndarray, s: np.ndarray, a: np.ndarray, y0: float, y1: float, i0: float,
             i1: float) -> None:
    """One observer step. s (3, 2): [p, v, b] per load point; a (2,): model acceleration of the last step (updated)."""
    T = p[_T]
    for j in range(2):
        acc = a[j] + s[2, j]
        pp = s[0, j] + T * s[1, j] + 0.5 * T * T * acc
        vp = s[1, j] + T * acc
        e = (y0 if j == 0 else y1) - pp
        s[0, j] = pp + Lo[0] * e
        s[1, j] = vp + Lo[1] * e
        s[2, j] = s[2, j] + Lo[2] * e
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    _model_accel(p, de1, de2, i0, i1, a)


@njit(cache=True)
def _land_law(p: np.ndarray, s: np.ndarray, ref: np.ndarray, ui: np.ndarray, i: np.ndarray, landed: bool,
              u: np.ndarray) -> None:
    """Voltages u (2,) of the landing law.

    ref (3, 2) = [r, r', r''] per load point and ui (2,) the current loop's integral [V] are advanced here.
    """
    T = p[_T]
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    dd1 = p[_P] * s[1, 0] + p[_Q] * s[1, 1]
    dd2 = p[_Q] * s[1, 0] + p[_P] * s[1, 1]
    istar1 = 0.0
    istar2 = 0.0
    if not landed:
        a1 = ref[2, 0] + p[_KD] * (ref[1, 0] - s[1, 0]) + p[_KP] * (ref[0, 0] - s[0, 0])
        a2 = ref[2, 1] + p[_KD] * (ref[1, 1] - s[1, 1]) + p[_KP] * (ref[0, 1] - s[0, 1])
        h1 = p[_C] * p[_N1] + p[_D] * p[_N2] + p[_G] - a1 + s[2, 0]  # M F* = n - a* + b
        h2 = p[_D] * p[_N1] + p[_C] * p[_N2] + p[_G] - a2 + s[2, 1]
        det = p[_A] * p[_A] - p[_B] * p[_B]
        F1 = (p[_A] * h1 - p[_B] * h2) / det
        F2 = (-p[_B] * h1 + p[_A] * h2) / det
        F1 = min(max(F1, 0.0), p[_K] * p[_ILIM] * p[_ILIM] / (de1 * de1))
        F2 = min(max(F2, 0.0), p[_K] * p[_ILIM] * p[_ILIM] / (de2 * de2))
        istar1 = de1 * math.sqrt(F1 / p[_K])
        istar2 = de2 * math.sqrt(F2 / p[_K])
        # the reference descends (r'' = a_ref up to r' = v_ref) and stops at r_stop
        for j in range(2):
            ref[0, j] += T * ref[1, j] + 0.5 * T * T * ref[2, j]
            ref[1, j] += T * ref[2, j]
            if ref[1, j] >= p[_VREF]:
                ref[1, j] = p[_VREF]
                ref[2, j] = 0.0
            if ref[0, j] >= p[_RSTOP]:
                ref[0, j] = p[_RSTOP]
                ref[1, j] = 0.0
                ref[2, j] = 0.0
    else:
        ui[0] = 0.0
        ui[1] = 0.0
    kK = 2.0 * p[_K]
    e1 = istar1 - i[0]
    e2 = istar2 - i[1]
    u[0] = p[_R] * i[0] + ui[0] + kK / de1 * (p[_KC] * e1 - i[0] * dd1 / de1)
    u[1] = p[_R] * i[1] + ui[1] + kK / de2 * (p[_KC] * e2 - i[1] * dd2 / de2)
    for j in range(2):
        lim = p[_UMAX]
        if u[j] > lim:
            u[j] = lim
        elif u[j] < -lim:
            u[j] = -lim
        elif not landed:  # integrate only when not saturated (anti-windup)
            e = e1 if j == 0 else e2
            de = de1 if j == 0 else de2
            ui[j] += T * p[_KI] * kK / de * e


class Supervisor:
    """The board: hard limits, command watchdog, landing law (see the module docstring).

    Args:
        cfg: the safety specs (``SAFETY_KEYS``, SI units) and the nominal plant
            parameters (``PLANT_KEYS``); extra keys are ignored.
        dt: sample period T [s].
        mode: the mode to start in; ``Mode.RUN`` when the plate already hovers
            under a voltage given as ``u0`` (2,) [V] (the simulator's initial hover).

    Attributes:
        mode: current :class:`Mode`.
        reason: why the supervisor is in this mode ("" in OFF/RUN).
        fault: the latched fault reason ("" when none), cleared by ``clear()``.
        counters: sample and event counts (see the module docstring).
        u (2,): the voltages applied by the last ``step`` [V] (the array ``step`` returned;
            the board may return it again, never changes it in place).
        estimate (3, 2): observer state [gap m, rate m/s, missed acceleration m/s^2] per load point.
    """

    def __init__(self, cfg: Mapping[str, Any], dt: float, mode: Mode = Mode.OFF, u0: np.ndarray | None = None):
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
        self.cfg = c
        self.dt = float(dt)
        L, l, m, In = c["L"], c["l"], c["m"], c["I"]
        p = np.zeros(_NP)
        p[_P] = (L + l) / (2 * L)
        p[_Q] = (L - l) / (2 * L)
        p[_A] = 1 / m + L * l / In
        p[_B] = 1 / m - L * l / In
        p[_C] = 1 / m + L * L / In
        p[_D] = 1 / m - L * L / In
        p[_K], p[_R], p[_N1], p[_N2], p[_G] = c["K"], c["R"], c["N1"], c["N2"], c["g"]
        p[_T] = self.dt
        p[_KP] = OUTER_BANDWIDTH**2
        p[_KD] = 2.0 * OUTER_BANDWIDTH
        p[_KC] = CURRENT_BANDWIDTH
        p[_UMAX] = c["u_max"]
        p[_ILIM] = 0.95 * c["i_max"]
        p[_DMIN] = 1e-4
        p[_VREF] = SPEED_FRACTION * c["landing_speed"]
        p[_AREF] = REF_ACCEL
        p[_RSTOP] = c["landing_gap"] + LANDING_OVERSHOOT
        p[_KI] = CURRENT_BANDWIDTH**2 / 5.0
        self._p = p
        self._Lo = observer_gains(self.dt, OBS_BANDWIDTH, BIAS_BANDWIDTH)
        self._u_max = c["u_max"]
        self._i_max = c["i_max"]
        self._hold_ns = round(c["hold_timeout"] * 1e9)
        self.estimate = np.zeros((3, 2))
        self._acc = np.zeros(2)
        self._i_last = (0.0, 0.0)
        self._ref = np.zeros((3, 2))
        self._ui = np.zeros(2)
        self._obs_ready = False
        self.u = np.zeros(2) if u0 is None else np.asarray(u0, float).copy()
        self._u_last = self.u.copy()
        self._t_fresh: int | None = None
        self.mode = Mode(mode)
        self.reason = ""
        self.fault = ""
        self._load_kernels()
        self.counters = dict.fromkeys(
            ("holds", "hold_events", "longest_hold_us", "clipped", "rejected", "landings", "trips", "estops", "landed"), 0)

    def _load_kernels(self) -> None:
        """Load (or compile: seconds) the numba kernels now, on scratch data, never in a sample."""
        s, a = np.zeros((3, 2)), np.zeros(2)
        s[0, :] = self.cfg["landing_gap"]
        de1, de2 = _deltas(self._p, s[0, 0], s[0, 1])
        _model_accel(self._p, de1, de2, 1.0, 1.0, a)
        _observe(self._p, self._Lo, s, a, s[0, 0], s[0, 1], 1.0, 1.0)
        _land_law(self._p, s, np.zeros((3, 2)), np.zeros(2), np.ones(2), False, np.zeros(2))

    # -- commands from outside -------------------------------------------------------------
    def land(self, reason: str) -> None:
        """Start a controlled landing (ignored when already landing, landed or faulted); latched until clear()."""
        if self.mode in (Mode.LAND, Mode.LANDED, Mode.FAULT):
            return
        if self.mode == Mode.OFF:
            self.mode, self.reason = Mode.LANDED, reason  # nothing airborne under our control
            return
        self.mode = Mode.LAND
        self.reason = reason
        self.counters["landings"] += 1
        s, r = self.estimate, self._ref
        r[0, :] = s[0, :]
        r[1, :] = np.clip(s[1, :], 0.0, self._p[_VREF])
        r[2, :] = REF_ACCEL
        # bumpless: the current loop's integral starts at what the nominal R misses of the last voltage
        self._ui[:] = self._u_last - self._p[_R] * np.asarray(self._i_last)

    def estop(self, reason: str) -> None:
        """Emergency stop: a latched fault that lands the plate (never a 0 V cut at hover)."""
        self.counters["estops"] += 1
        self._trip(f"e-stop: {reason}")

    def clear(self) -> None:
        """Acknowledge: LAND/LANDED/FAULT -> OFF, the latched fault is forgotten (counters stay)."""
        self.mode = Mode.OFF
        self.reason = ""
        self.fault = ""
        self._t_fresh = None

    def _trip(self, reason: str) -> None:
        if not self.fault:
            self.fault = reason
        self.counters["trips"] += 1
        self.land(reason)

    # -- the sample ---------------------------------------------------------------------------
    def step(self, t_ns: int, y: Sequence[float], i: Sequence[float], u_cmd: Sequence[float] | None,
             requested: Mode = Mode.RUN) -> np.ndarray:
        """Voltages (2,) [V] to apply over [t, t + T).

        Args:
            t_ns: sample time [ns] (any monotonic clock).
            y (2,): measured load-point gaps [d1, d2] [m] (any sequence of two numbers).
            i (2,): measured coil currents [A] (any sequence of two numbers).
            u_cmd (2,): a command that arrived for this sample [V], or None.
            requested: the mode the commander asks for (RUN; LAND or OFF start a landing).
        """
        y0, y1, i0, i1 = float(y[0]), float(y[1]), float(i[0]), float(i[1])
        if not (math.isfinite(y0) and math.isfinite(y1) and math.isfinite(i0) and math.isfinite(i1)):
            if self.mode != Mode.FAULT:
                self.fault = self.fault or f"non-finite sensor reading (gaps {y0!r}, {y1!r}; currents {i0!r}, {i1!r})"
                self.reason = self.fault
                self.counters["trips"] += 1
            self.mode = Mode.FAULT
            self.u = np.zeros(2)
            return self.u
        self._i_last = (i0, i1)
        if not self._obs_ready:
            self.estimate[0, :] = (y0, y1)
            self.estimate[1:, :] = 0.0
            de1, de2 = _deltas(self._p, y0, y1)
            _model_accel(self._p, de1, de2, i0, i1, self._acc)
            self.estimate[2, :] = -self._acc  # bumpless: at rest, the model misses -a_m
            self._obs_ready = True
        else:
            _observe(self._p, self._Lo, self.estimate, self._acc, y0, y1, i0, i1)
        mode = self.mode
        if mode == Mode.FAULT:
            self.u = np.zeros(2)
            return self.u
        fresh = u_cmd is not None
        if fresh:
            a, b = float(u_cmd[0]), float(u_cmd[1])  # type: ignore[index]
            if not (math.isfinite(a) and math.isfinite(b)):
                self.counters["rejected"] += 1
                fresh = False
        if mode in (Mode.RUN, Mode.HOLD) and requested in (Mode.LAND, Mode.OFF):
            self.land(f"{requested.name} requested")
            mode = self.mode
        if mode in (Mode.RUN, Mode.HOLD):
            g = self.estimate[0]
            worst = max(abs(i0), abs(i1))
            if worst > self._i_max:
                self._trip(f"coil current {worst:.2f} A above i_max = {self._i_max:g} A")
            elif min(g[0], g[1]) < self.cfg["trip_gap_min"]:
                self._trip(f"gap {min(g[0], g[1]) * 1e3:.3f} mm below trip_gap_min = {self.cfg['trip_gap_min'] * 1e3:g} mm")
            elif max(g[0], g[1]) > self.cfg["trip_gap_max"]:
                self._trip(f"gap {max(g[0], g[1]) * 1e3:.3f} mm above trip_gap_max = {self.cfg['trip_gap_max'] * 1e3:g} mm")
            mode = self.mode
        if mode == Mode.OFF:
            if fresh and requested == Mode.RUN:
                self.mode = mode = Mode.RUN
            else:
                self.u = np.zeros(2)
                return self.u
        if mode in (Mode.RUN, Mode.HOLD):
            if fresh:
                lim = self._u_max
                ua = min(max(a, -lim), lim)
                ub = min(max(b, -lim), lim)
                if ua != a or ub != b:
                    self.counters["clipped"] += 1
                self._u_last = np.array((ua, ub))
                self._t_fresh = t_ns
                if mode == Mode.HOLD:
                    self.mode, self.reason = Mode.RUN, ""
                self.u = self._u_last
                return self.u
            if self._t_fresh is None:
                self._t_fresh = t_ns
            if mode == Mode.RUN:
                self.mode, self.reason = Mode.HOLD, "command missing"
                self.counters["hold_events"] += 1
            held = t_ns - self._t_fresh
            if held <= self._hold_ns:
                self.counters["holds"] += 1
                if held > self.counters["longest_hold_us"] * 1000:
                    self.counters["longest_hold_us"] = held // 1000
                self.u = self._u_last
                return self.u
            self.land(f"no command for {(t_ns - self._t_fresh) * 1e-6:.1f} ms (hold_timeout "
                      f"{self._hold_ns * 1e-6:g} ms)")
            mode = self.mode
        u = np.empty(2)
        if mode == Mode.LAND and min(self.estimate[0, 0], self.estimate[0, 1]) >= self.cfg["landing_gap"]:
            self.mode = mode = Mode.LANDED
            self.counters["landed"] += 1
        if mode == Mode.LANDED and max(abs(i0), abs(i1)) < I_OFF:
            u[:] = 0.0
        else:
            _land_law(self._p, self.estimate, self._ref, self._ui, np.array(self._i_last), mode == Mode.LANDED, u)
        self.u = u
        return u

    def snapshot(self) -> dict[str, Any]:
        """Mode, reasons and counters as plain values (for /diagnostics and summaries)."""
        return {"mode": self.mode.name, "reason": self.reason, "fault": self.fault, **self.counters}
