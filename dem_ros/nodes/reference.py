"""``reference``: the reference model M(s) (Eq. 46) driven by the command schedule.

The schedule's t = 0 is the stamp of the first measurement of the experiment
(``frame_id == "dem"``); before it (pre-roll) the model rests where the plate
hovers (:func:`dem_ros.core.reference.hover_start` of the pre-roll's measured
gaps so far; the offline simulator starts from the same) and at t = 0 it
starts from there. On measurement k it
publishes the reference for sample k+1 (stamped t_k + T), one period ahead, so
the controller has it when measurement k+1 arrives; on the first measurement it
also publishes sample 0. Lost measurements are caught up sample by sample, so
the sequence is the offline simulator's exactly.

Implausible measurements are refused (counted, logged once a second), never acted on: fewer than two
gaps, a stamp more than ``FUTURE_S`` ahead of this node's clock (a rogue or broken clock: a +1 h stamp
would otherwise make the node compute an hour of reference before it answers again), or a jump of
more than ``MAX_CATCH_UP_S`` past the schedule at once.
"""

from __future__ import annotations

import sys

import numpy as np

from .. import contract
from ..core.reference import ReferenceModel, command, hover_start
from ..core.warmup import warm_up
from ..transport import Node, run_node
from .common import JointStates, stamp_ns

__all__ = ["ReferenceNode", "main"]

FUTURE_S = 1.0  # stamps may lead this node's clock by transport jitter, never by a second
MAX_CATCH_UP_S = 10.0  # lost measurements are caught up sample by sample, at most this much at once


class ReferenceNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("reference", self.on_change)
        self.model = ReferenceModel(self.cfg)
        self.dt_ns = round(self.cfg["dt"] * 1e9)
        self.epoch: int | None = None
        self.pre_seen = False
        self.pre_gaps: list[tuple[float, float]] = []  # measured gaps of the pre-roll
        self.next_k = 0
        self.refused = 0
        self._last_warn = 0
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.REFERENCE_NAMES)  # shared by every message published (never modified)
        self.pub = node.publisher(contract.REFERENCE)
        node.subscribe(contract.MEASUREMENT, self.on_measurement)
        node.logger.info("ready")

    def on_change(self, values) -> str | None:
        for key in ("a0", "a1", "a2", "b0"):
            if values[key] != self.cfg[key]:
                return "the reference model (a0, a1, a2, b0) cannot change during a run"
        self.cfg = dict(values)  # schedule changes act from the next sample
        return None

    def _publish_upto(self, k_last: int) -> None:
        assert self.epoch is not None  # set by the first measurement
        while self.next_k <= k_last:
            t = self.next_k * self.cfg["dt"]
            r = command(self.cfg, t)
            y = self.model.step(r)
            self._send(self.epoch + self.next_k * self.dt_ns, y.tolist() + np.asarray(r, float).tolist())
            self.next_k += 1

    def _send(self, t_ns: int, vec: list[float], frame: str = contract.FRAME) -> None:
        """Publish [y_d (8), r (2)] stamped ``t_ns`` (see ``contract.REFERENCE_NAMES``)."""
        self.pub.publish(self.js.make(self.js.header(t_ns, frame), self.names, vec))

    def _refuse(self, why: str) -> None:
        self.refused += 1
        now = self.node.now_ns()
        if now - self._last_warn > 1_000_000_000:
            self._last_warn = now
            self.node.logger.warn(f"measurement refused ({self.refused} so far): {why}")

    def on_measurement(self, msg) -> None:
        t = stamp_ns(msg)
        if len(msg.position) < 2:
            self._refuse(f"{len(msg.position)} gaps, expected 2")
            return
        if t - self.node.now_ns() > FUTURE_S * 1e9:
            self._refuse(f"stamp {(t - self.node.now_ns()) * 1e-9:.3g} s in the future")
            return
        if self.epoch is None and msg.header.frame_id == contract.FRAME_PREROLL:
            # levitating before t = 0: the model rests where the plate hovers
            self.pre_gaps.append((float(msg.position[0]), float(msg.position[1])))
            self.model.reset(hover_start(np.array(self.pre_gaps)))
            y = self.model.step_hold()
            r = command(self.cfg, -1.0)
            vec = y.tolist() + np.asarray(r, float).tolist()
            if not self.pre_seen:
                self.pre_seen = True
                self._send(t, vec, contract.FRAME_PREROLL)
            self._send(t + self.dt_ns, vec, contract.FRAME_PREROLL)
            return
        if self.epoch is None:
            self.epoch = t
            if self.pre_gaps:
                self.model.reset(hover_start(np.array(self.pre_gaps)))
            if self.pre_seen:
                self.next_k = 1  # sample 0 went out with the last pre-roll sample (the model at rest)
        k = round((t - self.epoch) / self.dt_ns)
        if k + 1 - self.next_k > MAX_CATCH_UP_S / self.cfg["dt"]:
            self._refuse(f"stamp {(k + 1 - self.next_k) * self.cfg['dt']:.3g} s past the schedule at once")
            return
        self._publish_upto(k + 1)


def main(args=None) -> int:
    return run_node("reference", ReferenceNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
