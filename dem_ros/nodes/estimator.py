"""``estimator``: the EKF of :mod:`dem_ros.core.estimator` between sensors and controller.

On each ``/dem/measurement`` it takes the voltage applied over the last sample
(``/dem/applied_voltage`` of the same stamp; the two topics may arrive in either
order, so a measurement whose voltage is not there yet waits for it, in stamp order
with the measurements after it, until a voltage of its stamp or a later one arrives or
``PENDING_MAX`` wait; a link that delivers a burst of samples, taken topic by topic,
hands over several measurements before their voltages; before the first voltage every
measurement waits, the oldest dropped: the filter never steps on a voltage it does not
know), runs one predict/update and
publishes ``/dem/state_estimate`` with the measurement's stamp. Gap rates are
used when the first measurement delivers them (a non-empty ``velocity``; a later
one without them updates without rates). Type ``none`` passes the measurement through.

Plausibility (the math is :mod:`dem_ros.core.estimator`'s): each gap is gated by the sensor's
range and by a chi^2 test on its innovation; a rejected sample holds the prediction, is counted
and reported (WARN); ``fault_samples`` rejections in a row, or an acceleration bias beyond
``bias_max`` that long, declare a sensor fault (latched ERROR on ``/diagnostics``, status
``estimator``; estimates go on from the other sensor, the currents and the model). A
measurement with fewer than two gaps or currents is dropped and counted.

Convergence: after a (re)start the node publishes no estimate until the filter has converged
(:attr:`KalmanEstimator.converged`: the start confirmed by the next sample passing every gate, and
without measured rates ``converge_samples`` samples in a row passing them); a start on a pre-roll
sample (frame ``dem/preroll``) publishes as soon as the start is confirmed: before t = 0 the plate
hovers in equilibrium, where the filter's start (rates 0, no bias) is right. When the confirming
sample is the one that begins publishing (rates measured, or a pre-roll start), the start's own
estimate (its measurement) goes out first, just before that sample's: no sample is left without an
estimate, which a lockstep plant needs (it waits for the command of every sample: a withheld first
sample would stall it until ``lockstep_timeout`` and land the plate). A start the next sample does not
confirm (an in-range spike) is never published: the filter starts again from that sample. Parameter
changes retune the running filter (no restart); ``type`` cannot change during a run.
"""

from __future__ import annotations

import math
import sys
from collections import deque

import numpy as np

from .. import contract
from ..core.estimator import Estimator, KalmanEstimator, make_estimator
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
    meas_into,
    stamp_ns,
    worth_logging,
)

__all__ = ["EstimatorNode", "main"]

KEEP = 32  # applied voltages kept by stamp
#: measurements that may wait for their applied voltages (a burst from the hw_driver's link: its frames
#: arrive together and the executor takes the topics one after the other, measurements before voltages)
PENDING_MAX = 8


class EstimatorNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("estimator", self.on_change)
        self.est: Estimator | None = None
        self.has_v: bool | None = None
        self.u_prev: np.ndarray | None = None  # the newest applied voltage (a row of ``u_ring``)
        # applied voltages by stamp, the newest KEEP: stamp -> row of u_ring (V), filled in place
        self.volts: dict[int, np.ndarray] = {}
        self.u_ring = np.zeros((KEEP + 1, 2))
        self.u_next = 0
        self.z = np.zeros(6)  # the measurement being processed [d1, d1', d2, d2', i1, i2]
        self.u_zero = np.zeros(2)
        self.pending: deque = deque()  # measurements waiting for their applied voltages, oldest first
        # stamps of the newest KEEP measurements taken: the plant sends each stamp once, a repeat is not its
        self.measured: dict[int, None] = {}
        self.publishing = False  # the filter has converged since its (re)start (or started in the pre-roll)
        self.preroll_start = False  # the filter started on a pre-roll sample: published once the start is confirmed
        self.start: tuple[int, list[float]] | None = None  # (stamp, estimate) of the start awaiting its confirmation
        # /diagnostics "estimator: filter", once a second: WARN after rejected or dropped samples, ERROR on a sensor
        # fault; with "estimator: /dem/state_estimate topic status"
        gates = [f"gap{j}_{why}" for j in (1, 2) for why in ("out_of_range", "innovation")]
        self.diag = Diagnostics(node, contract.ESTIMATOR_STATUS, values=self._values,
                                warn_on=(*gates, "malformed", "non_finite", "unpaired", "updates_skipped",
                                         "reinitialised", "repeated"))
        self.counts = self.diag.counters
        self.counts.update(measurements=0, published=0, withheld=0, malformed=0, non_finite=0, unpaired=0, restarts=0,
                           repeated=0)
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.MAGNETS)  # shared by every message published (never modified)
        self.pub = self.diag.diagnosed(contract.ESTIMATE)
        # the plant's streams, each bound to the plant's (or the driver's) writer (docs/manual/trust.md)
        self.inputs = Inputs(node)
        self.inputs.bind(contract.APPLIED, PLANT_SOURCES, self.on_applied)
        self.inputs.bind(contract.MEASUREMENT, PLANT_SOURCES, self.on_measurement)
        node.logger.info("ready")

    def on_change(self, values) -> str | None:
        if values["type"] != self.cfg["type"]:
            return "the estimator type cannot change during a run (a new filter would have to re-converge)"
        self.cfg = dict(values)
        if isinstance(self.est, KalmanEstimator):
            self.est.configure(values)  # the running filter takes the new settings; state and covariance stay
        return None

    def _values(self) -> dict:
        est = self.est
        out: dict = {"type": self.cfg["type"], "converged": self.publishing}
        if isinstance(est, KalmanEstimator):
            out.update(est.counters())
            out["faults"] = "; ".join(est.faults)
        return out

    def _repeated(self, what: str) -> None:
        """A second sample with a stamp already taken: the plant sends each once, so it is someone else's (a
        foreign or corrupt writer); the first stays, this one is counted (one 4 V 'voltage' taken at hover put
        the filter 5 mm off and the plate on its support: `dem-ros faults`, bad-cdr)."""
        n = self.diag.count("repeated")
        if worth_logging(n):
            self.node.logger.warn(f"{what} with a stamp already taken: dropped, the first one stays ({n} so far)")

    def on_applied(self, msg) -> None:
        if len(msg.effort) >= 2:
            t = stamp_ns(msg)
            volts = self.volts
            if t in volts:
                return self._repeated("applied voltage")
            if len(volts) >= KEEP:
                del volts[next(iter(volts))]  # the oldest (its row is reused KEEP + 1 samples later)
            u = self.u_ring[self.u_next]
            self.u_next = (self.u_next + 1) % (KEEP + 1)
            e = msg.effort
            u[0] = e[0]
            u[1] = e[1]
            volts[t] = self.u_prev = u
            pending = self.pending
            while pending and stamp_ns(pending[0]) <= t:  # voltages come in stamp order: none older will
                self._release(pending.popleft(), t)
            if len(pending) > 1 and stamp_ns(pending[-1]) <= t:
                # the head waits for a voltage from far ahead (a rogue or corrupt stamp): it must not hold
                # back the measurements behind it whose voltages came (arrival order = stamp order)
                for m in [m for m in pending if stamp_ns(m) <= t]:
                    pending.remove(m)
                    self._release(m, t)

    def _release(self, m, t: int) -> None:
        """Step a waiting measurement now that the voltage stamped ``t`` came (its own, or a later one)."""
        if stamp_ns(m) != t and stamp_ns(m) not in self.volts:
            self._unpaired()
        self._step(m)

    def on_measurement(self, msg) -> None:
        if len(msg.position) < 2 or len(msg.effort) < 2:
            n = self.diag.count("malformed")
            if n in (1, 10, 100, 1000):
                self.node.logger.warn(f"measurement with {len(msg.position)} gaps and {len(msg.effort)} currents"
                                      f" dropped, expected 2 each ({n} so far)")
            return
        pending = self.pending
        t = stamp_ns(msg)
        measured = self.measured
        if t in measured:
            return self._repeated("measurement")
        if len(measured) >= KEEP:
            del measured[next(iter(measured))]
        measured[t] = None
        if self.u_prev is None:
            # no voltage seen yet (the measurement's writer was bound first; one process per node binds the
            # topics in the order their first samples come): the filter never steps on a voltage it does not
            # know. Stepped with 0 V, a hovering plate's currents were predicted to collapse, both gaps failed
            # the innovation gate 20 times in a row and the latched sensor fault left a model-only estimate
            # 4 mm off when the law started (the rig, a process per node: the board landed the plate at t = 0)
            if len(pending) >= PENDING_MAX:
                pending.popleft()
                self.counts["withheld"] += 1
            pending.append(msg)
            return
        # wait for its voltage, or behind an older one waiting (a later-stamped one waiting - a rogue stamp far
        # ahead - holds nothing back)
        if t not in self.volts or (pending and any(stamp_ns(m) < t for m in pending)):
            if len(pending) >= PENDING_MAX:  # the oldest one's voltage never came: go on with the latest one
                self._unpaired()
                self._step(pending.popleft())
            pending.append(msg)  # the voltage of this sample (or of one before it) is still on its way
            return
        self._step(msg)

    def _unpaired(self) -> None:
        n = self.diag.count("unpaired")
        if n in (1, 10, 100, 1000):
            self.node.logger.warn(f"measurement without the applied voltage of its stamp ({n} so far)")

    def _step(self, msg) -> None:
        z = self.z
        has_v = meas_into(msg, z)
        counts = self.counts
        counts["measurements"] += 1
        if not all_finite(z):
            n = self.diag.count("non_finite")
            if n in (1, 10, 100, 1000):
                self.node.logger.warn(f"non-finite measurement ({n} so far): skipped by the filter")
        if self.est is None:  # (re)start: rates are used when the first measurement has them
            self.est = make_estimator(self.cfg, None, has_v)
            self.has_v = has_v
            self.publishing = not isinstance(self.est, KalmanEstimator)
            counts["restarts"] += 1
        elif self.has_v and not has_v:
            z[1] = z[3] = math.nan  # this sample has no rates: the update goes on without them
        t = stamp_ns(msg)
        u = self.volts.get(t, self.u_prev)
        est = self.est
        kf = est if isinstance(est, KalmanEstimator) else None
        started, confirmed = (kf.started, kf.confirmed) if kf is not None else (False, False)
        restarts = kf.unconfirmed_starts if kf is not None else 0
        x = est.step(z, u if u is not None else self.u_zero).tolist()
        if kf is not None:
            if not started and kf.started:
                self.preroll_start = msg.header.frame_id == contract.FRAME_PREROLL
            if self.preroll_start and kf.confirmed and not self.publishing:
                self.publishing = True  # started in the pre-roll: the plate hovers in equilibrium, as the filter starts
                self.diag.set_condition(OK)  # no longer "converging"
            self._check(kf)
            start, self.start = self.start, None
            if not kf.confirmed and (not started or kf.unconfirmed_starts != restarts):
                self.start = (t, x)  # this sample (re)started the filter: it goes out once the next one confirms it
            elif kf.confirmed and not confirmed and start is not None and self.publishing:
                # the start, confirmed by this sample, goes out first (its estimate is its measurement): every
                # sample gets its estimate, which a lockstep plant needs (it waits for the command of each)
                counts["withheld"] -= 1
                self._publish(*start)
        if not self.publishing:
            counts["withheld"] += 1
            return
        self._publish(t, x)

    def _publish(self, t: int, x: list[float]) -> None:
        self.counts["published"] += 1
        J = self.js
        self.pub.publish(J.make(J.header(t), self.names, [x[0], x[2]], [x[1], x[3]], [x[4], x[5]]))

    def _check(self, est: KalmanEstimator) -> None:
        """Convergence (publish from then on) and sensor faults (latched ERROR), reported once each."""
        if not self.publishing:
            if est.converged:
                self.publishing = True
                self.diag.set_condition(OK)
                self.node.logger.info(f"converged after {self.counts['withheld']} samples: publishing estimates")
            else:
                self.diag.set_condition(WARN, "converging: no estimate published yet")
        if est.faulty and self.diag.faulted is None:
            self.diag.fault("; ".join(est.faults))


def main(args=None) -> int:
    return run_node("estimator", EstimatorNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
