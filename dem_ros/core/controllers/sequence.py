"""The law's start, lift-off and restart on a real loop: :class:`ControlSequence` (no middleware).

A control law (:mod:`dem_ros.core.controllers`) steps from a state it was started in. On a loop that runs
before, between and after the law, something decides what is commanded until the law can start, from which
samples it starts, and when it must stop. That is this class; the controller node
(:mod:`dem_ros.nodes.controller`) feeds it the samples it accepted and publishes what it returns, and the
offline simulator (:func:`dem_ros.core.simulate.simulate`) starts its law through the same hover fit
(:meth:`ControlSequence.fit_window`).

Start and restart (the same path: a controller started mid-run, or a law swapped during the run): nothing is
commanded before the plant's applied voltage has been seen (the caller's rule: it does not call
:meth:`~ControlSequence.step` without one).

* **A levitating plate**: the law initialises from the current estimate and the last applied voltage
  (:mod:`.hover`); during the pre-roll (before t = 0) from a ``hover_window`` of pre-roll samples, holding the
  applied voltage meanwhile (:data:`HOLD`), as the offline simulator does.
* **A plate resting on its support** (the magnets carry less than a quarter of the load:
  :func:`~.hover.lift_fraction`; also after the board landed it under a running law): premagnetise the coils
  to half the hover force (:data:`PREMAGNETISE`), wait until the applied voltage shows that the board follows
  those commands (:data:`ECHO_SAMPLES` in a row: a landed board ignores them until it is armed again), raise
  the force until the plate leaves its support (:data:`~.hover.LIFT_DETECT`), and start the law there: its hover
  fit takes in the plate's accelerations (:func:`~.hover.departure_acceleration`) and the coils' resistances of
  the last :data:`LIFT_WINDOW` echoed samples, and a smooth reference leads from where the plate is, as fast as
  it moves, to the reference stream (:func:`~.hover.liftoff_reference`).
* **Stop**: the board applies about 0 V (below :data:`OFF_VOLTS` on both coils) for :data:`OFF_SAMPLES` applied
  samples, or the plate rests on its support for :data:`RESTING_S` under the running law: the board landed it
  and ignores our commands. The law stops at once, so that a re-arm finds it premagnetising, not wound up.

Parameter changes (:meth:`~ControlSequence.configure`) take effect at the next step; changing ``type`` swaps the
law, restarted from the next sample.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import Controller, make_controller
from .hover import (
    LIFT_DETECT,
    PREMAG_FRACTION,
    RAMP_MAX,
    RAMP_RATE,
    RESTING_FRACTION,
    departure_acceleration,
    lift_fraction,
    liftoff_duration,
    liftoff_reference,
    liftoff_target,
    premagnetise,
)

__all__ = ["ECHO_SAMPLES", "HOLD", "LAW", "LIFT_WINDOW", "OFF_SAMPLES", "OFF_VOLTS", "PREMAGNETISE", "RESTING_S",
           "ControlSequence", "Step"]

#: what a step commands: the applied voltage held (the hover window fills), a premagnetising voltage, or the law's
HOLD, PREMAGNETISE, LAW = "hold", "premagnetise", "law"
RESTING_S = 0.2  # s: resting this long under the running law -> the board landed it: stop, wait to lift off
#: the board applies (about) nothing - below OFF_VOLTS on both coils - for OFF_SAMPLES applied samples under the
#: running law: it is not applying our commands (OFF, or LANDED once the current is gone): stop the law at once, so
#: that a re-arm finds it premagnetising, not wound up (a law left running through a landing during a lift-off
#: and a re-arm kicked the plate up into the board's stopping-distance trip at every re-arm)
OFF_VOLTS = 1.0
OFF_SAMPLES = 20
ECHO_SAMPLES = 20  # premagnetised samples the board must echo before the law starts (5 coil time constants)
#: the coils' resistances in the law's hover fit at lift-off: from the last this many echoed premagnetised samples
#: (from one sample, current noise alone makes them differ, and the plate leaves its support tilting)
LIFT_WINDOW = 50


def _finite2(u: np.ndarray) -> bool:
    return math.isfinite(u[0]) and math.isfinite(u[1])


def _quiet(text: str) -> None:
    return None


@dataclass(frozen=True)
class Step:
    """What one sample commands.

    Attributes:
        kind: :data:`HOLD` (``u`` is the applied voltage, held while the hover window fills), :data:`PREMAGNETISE`
            or :data:`LAW`.
        u: the voltages to command (V; the caller clips them to its limit), or None: the law produced no valid
            voltage (non-finite, or its own fault flag): command nothing for this sample.
    """

    kind: str
    u: np.ndarray | None


class ControlSequence:
    """A law with its start, lift-off and restart (see the module docstring).

    Args:
        cfg: the ``controller`` parameters (:mod:`dem_ros.core.params`).
        law: the law to run (default: ``make_controller(cfg)``); a swap or a restart makes a new one from ``cfg``.
        info, warn: where the sequence says what it did (the node's logger; default: nowhere).

    Attributes:
        law: the law now; its ``diag`` is that of its last step.
        counts: ``starts`` (law starts, lift-offs included), ``liftoffs``, ``landed_stops`` (stops because the board
            landed the plate).
    """

    def __init__(self, cfg: Mapping[str, Any], law: Controller | None = None, *,
                 info: Callable[[str], None] = _quiet, warn: Callable[[str], None] = _quiet):
        self.cfg = dict(cfg)
        self.law = law if law is not None else make_controller(self.cfg)
        self.info, self.warn = info, warn
        self.counts = dict.fromkeys(("starts", "liftoffs", "landed_stops"), 0)
        self.started = False
        self.window: list[tuple[np.ndarray, np.ndarray]] | None = []  # hover window (estimate, applied voltage)
        self.window_n = max(round(self.cfg["hover_window"] / self.cfg["dt"]), 1)
        self.applied_off = 0  # consecutive applied samples of (about) 0 V on both coils
        self.landed = False  # the plate rests on its support: premagnetise, then lift off
        self.echoed = 0  # consecutive samples whose applied voltage was our premagnetising command
        self.u_premag = np.zeros(2)  # the last premagnetising command [V]
        self.y_rest = np.zeros(2)  # where the plate rested on its support [m]
        self.lift_from = np.zeros(2)
        self.premag_window: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=LIFT_WINDOW)  # (estimate, applied)
        #: (gaps y0, start stamp, duration T s, gap rates, gap accelerations) where the plate left its support
        self.liftoff: tuple[np.ndarray, int, float, np.ndarray, np.ndarray] | None = None
        self.resting_since: int | None = None

    # -- what the caller tells it ----------------------------------------------------------------------
    def configure(self, cfg: Mapping[str, Any]) -> None:
        """New parameters (validated as a whole), from the next step; a new ``type`` swaps the law, restarted from
        the next sample alone (no hover window mid-run)."""
        if cfg["type"] != self.cfg["type"]:
            self.law = make_controller(cfg)
            self.started = False
            self.window = None
        else:
            self.law.set_params(cfg)
        self.cfg = dict(cfg)

    def applied(self, u: Any) -> None:
        """One applied-voltage sample of the plant (two finite values): counts the board's 0 V."""
        off = abs(u[0]) < OFF_VOLTS and abs(u[1]) < OFF_VOLTS
        self.applied_off = self.applied_off + 1 if off else 0

    def reset(self) -> None:
        """Start over: the law stopped, a new one made from the parameters, any lift-off dropped; it starts again
        from the next sample (premagnetising if the plate rests)."""
        self.resting_since = None
        self.started = False
        self.liftoff = None
        self.law = make_controller(self.cfg)

    # -- the sample ------------------------------------------------------------------------------------
    def step(self, t: int, xh: np.ndarray, u_applied: np.ndarray, ref: np.ndarray | None, preroll: bool) -> Step:
        """What to command for the estimate ``xh`` [d1, d1', d2, d2', i1, i2] stamped ``t`` (ns) with the last
        applied voltage ``u_applied`` and the reference for ``t`` (None before any: the measured gaps are held);
        ``preroll``: the sample is the pre-roll's (before t = 0)."""
        if self.started and self.applied_off >= OFF_SAMPLES:
            self._stop(f"the board applies 0 V ({self.applied_off} samples): it does not apply our commands "
                       "(landed or off); law stopped, it lifts off when the board applies commands again")
        if not self.started:
            first = self._start(t, xh, u_applied, ref, preroll)
            if first is not None:
                return first
        if ref is None:  # the first samples before any reference: hold the measured hover
            ref = np.array([xh[0], xh[2], 0, 0, 0, 0, 0, 0], dtype=float)
        if self.liftoff is not None:
            y0, t0, T, v0, a0 = self.liftoff
            target, handover = liftoff_target(self.lift_from, ref)
            ref = liftoff_reference(y0, target, (t - t0) * 1e-9, T, v0, a0)
            if handover and t - t0 >= T * 1e9:
                self.liftoff = None
                self.info("lift-off done: tracking the reference")
        u = self.law.step(xh, ref)
        if not _finite2(u) or self.law.diag[-1] > 0:
            return Step(LAW, None)
        self._watch_resting(t, xh)
        return Step(LAW, u)

    def fit_window(self, Zw: np.ndarray, Uw: np.ndarray) -> bool:
        """Start the law from a hover window: estimates (n, 6) and the voltages applied meanwhile (n, 2). False
        (nothing started) when the window's mean shows a plate resting on its support."""
        if lift_fraction(Zw.mean(axis=0), self.cfg) < RESTING_FRACTION:
            return False
        self._begin(Zw, Uw)
        return True

    @property
    def phase(self) -> str:
        """``running``, ``premagnetised, waiting for the board`` or ``waiting to start``."""
        return ("running" if self.started else "premagnetised, waiting for the board" if self.landed
                else "waiting to start")

    # -- start / restart -------------------------------------------------------------------------------
    def _begin(self, Zw: np.ndarray, Uw: np.ndarray) -> None:
        self.law.reset(Zw, Uw)
        self.started = True
        self.counts["starts"] += 1
        z, u = np.atleast_2d(Zw)[-1], np.atleast_2d(Uw)[-1]
        self.info(f"law {self.law.name} started at {z[0] * 1e3:.3f} / {z[2] * 1e3:.3f} mm from the"
                  f" applied {u[0]:.1f} / {u[1]:.1f} V")

    def _start(self, t: int, xh: np.ndarray, u_applied: np.ndarray, ref: np.ndarray | None,
               preroll: bool) -> Step | None:
        """None: the law is started (step it on this sample); else what to command while it is not."""
        if self.landed or (not self.window and lift_fraction(xh, self.cfg) < RESTING_FRACTION):
            return self._premagnetise(t, xh, u_applied, ref)
        if self.window is not None:
            self.window.append((xh.copy(), u_applied.copy()))
            if len(self.window) < self.window_n and preroll:
                return Step(HOLD, u_applied.copy())  # hold the hover meanwhile
            Zw = np.array([z for z, _ in self.window])
            Uw = np.array([u for _, u in self.window])
            self.window = None
            if not self.fit_window(Zw, Uw):  # a resting window: no hover fit
                return self._premagnetise(t, xh, u_applied, ref)
            return None
        self._begin(xh.copy(), u_applied.copy())  # started mid-run, or swapped: this sample alone
        return None

    def _premagnetise(self, t: int, xh: np.ndarray, ua: np.ndarray, ref: np.ndarray | None) -> Step | None:
        """A resting plate: premagnetise to half the hover force until the board echoes it, raise the force until
        the plate leaves its support, then start the law from that sample with a lift-off reference (None)."""
        if not self.landed:
            self.landed = True
            self.window = None
            self.echoed = 0
            self.y_rest = np.array([xh[0], xh[2]])
            self.info(f"the plate rests on its support ({xh[0] * 1e3:.3f} / {xh[2] * 1e3:.3f} mm): "
                      "premagnetising; lift-off once the board applies our commands")
        u_last = self.u_premag
        if np.all(np.abs(ua - u_last) <= 0.05 * np.abs(u_last) + 0.5):
            self.echoed += 1
            self.premag_window.append((xh.copy(), ua.copy()))
        else:
            self.echoed = 0  # the board does not (or no longer) apply our commands: start over
            self.premag_window.clear()
        y = np.array([xh[0], xh[2]])
        if self.echoed >= ECHO_SAMPLES and ref is not None and np.any(y < self.y_rest - LIFT_DETECT):
            # the hover fit at this sample: the magnets now carry the plate, and accelerate it (it leaves its
            # support): fitted as if at rest, the law's model would take that net force for a bias and let the plate
            # rise on (the heave equation wants this very sample: a window's mean, partly carried by the support,
            # left the same bias). The coils' resistances from the premagnetised window: the voltages that they
            # give at this sample's currents
            accel = departure_acceleration(self.y_rest, y, np.array([xh[1], xh[3]]), self.cfg["g"])
            i_w = np.mean([z[4:6] for z, _ in self.premag_window], axis=0)
            u_w = np.mean([u for _, u in self.premag_window], axis=0)
            R_w = np.divide(u_w, i_w, out=np.zeros(2), where=i_w > 0.0)
            u_fit = np.where(i_w > 0.0, R_w * xh[4:6], ua)
            self.law = make_controller(self.cfg)
            self.law.reset(xh.copy(), u_fit, accel)
            self.liftoff = (y, t, liftoff_duration(y, liftoff_target(self.y_rest, ref)[0]), np.array([xh[1], xh[3]]),
                            accel)
            self.lift_from = self.y_rest.copy()
            self.landed = False
            self.started = True
            self.counts["starts"] += 1
            self.counts["liftoffs"] += 1
            self.info(f"off the support at {y[0] * 1e3:.3f} / {y[1] * 1e3:.3f} mm ({ua[0]:.1f} / {ua[1]:.1f} V): "
                      f"law {self.law.name} started, lift-off to the reference over {self.liftoff[2]:.2f} s")
            return None
        ramp = max(self.echoed - ECHO_SAMPLES, 0) * self.cfg["dt"] * RAMP_RATE
        _, self.u_premag = premagnetise(xh, self.cfg, min(PREMAG_FRACTION + ramp, RAMP_MAX))
        return Step(PREMAGNETISE, self.u_premag)

    def _watch_resting(self, t: int, xh: np.ndarray) -> None:
        """Under the running law the plate rests on its support for RESTING_S: the board landed it (it ignores
        our commands now). Stop the law, so that it lifts off afresh when the board follows again."""
        if self.liftoff is not None or lift_fraction(xh, self.cfg) >= RESTING_FRACTION:
            self.resting_since = None
            return
        if self.resting_since is None:
            self.resting_since = t
        elif t - self.resting_since >= RESTING_S * 1e9:
            self._stop("the plate rests on its support under the running law (the board landed it): law "
                       "stopped; it lifts off when the board applies commands again")

    def _stop(self, why: str) -> None:
        """The board does not apply our commands (it landed the plate): stop the law (and any lift-off), so that it
        starts afresh - premagnetising, then lifting off - once the board applies commands again."""
        self.reset()
        self.counts["landed_stops"] += 1
        self.warn(why)
