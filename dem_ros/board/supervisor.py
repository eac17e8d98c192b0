"""The board's supervisor: the mode machine that composes the limits, the held commands, the stopping-distance
trip, the landing observer and law, the lost-sensor ride-through and the gap plausibility check
(docs/manual/board.md). Pure Python + numba, no middleware: ``plant_sim``'s simulated board and the rig
emulator's board both run it."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .braking import _brake, _stop_gaps
from .coil import CoilModel
from .config import (
    _R,
    _VREF,
    BIAS_BANDWIDTH,
    CAPTURE_ACCEL,
    CAPTURE_TIME,
    HOLD_DESCENT_FRACTION,
    HOLD_GUARD_AFTER,
    HOLD_RISE_FRACTION,
    HOLD_SPEEDUP_FRACTION,
    I_OFF,
    OBS_BANDWIDTH,
    REF_ACCEL,
    SENSOR_BLIND_SAMPLES,
    hold_guard_text,
    kernel_vector,
)
from .gapcheck import GapCheck
from .landing import _land_law
from .modes import Mode
from .observer import _deltas, _model_accel, _observe, observer_gains
from .sensor_loss import SensorLosses

__all__ = ["Supervisor"]


class Supervisor(SensorLosses):
    """The board: hard limits, command watchdog, landing law (docs/manual/board.md).

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
        counters: sample and event counts (docs/manual/board.md).
        u (2,): the voltages applied by the last ``step`` [V] (the array ``step`` returned;
            the board may return it again, never changes it in place).
        estimate (3, 2): observer state [gap m, rate m/s, missed acceleration m/s^2] per load point.
        stop_gap (2,): the last predicted stopping gap per load point [m] (the braking bound).
        min_stop_gap: the smallest predicted stopping gap checked so far [m].
        implausible (2,): gap sensor j found contradicting the coils' fluxes (latched until ``clear()``;
            the board's status bits GAPj_IMPLAUSIBLE).
        command_timeout: the landing was started by ``hold_timeout`` without a command (the board's link
            watchdog: status bit LINK_TIMEOUT), until ``clear()``.
    """

    def __init__(self, cfg: Mapping[str, Any], dt: float, mode: Mode = Mode.OFF, u0: np.ndarray | None = None):
        c, p = kernel_vector(cfg, dt)
        self.cfg = c
        self.dt = float(dt)
        self._p = p
        self._Lo = observer_gains(self.dt, OBS_BANDWIDTH, BIAS_BANDWIDTH)
        self._u_max = c["u_max"]
        self._i_max = c["i_max"]
        self._hold_ns = round(c["hold_timeout"] * 1e9)
        # the hold's speed guard: the held plate's rate limits [m/s] (descending, rising) and the observer's age
        # [samples] from which it acts
        self._hold_descent = HOLD_DESCENT_FRACTION * c["landing_speed"]
        self._hold_rise = HOLD_RISE_FRACTION * c["landing_speed"]
        self._hold_speedup = HOLD_SPEEDUP_FRACTION * c["landing_speed"]
        self._hold_v0 = np.zeros(2)  # the observer's rates [m/s] at the hold's first sample
        self._guard_samples = round(HOLD_GUARD_AFTER / self.dt)
        self._obs_age = 0  # samples the observer has run (counted up to _guard_samples)
        self.estimate = np.zeros((3, 2))
        self._acc = np.zeros(2)
        self._i_last = (0.0, 0.0)
        self._ref = np.zeros((3, 2))
        self._ui = np.zeros(2)
        self._obs_ready = False
        self.u = np.zeros(2) if u0 is None else np.asarray(u0, float).copy()
        self._u_last: np.ndarray = self.u.copy()
        self._t_fresh: int | None = None
        self._braking = False
        self._gated = np.zeros(2)
        self._wild = np.zeros(2)
        self._blind = [0, 0, 0, 0]  # consecutive samples without a finite gap 1, gap 2, current 1, current 2
        self._blind_now = np.zeros(2)
        self.coil = CoilModel(p, self.dt)  # lost current samples; gaps from the coils' fluxes
        self._loss_counted = [False, False, False, False]  # channel given up (counted in sensor_losses)
        self._check = GapCheck(p, self.dt)  # the gap sensors against the coils' fluxes
        self.implausible = [False, False]  # gap sensor j contradicts the coil fluxes: ignored until clear()
        self.command_timeout = False  # the landing was started by the command hold timeout (a link watchdog)
        self.stop_gap = np.full(2, math.inf)
        self.min_stop_gap = math.inf
        self.mode = Mode(mode)
        self.reason = ""
        self.fault = ""
        self._load_kernels()
        self.counters = dict.fromkeys(
            ("holds", "hold_events", "longest_hold_us", "clipped", "rejected", "landings", "trips", "estops", "landed",
             "brakes", "brake_events", "sensor_gaps", "sensor_gap_events", "sensor_losses", "implausible"), 0)

    def _load_kernels(self) -> None:
        """Load (or compile: seconds) the numba kernels now, on scratch data, never in a sample."""
        s, a = np.zeros((3, 2)), np.zeros(2)
        s[0, :] = self.cfg["landing_gap"]
        de1, de2 = _deltas(self._p, s[0, 0], s[0, 1])
        _model_accel(self._p, de1, de2, 1.0, 1.0, a)
        _observe(self._p, self._Lo, s, a, s[0, 0], s[0, 1], 1.0, 1.0, np.zeros(2), np.zeros(2), np.zeros(2))
        _land_law(self._p, s, np.zeros((3, 2)), np.zeros(2), np.ones(2), False, np.zeros(2))
        _stop_gaps(self._p, s, np.ones(2), np.ones(2), self._u_max, np.zeros(2))
        _brake(self._p, s, np.ones(2), self._u_max, np.zeros(2))

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
        self._start_reference()
        # bumpless: the current loop's integral starts at what the nominal R misses of the last voltage
        self._ui[:] = self._u_last - self._p[_R] * np.asarray(self._i_last)

    def _start_reference(self) -> None:
        """The landing reference starts at the estimate, with the plate's own downward speed (<= v_ref)."""
        s, r = self.estimate, self._ref
        r[0, :] = s[0, :]
        r[1, :] = np.minimum(s[1, :], self._p[_VREF])
        r[2, :] = np.where(r[1, :] < 0.0, np.clip(-r[1, :] / CAPTURE_TIME, REF_ACCEL, CAPTURE_ACCEL), REF_ACCEL)

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
        self._braking = False
        self.coil.flux_gap = [False, False]
        self._loss_counted = [False, False, False, False]
        self.implausible = [False, False]
        self.command_timeout = False
        self._check.reset()

    def _trip(self, reason: str) -> None:
        if not self.fault:
            self.fault = reason
        self.counters["trips"] += 1
        self.land(reason)

    # -- the sample ---------------------------------------------------------------------------
    def step(self, t_ns: int, y: Sequence[float] | np.ndarray | None, i: Sequence[float] | np.ndarray | None,
             u_cmd: Sequence[float] | np.ndarray | None,
             requested: Mode = Mode.RUN, bus: float | None = None,
             applied: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
        """Voltages (2,) [V] to apply over [t, t + T).

        Args:
            t_ns: sample time [ns] (any monotonic clock).
            y (2,): measured load-point gaps [d1, d2] [m] (any sequence of two numbers; None or a
                non-finite entry: no sample, see docs/manual/board.md, "Lost sensor samples").
            i (2,): measured coil currents [A] (any sequence of two numbers; None / non-finite likewise).
            u_cmd (2,): a command that arrived for this sample [V], or None.
            requested: the mode the commander asks for (RUN; LAND or OFF start a landing).
            bus: the coil drivers' measured bus voltage [V], when the board measures it: the brake
                can apply at most min(u_max, bus) (None: u_max).
            applied (2,): the voltages the coil drivers applied over the last period [V], when the board
                measures them (a failed bridge, PWM steps, the current limit); None: the last voltages this
                supervisor returned, clipped to the bus it was given.
        """
        y0, y1 = (math.nan, math.nan) if y is None else (float(y[0]), float(y[1]))
        i0, i1 = (math.nan, math.nan) if i is None else (float(i[0]), float(i[1]))
        if applied is not None and math.isfinite(applied[0]) and math.isfinite(applied[1]):
            self.coil.u_prev[:] = (float(applied[0]), float(applied[1]))
        if self.implausible[0]:  # found implausible: never read again until clear()
            y0 = math.nan
        if self.implausible[1]:
            y1 = math.nan
        for n, v in enumerate((y0, y1, i0, i1)):  # a sensor that reads again may be given up again (counted)
            if math.isfinite(v):
                self._loss_counted[n] = False
        if self.coil.flux_gap[0] or self.coil.flux_gap[1]:  # a gap sensor given up: its gap from the coil's flux
            y0, y1 = self.coil.flux_gaps(y0, y1, i0, i1, self.mode == Mode.LANDED, self.estimate[0])
        ok = (math.isfinite(y0), math.isfinite(y1), math.isfinite(i0), math.isfinite(i1))
        if not all(ok) and self._sensor_gap(t_ns, ok, (y0, y1, i0, i1)):
            return self.u
        for n in range(4):
            self._blind[n] = 0 if ok[n] else self._blind[n] + 1
        if not ok[2] or not ok[3]:  # a missing current: the board's coil model from the voltage it applied
            i0 = i0 if ok[2] else float(self.coil.i_est[0])
            i1 = i1 if ok[3] else float(self.coil.i_est[1])
        self._i_last = (i0, i1)
        if self.mode in (Mode.RUN, Mode.HOLD, Mode.LAND):  # (with a gap from its coil's flux: the other one)
            gone = (self.coil.flux_gap[0], self.coil.flux_gap[1])
            bad = self._check.step(y0, y1, (i0, i1), (ok[2], ok[3]), self.coil.u_prev, self.coil.r_est, gone)
            if bad == 2 or (bad >= 0 and gone[1 - bad]):
                return self._both_implausible(bad, y0, y1)
            if bad >= 0:
                y0, y1 = self._implausible(bad, y0, y1, i0, i1)
        else:
            self._check.reset()
        self._blind_now[0] = 0.0 if ok[0] else 1.0
        self._blind_now[1] = 0.0 if ok[1] else 1.0
        if self._obs_age < self._guard_samples:
            self._obs_age += 1
        if not self._obs_ready:
            self.estimate[0, :] = (y0, y1)
            self.estimate[1:, :] = 0.0
            de1, de2 = _deltas(self._p, y0, y1)
            _model_accel(self._p, de1, de2, i0, i1, self._acc)
            self.estimate[2, :] = -self._acc  # bumpless: at rest, the model misses -a_m
            self._obs_ready = True
        else:
            _observe(self._p, self._Lo, self.estimate, self._acc, y0, y1, i0, i1, self._gated, self._blind_now,
                     self._wild)
        if self.mode in (Mode.RUN, Mode.HOLD, Mode.LAND) and max(self._blind) > SENSOR_BLIND_SAMPLES:
            why = self._lost_channels(ok)
            if why:  # nothing left to land with (docs/manual/board.md, "Lost sensor samples")
                self.counters["trips"] += 1
                self.fault = self.reason = why
                self.mode = Mode.FAULT
                self.u = np.zeros(2)
                return self.u
        u = self._step_modes(t_ns, u_cmd, requested, bus, i0, i1)
        self.coil.predict(u, ok[2], ok[3], self._i_last, _deltas(self._p, self.estimate[0, 0], self.estimate[0, 1]))
        if bus is not None and math.isfinite(bus):  # what the bridges can apply of it (``applied``: what they did)
            U = max(float(bus), 0.0)
            np.clip(self.coil.u_prev, -U, U, out=self.coil.u_prev)
        return u

    def _step_modes(self, t_ns: int, u_cmd: Sequence[float] | np.ndarray | None, requested: Mode,
                    bus: float | None, i0: float, i1: float) -> np.ndarray:
        """The mode machine of ``step``, after the observer."""
        mode = self.mode
        if mode == Mode.FAULT:
            self.u = np.zeros(2)
            return self.u
        U = self._u_max if bus is None else max(min(self._u_max, float(bus)), 1e-6)  # what the bridge can apply
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
            elif max(g[0], g[1]) > self.cfg["trip_gap_max"]:
                self._trip(f"gap {max(g[0], g[1]) * 1e3:.3f} mm above trip_gap_max = "
                           f"{self.cfg['trip_gap_max'] * 1e3:g} mm")
            mode = self.mode
        if mode == Mode.OFF:
            if fresh and requested == Mode.RUN:
                self.mode = mode = Mode.RUN
            else:
                self.u = np.zeros(2)
                return self.u
        if mode in (Mode.RUN, Mode.HOLD):
            cand = self._run_candidate(t_ns, mode, fresh, a if fresh else 0.0, b if fresh else 0.0)
            mode = self.mode
            if cand is not None:
                if self._safe(cand, U):
                    self.u = cand
                    return cand
                j = int(np.argmin(self.stop_gap))
                self._trip(f"predicted stopping gap {self.stop_gap[j] * 1e3:.3f} mm below trip_gap_min = "
                           f"{self.cfg['trip_gap_min'] * 1e3:g} mm at end {j + 1} "
                           f"(gap {self.estimate[0, j] * 1e3:.3f} mm, "
                           f"rate {self.estimate[1, j] * 1e3:+.1f} mm/s)")
                mode = self.mode
        u = np.empty(2)
        if mode == Mode.LAND and min(self.estimate[0, 0], self.estimate[0, 1]) >= self.cfg["landing_gap"]:
            self.mode = mode = Mode.LANDED
            self.counters["landed"] += 1
            self._braking = False
        if mode == Mode.LANDED:
            if max(abs(i0), abs(i1)) < I_OFF:
                u[:] = 0.0
            else:
                _land_law(self._p, self.estimate, self._ref, self._ui, np.array(self._i_last), True, u)
            self.u = u
            return u
        i_now = np.array(self._i_last)
        _land_law(self._p, self.estimate, self._ref, self._ui, i_now, False, u)
        safe = self._safe(u, U)
        if not safe or (self._braking and min(self.estimate[1, 0], self.estimate[1, 1]) < 0.0):
            if not self._braking:
                self.counters["brake_events"] += 1
            self._braking = True
            self.counters["brakes"] += 1
            _brake(self._p, self.estimate, i_now, U, u)
        elif self._braking:  # released: land from the state the brake left
            self._braking = False
            self._start_reference()
            self._ui[:] = 0.0
            _land_law(self._p, self.estimate, self._ref, self._ui, i_now, False, u)
        self.u = u
        return u

    def _run_candidate(self, t_ns: int, mode: Mode, fresh: bool, a: float, b: float) -> np.ndarray | None:
        """RUN/HOLD: the fresh command clipped to u_max, or the held one; None once the hold timed out (LAND)."""
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
            return self._u_last
        if self._t_fresh is None:
            self._t_fresh = t_ns
        if mode == Mode.RUN:
            self.mode, self.reason = Mode.HOLD, "command missing"
            self._hold_v0 = self.estimate[1].copy()
            self.counters["hold_events"] += 1
        held = t_ns - self._t_fresh
        j = self._held_too_fast()
        if held <= self._hold_ns and j < 0:
            self.counters["holds"] += 1
            if held > self.counters["longest_hold_us"] * 1000:
                self.counters["longest_hold_us"] = held // 1000
            return self._u_last
        self.command_timeout = True
        if j >= 0:  # the held voltage no longer holds the plate: land before it outruns the landing speed
            self.land(f"no command for {held * 1e-6:.1f} ms and end {j + 1} moves at {self.estimate[1, j] * 1e3:+.1f} "
                      f"mm/s ({hold_guard_text(-self._hold_rise, self._hold_descent)})")
        else:
            self.land(f"no command for {held * 1e-6:.1f} ms (hold_timeout {self._hold_ns * 1e-6:g} ms)")
        return None

    def _held_too_fast(self) -> int:
        """The hold's speed guard: the end (0, 1) whose estimated rate is beyond the hold's limits, or -1 (also
        while the observer is younger than HOLD_GUARD_AFTER); end 1 first. Beyond: descending faster than
        HOLD_DESCENT_FRACTION, or rising faster than HOLD_RISE_FRACTION, of landing_speed, *and* that way faster by
        HOLD_SPEEDUP_FRACTION of it than at the hold's first sample: the held voltage speeds the plate up. A plate
        the controller itself moves fast (a lift-off rising at 30 mm/s, falling back at 15) is held through a late
        command like any other motion; landing it there would start the landing at the controller's speed."""
        if self._obs_age < self._guard_samples:
            return -1
        for j in (0, 1):
            v = float(self.estimate[1, j])
            dv = v - float(self._hold_v0[j])  # what the hold changed (positive: toward the support)
            down = v > self._hold_descent and dv > self._hold_speedup
            if down or (v < -self._hold_rise and -dv > self._hold_speedup):
                return j
        return -1

    def _safe(self, cand: np.ndarray, U: float) -> bool:
        """Does the plate stop at least trip_gap_min from the rail at both ends if ``cand`` is applied for one
        sample, then the brake? Updates ``stop_gap`` and ``min_stop_gap``."""
        _stop_gaps(self._p, self.estimate, np.array(self._i_last), cand, U, self.stop_gap)
        low = float(min(self.stop_gap[0], self.stop_gap[1]))
        if low < self.min_stop_gap:
            self.min_stop_gap = low
        return low >= self.cfg["trip_gap_min"]

    def snapshot(self) -> dict[str, Any]:
        """Mode, reasons and counters as plain values (for /diagnostics and summaries)."""
        return {"mode": self.mode.name, "reason": self.reason, "fault": self.fault, **self.counters,
                "stop_gap_mm": [round(float(g) * 1e3, 4) if math.isfinite(g) else None for g in self.stop_gap],
                "min_stop_gap_mm": round(self.min_stop_gap * 1e3, 4) if math.isfinite(self.min_stop_gap) else None}
