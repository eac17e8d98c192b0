"""``controller``: the control laws of :mod:`dem_ros.core.controllers` at 1 kHz.

Triggered by ``/dem/state_estimate``: it looks up the reference of the same
stamp (published one period ahead; kept by stamp, so the arrival order of the
two topics does not matter), steps the law and publishes
``/dem/command`` (coil voltages) and ``/dem/controller/state`` with the
measurement's stamp. Before the law starts, the node holds the applied voltage
(``/dem/applied_voltage``) for ``hover_window`` seconds of pre-roll and
collects the estimates and voltages of that window; the law initialises from
it (:mod:`dem_ros.core.controllers.hover`, the same code as the offline
simulator). A sample of the experiment (t >= 0) ends the window early. A law
swapped during the run restarts from the current sample.

Safety: a sample older than ``max_age`` or with non-finite values is not acted
on (no command; the plant's watchdog takes over) and is counted; a law that
produces a non-finite voltage publishes nothing. Parameter changes (validated
as a whole by the schema) take effect at the next step; changing ``type``
swaps the law, restarted from the current sample.
"""

from __future__ import annotations

import sys

import numpy as np

from .. import contract
from ..core.controllers import make_controller
from ..core.warmup import warm_up
from ..transport import Node, run_node
from .common import JointStates, all_finite, clipped, diag_array, meas_into, stamp_ns

__all__ = ["ControllerNode", "main"]

REF_KEEP = 32  # reference samples kept by stamp


class ControllerNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("controller", self.on_change)
        self.ctrl = make_controller(self.cfg)
        self.started = False
        # reference samples by stamp, the newest REF_KEEP: stamp -> row of ref_ring, filled in place
        self.refs: dict[int, np.ndarray] = {}
        self.ref_ring = np.zeros((REF_KEEP + 1, 8))
        self.ref_next = 0
        self.xh = np.zeros(6)  # the estimate being acted on [d1, d1', d2, d2', i1, i2]
        self.u_applied: np.ndarray | None = None
        self.window: list[tuple[np.ndarray, np.ndarray]] | None = []  # hover window (estimate, applied voltage)
        self.window_n = max(round(self.cfg["hover_window"] / self.cfg["dt"]), 1)
        self.ref_lag = float("nan")
        self.counts = {"steps": 0, "stale": 0, "non_finite_input": 0, "non_finite_output": 0, "reference_mismatch": 0}
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.MAGNETS)  # shared by every message published (never modified)
        self.names_state = list(contract.CONTROLLER_STATE_NAMES)
        self.D = (node.msg("diagnostic_msgs/msg/DiagnosticArray"), node.msg("diagnostic_msgs/msg/DiagnosticStatus"),
                  node.msg("diagnostic_msgs/msg/KeyValue"))
        self.pub_cmd = node.publisher(contract.COMMAND)
        self.pub_state = node.publisher(contract.CONTROLLER_STATE)
        self.pub_diag = node.publisher(contract.DIAGNOSTICS)
        node.subscribe(contract.REFERENCE, self.on_reference)
        node.subscribe(contract.APPLIED, self.on_applied)
        node.subscribe(contract.ESTIMATE, self.on_estimate)
        node.timer(1.0, self.publish_diag)
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
        self.node.logger.info("parameters applied from the next step")
        return None

    # -- inputs --------------------------------------------------------------
    def on_reference(self, msg) -> None:
        if len(msg.position) >= 8:
            refs = self.refs
            if len(refs) >= REF_KEEP:
                del refs[next(iter(refs))]  # the oldest (its row is reused REF_KEEP + 1 samples later)
            row = self.ref_ring[self.ref_next]
            self.ref_next = (self.ref_next + 1) % (REF_KEEP + 1)
            row[:] = msg.position[:8]
            refs[stamp_ns(msg)] = row

    def _reference(self, t: int) -> tuple[np.ndarray | None, int]:
        """The reference for stamp ``t``, else the newest older one; (vector, stamp)."""
        ref = self.refs.get(t)
        if ref is not None:
            return ref, t
        older = [s for s in self.refs if s <= t]
        if older:
            s = max(older)
            return self.refs[s], s
        return None, -1

    def on_applied(self, msg) -> None:
        if len(msg.effort) >= 2:
            if self.u_applied is None:
                self.u_applied = np.zeros(2)
            self.u_applied[0] = msg.effort[0]
            self.u_applied[1] = msg.effort[1]

    def on_estimate(self, msg) -> None:
        t = stamp_ns(msg)
        age = (self.node.now_ns() - t) * 1e-9
        xh = self.xh
        meas_into(msg, xh)
        fault = 0.0
        if self.cfg["max_age"] > 0 and age > self.cfg["max_age"]:
            self.counts["stale"] += 1
            self._warn_every("stale", f"sample {age * 1e3:.2f} ms old (> max_age): not acted on")
            return self._state(t, age, 1.0)
        if not all_finite(xh):
            self.counts["non_finite_input"] += 1
            self._warn_every("non_finite_input", "non-finite input: not acted on")
            return self._state(t, age, 1.0)
        ref, ref_stamp = self._reference(t)
        if ref is None:  # first sample before any reference: hold the measured hover
            ref = np.array([xh[0], xh[2], 0, 0, 0, 0, 0, 0], dtype=float)
            self.ref_lag = float("nan")
        else:
            self.ref_lag = round((t - ref_stamp) / (self.cfg["dt"] * 1e9))
        if self.ref_lag != 0:
            self.counts["reference_mismatch"] += 1
        if not self.started:
            u0 = self.u_applied.copy() if self.u_applied is not None else np.zeros(2)
            if self.window is not None and self.u_applied is not None:
                self.window.append((xh.copy(), u0))
                if len(self.window) < self.window_n and msg.header.frame_id == contract.FRAME_PREROLL:
                    h = self.js.header(t)
                    self.pub_cmd.publish(self.js.make(h, self.names, effort=u0))  # hold the hover meanwhile
                    return self._state(t, age, fault, h)
                Zw = np.array([z for z, _ in self.window])
                Uw = np.array([u for _, u in self.window])
                self.window = None
            else:  # swapped mid-run, or no applied voltage seen yet: this sample alone
                Zw, Uw = xh.copy(), u0
            self.ctrl.reset(Zw, Uw)
            self.started = True
        u = self.ctrl.step(xh, ref)
        self.counts["steps"] += 1
        if not all_finite(u) or self.ctrl.diag[-1] > 0:
            self.counts["non_finite_output"] += 1
            self._warn_every("non_finite_output", "the law produced no valid voltage: no command sent")
            return self._state(t, age, 1.0)
        lim = self.cfg["voltage_limit"]
        h = self.js.header(t)
        self.pub_cmd.publish(self.js.make(h, self.names, effort=clipped(u, lim)))
        self._state(t, age, fault, h)

    def _state(self, t: int, age: float, fault: float, header=None) -> None:
        J = self.js
        values = self.ctrl.diag[:8].tolist()
        values += (age, fault, float(self.ref_lag))
        self.pub_state.publish(J.make(header if header is not None else J.header(t), self.names_state, values))

    def _warn_every(self, key: str, text: str) -> None:
        n = self.counts[key]
        if n in (1, 10, 100, 1000) or n % 10000 == 0:
            self.node.logger.warn(f"{text} ({n} so far)")

    def publish_diag(self) -> None:
        bad = self.counts["stale"] + self.counts["non_finite_input"] + self.counts["non_finite_output"]
        self.pub_diag.publish(diag_array(*self.D, self.node.now_ns(), "controller", 1 if bad else 0,
                                         f"{self.ctrl.name}", {**self.counts, "law": self.ctrl.name}))


def main(args=None) -> int:
    return run_node("controller", ControllerNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
