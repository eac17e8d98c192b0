"""``reference``: the reference model M(s) (Eq. 46) driven by the command schedule.

The schedule is anchored to the experiment clock: its t = 0 is the plant's sample 0 (the stamp
of the first measurement with ``frame_id == "dem"``; the plant, or the hardware driver, also
reports it as ``epoch_ns`` in its loop status on ``/diagnostics``). Before it (pre-roll) the
model rests where the plate hovers (:func:`dem_ros.core.reference.hover_start` of the last
``PREROLL_KEEP`` pre-roll gaps; the offline simulator starts from the same) and at t = 0 it
starts from there. On measurement k it publishes the reference for sample k+1 (stamped
t_k + T), one period ahead, so the controller has it when measurement k+1 arrives; on the
first measurement it also publishes sample 0. Lost measurements are caught up sample by
sample, so the sequence is the offline simulator's exactly.

A reference (re)started after t = 0 has not seen the epoch: it holds the model at rest where
the plate is (the first measured gaps) until the plant's loop status gives ``epoch_ns``, then
resumes the schedule at the sample the plant is at (t = stamp - epoch), gliding from there
through M(s): the step times stay those of the experiment, never re-based to the restart.

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
from .common import OK, PLANT_SOURCES, WARN, Diagnostics, Inputs, JointStates, stamp_ns

__all__ = ["ReferenceNode", "main"]

PREROLL_KEEP = 1000  # pre-roll gaps whose median is the rest (1 s: the default pre-roll; bounded per sample)
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
        self.pre_gaps = np.zeros((PREROLL_KEEP, 2))  # measured gaps of the pre-roll: a ring of the newest
        self.pre_n = 0
        self.plant_epoch: int | None = None  # t = 0 as the plant reports it (loop status epoch_ns)
        self.resting_at: np.ndarray | None = None  # restarted after t = 0: the gaps the model rests at
        self.next_k = 0
        self.refused = 0
        self._last_warn = 0
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.REFERENCE_NAMES)  # shared by every message published (never modified)
        # /diagnostics "reference: schedule" once a second: WARN after refused measurements and while resting after
        # a restart; with "reference: /dem/reference topic status"
        self.diag = Diagnostics(node, contract.REFERENCE_STATUS, warn_on=("refused",), values=self._diag_values)
        self.pub = self.diag.diagnosed(contract.REFERENCE)
        # the plant's measurement, bound to the plant's (or the driver's) writer (docs/manual/trust.md)
        self.inputs = Inputs(node)
        self.inputs.bind(contract.MEASUREMENT, PLANT_SOURCES, self.on_measurement)
        node.subscribe(contract.DIAGNOSTICS, self.on_diagnostics)
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

    def _diag_values(self) -> dict:
        resting = self.epoch is None and self.resting_at is not None
        self.diag.set_condition(WARN if resting else OK, "restarted after t = 0: resting until the plant's epoch is"
                                " known" if resting else "schedule" if self.epoch is not None else "pre-roll")
        t = (self.next_k - 1) * self.cfg["dt"] if self.epoch is not None else None
        return {"refused": self.refused, "schedule_t_s": "none" if t is None else round(t, 3),
                "epoch_ns": self.epoch if self.epoch is not None else "none"}

    def _refuse(self, why: str) -> None:
        self.refused += 1
        now = self.node.now_ns()
        if now - self._last_warn > 1_000_000_000:
            self._last_warn = now
            self.node.logger.warn(f"measurement refused ({self.refused} so far): {why}")

    def on_diagnostics(self, msg) -> None:
        """The plant's (or the hardware driver's) loop status carries the experiment's t = 0 (``epoch_ns``)."""
        for st in msg.status:
            if st.name in (contract.LOOP_STATUS, contract.HW_LOOP_STATUS):
                for kv in st.values:
                    if kv.key == "epoch_ns":
                        try:
                            self.plant_epoch = int(kv.value)
                        except ValueError:
                            self._refuse(f"loop status epoch_ns {kv.value[:40]!r} is not an integer")

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
            row = self.pre_gaps[self.pre_n % PREROLL_KEEP]
            row[0], row[1] = msg.position[0], msg.position[1]
            self.pre_n += 1
            self.model.reset(hover_start(self.pre_gaps[: min(self.pre_n, PREROLL_KEEP)]))
            y = self.model.step_hold()
            r = command(self.cfg, -1.0)
            vec = y.tolist() + np.asarray(r, float).tolist()
            if not self.pre_seen:
                self.pre_seen = True
                self._send(t, vec, contract.FRAME_PREROLL)
            self._send(t + self.dt_ns, vec, contract.FRAME_PREROLL)
            return
        if self.epoch is None and not self.pre_seen and not self._resume(t, msg):
            return  # (re)started after t = 0: resting until the plant's epoch is known
        if self.epoch is None:
            self.epoch = t
            if self.pre_n:
                self.model.reset(hover_start(self.pre_gaps[: min(self.pre_n, PREROLL_KEEP)]))
            if self.pre_seen:
                self.next_k = 1  # sample 0 went out with the last pre-roll sample (the model at rest)
        k = round((t - self.epoch) / self.dt_ns)
        if k + 1 - self.next_k > MAX_CATCH_UP_S / self.cfg["dt"]:
            self._refuse(f"stamp {(k + 1 - self.next_k) * self.cfg['dt']:.3g} s past the schedule at once")
            return
        self._publish_upto(k + 1)

    def _resume(self, t: int, msg) -> bool:
        """Started after t = 0: rest at the measured gaps until the plant's epoch is known, then resume the
        schedule at this sample (True)."""
        if self.resting_at is None:
            self.resting_at = np.array([float(msg.position[0]), float(msg.position[1])])
            self.model.reset(self.resting_at)
            self.diag.set_condition(WARN, "resting at the measured gaps until the plant reports t = 0")
            self.node.logger.warn(f"started after t = 0: resting at the measured {self.resting_at[0] * 1e3:.3f} /"
                                  f" {self.resting_at[1] * 1e3:.3f} mm until the plant reports the experiment's t = 0")
        epoch = self.plant_epoch
        if epoch is None or t < epoch:
            y = self.model.step_hold()
            self._send(t + self.dt_ns, y.tolist() + self.model.r_rest.tolist())
            return False
        self.epoch = epoch
        self.diag.set_condition(0)
        self.next_k = round((t - epoch) / self.dt_ns) + 1
        self.node.logger.info(f"resumed the schedule at t = {(t - epoch) * 1e-9:.3f} s of the experiment"
                              " (epoch from the plant's loop status), gliding from the measured gaps")
        return True


def main(args=None) -> int:
    return run_node("reference", ReferenceNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
