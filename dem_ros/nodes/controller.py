"""``controller``: the control laws of :mod:`dem_ros.core.controllers` at 1 kHz.

Triggered by ``/dem/state_estimate``: it looks up the reference of the same
stamp (published one period ahead; kept by stamp, so the arrival order of the
two topics does not matter), steps the law and publishes
``/dem/command`` (coil voltages) and ``/dem/controller/state`` with the
measurement's stamp.

Inputs are checked first (:mod:`dem_ros.core.controllers.checks`): a reference
outside the gap range, faster than the reference model can be, non-finite or
stamped ahead of the plant is refused and counted, and the last good one is
used; when none is recent (the reference node is down) the last good gaps are
held at rest. An estimate older than ``max_age`` on the experiment clock (the
newest ``/dem/applied_voltage`` stamp; default (command_delay + 1) dt), stamped
ahead of it, or non-finite is not acted on (no command: the board holds) and is
counted; a law that produces a non-finite voltage publishes nothing. An applied voltage whose stamp
is refused as a lone jump of the experiment clock (a corrupt or foreign sample) is not taken as the
applied voltage either.

Start and restart (the same path: a controller started mid-run, or a law swapped
during the run): nothing is commanded before the plant's applied voltage has been
seen. A levitating plate: the law initialises from the current estimate and the
last applied voltage (:mod:`dem_ros.core.controllers.hover`; before t = 0 from a
``hover_window`` of pre-roll samples, holding the applied voltage meanwhile, as the
offline simulator does). A plate resting on its support (the magnets carry less
than a quarter of the load: :func:`~dem_ros.core.controllers.hover.lift_fraction`;
also after the board landed it under a running controller): the node premagnetises
the coils to half the hover force, waits until the applied voltage shows that the
board follows its commands (a landed board ignores them until it is armed again),
raises the force until the plate leaves its support, and starts the law there: its
hover fit takes in the plate's accelerations
(:func:`~dem_ros.core.controllers.hover.departure_acceleration`), and a smooth
reference leads from where the plate is, as fast as it moves, to the reference
stream (:func:`~dem_ros.core.controllers.hover.liftoff_reference`).

Parameter changes (validated as a whole by the schema) take effect at the next
step; changing ``type`` swaps the law, restarted from the current sample.
"""

from __future__ import annotations

import math
import sys
from collections import deque

import numpy as np

