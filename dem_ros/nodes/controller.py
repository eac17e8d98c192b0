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

Start and restart (a controller started mid-run, a law swapped during the run, a plate resting on its support,
a board that landed it under a running law): :class:`~dem_ros.core.controllers.sequence.ControlSequence`, which
this node feeds with every estimate it acts on and every applied voltage it takes; nothing is commanded before the
plant's applied voltage has been seen.

Parameter changes (validated as a whole by the schema) take effect at the next
step; changing ``type`` swaps the law, restarted from the current sample.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from .. import contract
from ..core.controllers.checks import InputChecks
from ..core.controllers.sequence import HOLD, LAW, ControlSequence
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
#: counters that make the once-a-second diagnostics WARN when they grew
_WARN_KEYS = ("stale", "future", "non_finite_input", "non_finite_output", "reference_range", "reference_rate",
              "reference_future", "reference_invalid", "reference_held", "waiting_for_applied", "plant_stamp_jump",
              "estimate_repeated")


class ControllerNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("controller", self.on_change)
        self.seq = ControlSequence(self.cfg, info=node.logger.info, warn=node.logger.warn)
        self.checks = InputChecks(self.cfg)
        # reference samples by stamp, the newest REF_KEEP: stamp -> row of ref_ring, filled in place
        self.refs: dict[int, np.ndarray] = {}
        self.ref_ring = np.zeros((REF_KEEP + 1, 8))
        self.ref_next = 0
        self.xh = np.zeros(6)  # the estimate being acted on [d1, d1', d2, d2', i1, i2]
        self.u_applied: np.ndarray | None = None
        self.ref_lag = float("nan")
        self.counts = dict.fromkeys(("steps", "stale", "future", "non_finite_input", "non_finite_output",
                                     "reference_mismatch", "reference_range", "reference_rate", "reference_future",
                                     "reference_invalid", "reference_held", "waiting_for_applied",
                                     "plant_stamp_jump", "estimate_repeated"), 0)
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
        self.seq.configure(values)
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
            self.seq.applied(msg.effort)

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
        step = self.seq.step(t, xh, self.u_applied, self._reference(t), msg.header.frame_id == contract.FRAME_PREROLL)
        if step.kind == HOLD and step.u is not None:  # the hover window fills: hold the applied voltage
            h = self.js.header(t)
            self.pub_cmd.publish(self.js.make(h, self.names, effort=step.u.tolist()))
            return self._state(t, age, 0.0, h)
        if step.kind == LAW:
            self.counts["steps"] += 1
        if step.u is None:
            self.counts["non_finite_output"] += 1
            self._warn_every("non_finite_output", "the law produced no valid voltage: no command sent")
            return self._state(t, age, 1.0)
        h = self.js.header(t)
        self.pub_cmd.publish(self.js.make(h, self.names, effort=clipped(step.u, self.cfg["voltage_limit"])))
        self._state(t, age, 0.0, h)

    # -- reporting -------------------------------------------------------------
    def _state(self, t: int, age: float, fault: float, header=None) -> None:
        J = self.js
        values = self.seq.law.diag[:8].tolist()
        values += (age, fault, float(self.ref_lag))
        self.pub_state.publish(J.make(header if header is not None else J.header(t), self.names_state, values))

    def _warn_every(self, key: str, text: str) -> None:
        n = self.counts[key]
        if worth_logging(n):
            self.node.logger.warn(f"{text} ({n} so far)")

    def _diag_values(self) -> dict:
        """The once-a-second report: the counters, the law and its phase (``Diagnostics`` adds the rest)."""
        seq = self.seq
        phase = seq.phase
        self.diag.set_condition(OK if seq.started else WARN, f"{seq.law.name}: {phase}")
        return {**self.counts, **seq.counts, "law": seq.law.name, "phase": phase,
                "lifting_off": seq.liftoff is not None, "max_age_s": self.cfg["max_age"],
                "reference_max_speed_mm_s": round(self.checks.v_max * 1e3, 4),
                "ref_lag": self.ref_lag if math.isfinite(self.ref_lag) else "none"}


def main(args=None) -> int:
    return run_node("controller", ControllerNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
