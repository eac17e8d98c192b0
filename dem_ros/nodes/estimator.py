"""``estimator``: the EKF of :mod:`dem_ros.core.estimator` between sensors and controller.

On each ``/dem/measurement`` it takes the voltage applied over the last sample
(``/dem/applied_voltage`` of the same stamp; the two topics may arrive in either
order, so a measurement whose voltage is not there yet waits for it, at most
until the next measurement), runs one predict/update and
publishes ``/dem/state_estimate`` with the measurement's stamp. Gap rates are
used when the sensors deliver them (a non-empty ``velocity``). Non-finite
sensor values are skipped by the update (counted); type ``none`` passes the
measurement through.
"""

from __future__ import annotations

import sys

import numpy as np

from .. import contract
from ..core.estimator import Estimator, make_estimator
from ..core.warmup import warm_up
from ..transport import Node, run_node
from .common import JointStates, all_finite, meas_into, stamp_ns

__all__ = ["EstimatorNode", "main"]

KEEP = 32  # applied voltages kept by stamp


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
        self.pending = None  # a measurement waiting for its applied voltage
        self.bad = 0
        self.unpaired = 0  # measurements processed without the voltage of their stamp
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.MAGNETS)  # shared by every message published (never modified)
        self.pub = node.publisher(contract.ESTIMATE)
        node.subscribe(contract.APPLIED, self.on_applied)
        node.subscribe(contract.MEASUREMENT, self.on_measurement)
        node.logger.info("ready")

    def on_change(self, values) -> str | None:
        self.cfg = dict(values)
        self.est = None  # rebuilt (and restarted) at the next measurement
        return None

    def on_applied(self, msg) -> None:
        if len(msg.effort) >= 2:
            t = stamp_ns(msg)
            volts = self.volts
            if len(volts) >= KEEP:
                del volts[next(iter(volts))]  # the oldest (its row is reused KEEP + 1 samples later)
            u = self.u_ring[self.u_next]
            self.u_next = (self.u_next + 1) % (KEEP + 1)
            e = msg.effort
            u[0] = e[0]
            u[1] = e[1]
            volts[t] = self.u_prev = u
            pending = self.pending
            if pending is not None and stamp_ns(pending) == t:
                self.pending = None
                self._step(pending)

    def on_measurement(self, msg) -> None:
        if self.pending is not None:  # its voltage never came: go on with the latest one
            self.unpaired += 1
            if self.unpaired in (1, 10, 100, 1000):
                self.node.logger.warn(f"measurement without the applied voltage of its stamp ({self.unpaired} so far)")
            pending, self.pending = self.pending, None
            self._step(pending)
        if self.u_prev is not None and stamp_ns(msg) not in self.volts:
            self.pending = msg  # the voltage of this sample is still on its way
            return
        self._step(msg)

    def _step(self, msg) -> None:
        z = self.z
        has_v = meas_into(msg, z)
        if not all_finite(z):
            self.bad += 1
            if self.bad in (1, 10, 100, 1000):
                self.node.logger.warn(f"non-finite measurement ({self.bad} so far): skipped by the filter")
        if self.est is None or has_v != self.has_v:
            self.est = make_estimator(self.cfg, None, has_v)
            self.has_v = has_v
        t = stamp_ns(msg)
        u = self.volts.get(t, self.u_prev)
        x = self.est.step(z, u if u is not None else self.u_zero).tolist()
        J = self.js
        self.pub.publish(J.make(J.header(t), self.names, [x[0], x[2]], [x[1], x[3]], [x[4], x[5]]))


def main(args=None) -> int:
    return run_node("estimator", EstimatorNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