from .. import contract
from ..core.controllers import make_controller
from ..core.controllers.checks import InputChecks
from ..core.controllers.hover import (
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
from ..core.warmup import warm_up
from ..transport import Node, run_node
from .common import (
    OK,
    PLANT_SOURCES,
    WARN,
    Diagnostics,
    Inputs,
    JointStates,
    all_finite,
    clipped,
    meas_into,
    stamp_ns,
    worth_logging,
)

__all__ = ["ControllerNode", "main"]

REF_KEEP = 32  # reference samples kept by stamp
RESTING_S = 0.2  # s: resting this long under the running law -> the board landed it: stop, wait to lift off
#: the board applies (about) nothing - below OFF_VOLTS on both coils - for OFF_SAMPLES applied samples under the
#: running law: it is not applying our commands (OFF, or LANDED once the current is gone): stop the law at once, so
#: that a re-arm finds it premagnetising, not wound up (a law left running through a landing during a lift-off
#: and a re-arm kicked the plate up at 100-210 mm/s: the board's stopping-distance trip landed it at every re-arm)
OFF_VOLTS = 1.0
OFF_SAMPLES = 20
ECHO_SAMPLES = 20  # premagnetised samples the board must echo before the law starts (5 coil time constants)
#: the coils' resistances in the law's hover fit at lift-off: from the last this many echoed premagnetised samples
#: (from one sample, current noise alone makes them differ, and the plate leaves its support tilting)
LIFT_WINDOW = 50
#: counters that make the once-a-second diagnostics WARN when they grew
_WARN_KEYS = ("stale", "future", "non_finite_input", "non_finite_output", "reference_range", "reference_rate",
              "reference_future", "reference_invalid", "reference_held", "waiting_for_applied", "plant_stamp_jump",
              "estimate_repeated")


class ControllerNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("controller", self.on_change)
        self.ctrl = make_controller(self.cfg)
        self.checks = InputChecks(self.cfg)
        self.started = False
        # reference samples by stamp, the newest REF_KEEP: stamp -> row of ref_ring, filled in place
        self.refs: dict[int, np.ndarray] = {}
        self.ref_ring = np.zeros((REF_KEEP + 1, 8))
        self.ref_next = 0
        self.xh = np.zeros(6)  # the estimate being acted on [d1, d1', d2, d2', i1, i2]
        self.u_applied: np.ndarray | None = None
        self.applied_off = 0  # consecutive applied samples of (about) 0 V on both coils
        self.window: list[tuple[np.ndarray, np.ndarray]] | None = []  # hover window (estimate, applied voltage)
        self.window_n = max(round(self.cfg["hover_window"] / self.cfg["dt"]), 1)
        self.landed = False  # the plate rests on its support: premagnetise, then lift off
        self.echoed = 0  # consecutive samples whose applied voltage was our premagnetising command
        self.u_premag = np.zeros(2)  # the last premagnetising command [V]
        self.y_rest = np.zeros(2)  # where the plate rested on its support [m]
        self.lift_from = np.zeros(2)
        self.premag_window: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=LIFT_WINDOW)  # (estimate, applied)
        #: (gaps y0, start stamp, duration T s, gap rates, gap accelerations) where the plate left its support
        self.liftoff: tuple[np.ndarray, int, float, np.ndarray, np.ndarray] | None = None
        self.resting_since: int | None = None
        self.ref_lag = float("nan")
        self.counts = dict.fromkeys(("steps", "stale", "future", "non_finite_input", "non_finite_output",
                                     "reference_mismatch", "reference_range", "reference_rate", "reference_future",
                                     "reference_invalid", "reference_held", "waiting_for_applied", "starts",
                                     "liftoffs", "landed_stops", "plant_stamp_jump", "estimate_repeated"), 0)
        self.t_acted: int | None = None  # stamp of the newest estimate acted on (a command, or a hold, sent for it)
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.MAGNETS)  # shared by every message published (never modified)
        self.names_state = list(contract.CONTROLLER_STATE_NAMES)
        # /diagnostics "controller: law" once a second, with the topic status of the command and the state
        self.diag = Diagnostics(node, contract.CONTROLLER_STATUS, warn_on=_WARN_KEYS, values=self._diag_values)
        self.pub_cmd = self.diag.diagnosed(contract.COMMAND)
        self.pub_state = self.diag.diagnosed(contract.CONTROLLER_STATE)
        self.diag.set_condition(WARN, "waiting to start")
        # the plant's clock first: an executor that drains reader by reader then never sees a reference or
        # estimate ahead of the newest applied voltage it has (a queue behind is seen as behind)
        # each input bound to its writer (docs/manual/trust.md)
        self.inputs = Inputs(node)
        self.inputs.bind(contract.APPLIED, PLANT_SOURCES, self.on_applied)
        self.inputs.bind(contract.REFERENCE, "reference", self.on_reference)
        self.inputs.bind(contract.ESTIMATE, "estimator", self.on_estimate)
        node.logger.info("ready")

    # -- parameters ----------------------------------------------------------
    def on_change(self, values) -> str | None:
        for key in ("dt", "command_delay"):
            if values[key] != self.cfg[key]:
                return f"{key} cannot change during a run"
        if values["type"] != self.cfg["type"]:
            self.ctrl = make_controller(values)
            self.started = False  # re-initialised from the next sample (no open-loop window mid-run)
            self.window = None
        else:
            self.ctrl.set_params(values)
        self.cfg = dict(values)
        self.checks.configure(values)
        self.node.logger.info("parameters applied from the next step")
        return None

    # -- inputs --------------------------------------------------------------
    def on_reference(self, msg) -> None:
        if len(msg.position) < 8:
            self._refuse("reference_invalid", f"{len(msg.position)} values, expected 10")
            return
        t = stamp_ns(msg)
        verdict = self.checks.reference(t, msg.position)
        if not verdict.ok:
            self._refuse(verdict.key, verdict.why)
            return
        refs = self.refs
        if len(refs) >= REF_KEEP:
            del refs[next(iter(refs))]  # the oldest (its row is reused REF_KEEP + 1 samples later)
        row = self.ref_ring[self.ref_next]
        self.ref_next = (self.ref_next + 1) % (REF_KEEP + 1)
        row[:] = msg.position[:8]
        refs[t] = row

    def _refuse(self, key: str, why: str) -> None:
        self.counts[key] += 1
        self._warn_every(key, f"reference refused ({key}): {why}; the last good one is used")

    def _reference(self, t: int) -> np.ndarray | None:
        """The reference for stamp ``t``: its own, else the newest older one if recent, else the last good
        gaps held at rest; None before any. Sets ``ref_lag`` (samples)."""
        dt_ns = self.checks.dt_ns
        ref = self.refs.get(t)
        if ref is not None:
            self.ref_lag = 0.0
            return ref
        older = [s for s in self.refs if s <= t]
        if not older:
            if self.checks.last_ref_t is None:
                self.ref_lag = float("nan")
                return None
            s = self.checks.last_ref_t
        else:
            s = max(older)
        self.ref_lag = round((t - s) / dt_ns)
        self.counts["reference_mismatch"] += 1
        if older and t - s <= max(self.checks.max_age_ns, 2 * dt_ns):
            return self.refs[s]
        self.counts["reference_held"] += 1
        if self.counts["reference_held"] in (1, 1000) or self.counts["reference_held"] % 10000 == 0:
            self.node.logger.warn(f"no recent reference ({self.ref_lag:.0f} samples behind): holding the last good gaps"
                                  f" ({self.counts['reference_held']} samples so far)")
        return self.checks.held_reference()

    def on_applied(self, msg) -> None:
        if len(msg.effort) >= 2 and all_finite(msg.effort[:2]):
            # the stamp first: a sample it refuses (a lone jump of the experiment clock: a corrupt or foreign
            # stamp) is not the plant's, so its effort is not either (u_applied feeds the hover fit and restarts)
            if not self.checks.plant_stamp(stamp_ns(msg)):
                self.counts["plant_stamp_jump"] = self.checks.stamps_refused  # the checks count them; shown here
                self._warn_every("plant_stamp_jump", "applied voltage stamped far from the plant's clock: not taken"
                                 " (neither as the clock nor as the applied voltage) until the next sample confirms it")
                return
            if self.u_applied is None:
                self.u_applied = np.zeros(2)
            self.u_applied[0] = msg.effort[0]
            self.u_applied[1] = msg.effort[1]
            off = abs(msg.effort[0]) < OFF_VOLTS and abs(msg.effort[1]) < OFF_VOLTS
            self.applied_off = self.applied_off + 1 if off else 0

    def on_estimate(self, msg) -> None:
        t = stamp_ns(msg)
        age_ns = self.checks.age_ns(t)
        age = age_ns * 1e-9 if age_ns is not None else float("nan")
        xh = self.xh
        if len(msg.position) < 2 or len(msg.effort) < 2:
            self.counts["non_finite_input"] += 1
            self._warn_every("non_finite_input", "estimate without two gaps and two currents: not acted on")
            return self._state(t, age, 1.0)
        meas_into(msg, xh)
        why = self.checks.estimate(t)
        if why:
            self.counts[why] += 1
            self._warn_every(why, f"estimate {abs(age) * 1e3:.2f} ms {'old' if why == 'stale' else 'ahead'}"
                                  " on the experiment clock (> max_age): not acted on")
            return self._state(t, age, 1.0)
        if not all_finite(xh):
            self.counts["non_finite_input"] += 1
            self._warn_every("non_finite_input", "non-finite input: not acted on")
            return self._state(t, age, 1.0)
        if self.u_applied is None:  # never start from a guess: the board holds meanwhile
            self.counts["waiting_for_applied"] += 1
            self._warn_every("waiting_for_applied", "no applied voltage seen yet: not started")
            return self._state(t, age, 1.0)
        if self.t_acted is not None and t <= self.t_acted:
            # the estimator sends each stamp once: a repeat (or an older one) is not its, and stepping the law
            # twice for one sample would advance its filters and adaptation twice and send two commands
            self.counts["estimate_repeated"] += 1
            self._warn_every("estimate_repeated", "estimate with a stamp not newer than the last one acted on: not"
                                                  " acted on")
            return self._state(t, age, 1.0)
        self.t_acted = t
        ref = self._reference(t)
        if self.started and self.applied_off >= OFF_SAMPLES:
            self._stop_law(f"the board applies 0 V ({self.applied_off} samples): it does not apply our commands "
                           "(landed or off); law stopped, it lifts off when the board applies commands again")
        if not self.started and not self._start(t, msg, xh, ref, age):
            return
        if ref is None:  # the first samples before any reference: hold the measured hover
            ref = np.array([xh[0], xh[2], 0, 0, 0, 0, 0, 0], dtype=float)
        if self.liftoff is not None:
            y0, t0, T, v0, a0 = self.liftoff
            target, handover = liftoff_target(self.lift_from, ref)
            ref = liftoff_reference(y0, target, (t - t0) * 1e-9, T, v0, a0)
            if handover and t - t0 >= T * 1e9:
                self.liftoff = None
                self.node.logger.info("lift-off done: tracking the reference")
        u = self.ctrl.step(xh, ref)
        self.counts["steps"] += 1
        if not all_finite(u) or self.ctrl.diag[-1] > 0:
            self.counts["non_finite_output"] += 1
            self._warn_every("non_finite_output", "the law produced no valid voltage: no command sent")
            return self._state(t, age, 1.0)
        h = self.js.header(t)
        self.pub_cmd.publish(self.js.make(h, self.names, effort=clipped(u, self.cfg["voltage_limit"])))
        self._state(t, age, 0.0, h)
        self._watch_resting(t, xh)

    # -- start / restart ---------------------------------------------------------
    def _start(self, t: int, msg, xh: np.ndarray, ref: np.ndarray | None, age: float) -> bool:
        """Initialise the law (True) or hold/premagnetise for this sample (False; the command is sent here)."""
        u_applied = self.u_applied
        assert u_applied is not None
        if self.landed or (not self.window and lift_fraction(xh, self.cfg) < RESTING_FRACTION):
            return self._premagnetise(t, xh, ref, age)
        if self.window is not None:
            self.window.append((xh.copy(), u_applied.copy()))
            if len(self.window) < self.window_n and msg.header.frame_id == contract.FRAME_PREROLL:
                h = self.js.header(t)
                self.pub_cmd.publish(self.js.make(h, self.names, effort=u_applied.tolist()))  # hold the hover meanwhile
                self._state(t, age, 0.0, h)
                return False
            Zw = np.array([z for z, _ in self.window])
            Uw = np.array([u for _, u in self.window])
            self.window = None
            if lift_fraction(Zw.mean(axis=0), self.cfg) < RESTING_FRACTION:  # a resting window: no hover fit
                return self._premagnetise(t, xh, ref, age)
        else:  # started mid-run, or swapped: this sample alone
            Zw, Uw = xh.copy(), u_applied.copy()
        self.ctrl.reset(Zw, Uw)
        self.started = True
        self.counts["starts"] += 1
        self.node.logger.info(f"law {self.ctrl.name} started at {xh[0] * 1e3:.3f} / {xh[2] * 1e3:.3f} mm from the"
                              f" applied {u_applied[0]:.1f} / {u_applied[1]:.1f} V")
        return True

    def _premagnetise(self, t: int, xh: np.ndarray, ref: np.ndarray | None, age: float) -> bool:
        """A resting plate (:mod:`dem_ros.core.controllers.hover`, lift-off): premagnetise to half the hover
        force until the board echoes it, raise the force until the plate leaves its support, then start the
        law from that sample with a lift-off reference. False while the plate is still down."""
        if not self.landed:
            self.landed = True
            self.window = None
            self.echoed = 0
            self.y_rest = np.array([xh[0], xh[2]])
            self.node.logger.info(f"the plate rests on its support ({xh[0] * 1e3:.3f} / {xh[2] * 1e3:.3f} mm): "
                                  "premagnetising; lift-off once the board applies our commands")
        ua = self.u_applied
        assert ua is not None
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
            self.ctrl = make_controller(self.cfg)
            self.ctrl.reset(xh.copy(), u_fit, accel)
            self.liftoff = (y, t, liftoff_duration(y, liftoff_target(self.y_rest, ref)[0]), np.array([xh[1], xh[3]]),
                            accel)
            self.lift_from = self.y_rest.copy()
            self.landed = False
            self.started = True
            self.counts["starts"] += 1
            self.counts["liftoffs"] += 1
            self.node.logger.info(f"off the support at {y[0] * 1e3:.3f} / {y[1] * 1e3:.3f} mm "
                                  f"({ua[0]:.1f} / {ua[1]:.1f} V): law {self.ctrl.name} started, lift-off to the "
                                  f"reference over {self.liftoff[2]:.2f} s")
            return True
        ramp = max(self.echoed - ECHO_SAMPLES, 0) * self.cfg["dt"] * RAMP_RATE
        _, self.u_premag = premagnetise(xh, self.cfg, min(PREMAG_FRACTION + ramp, RAMP_MAX))
        h = self.js.header(t)
        self.pub_cmd.publish(self.js.make(h, self.names, effort=clipped(self.u_premag, self.cfg["voltage_limit"])))
        self._state(t, age, 0.0, h)
        return False

    def _watch_resting(self, t: int, xh: np.ndarray) -> None:
        """Under the running law the plate rests on its support for RESTING_S: the board landed it (it ignores
        our commands now). Stop the law, so that it lifts off afresh when the board follows again."""
        if self.liftoff is not None or lift_fraction(xh, self.cfg) >= RESTING_FRACTION:
            self.resting_since = None
            return
        if self.resting_since is None:
            self.resting_since = t
        elif t - self.resting_since >= RESTING_S * 1e9:
            self._stop_law("the plate rests on its support under the running law (the board landed it): law "
                           "stopped; it lifts off when the board applies commands again")

    def _stop_law(self, why: str) -> None:
        """The board does not apply our commands (it landed the plate): stop the law (and any lift-off), so that it
        starts afresh - premagnetising, then lifting off - once the board applies commands again."""
        self.resting_since = None
        self.started = False
        self.liftoff = None
        self.ctrl = make_controller(self.cfg)
        self.counts["landed_stops"] += 1
        self.node.logger.warn(why)

    # -- reporting -------------------------------------------------------------
    def _state(self, t: int, age: float, fault: float, header=None) -> None:
        J = self.js
        values = self.ctrl.diag[:8].tolist()
        values += (age, fault, float(self.ref_lag))
        self.pub_state.publish(J.make(header if header is not None else J.header(t), self.names_state, values))

    def _warn_every(self, key: str, text: str) -> None:
        n = self.counts[key]
        if worth_logging(n):
            self.node.logger.warn(f"{text} ({n} so far)")

    def _diag_values(self) -> dict:
        """The once-a-second report: the counters, the law and its phase (``Diagnostics`` adds the rest)."""
        phase = ("running" if self.started else "premagnetised, waiting for the board" if self.landed
                 else "waiting to start")
        self.diag.set_condition(OK if self.started else WARN, f"{self.ctrl.name}: {phase}")
        return {**self.counts, "law": self.ctrl.name, "phase": phase, "lifting_off": self.liftoff is not None,
                "max_age_s": self.cfg["max_age"], "reference_max_speed_mm_s": round(self.checks.v_max * 1e3, 4),
                "ref_lag": self.ref_lag if math.isfinite(self.ref_lag) else "none"}


def main(args=None) -> int:
    return run_node("controller", ControllerNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
