"""``plant_sim``: the simulated DEM, ticking at 1 kHz against absolute deadlines.

At tick k (stamp t_k = epoch + k T) it applies the command computed from the
measurement of tick k-1 (zero-order hold over [t_k-1, t_k)), integrates, and
publishes ``/dem/applied_voltage``, ``/dem/plant/truth`` and ``/dem/measurement``
stamped t_k. A command that has not arrived by its tick is a counted deadline
miss: the last command is held, and after ``command_timeout`` the coils get
0 V (watchdog). Latency = receive time of the command - stamp of the
measurement it answers. A hardware driver replaces this node by honouring the
same topics.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from .. import contract
from ..core.plant import DemPlant
from ..core.warmup import warm_up
from ..transport import Node, run_node
from .common import LatencyStats, diag_array, joint_state, named_vector, stamp_ns

__all__ = ["PlantSimNode", "main"]


class PlantSimNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("plant_sim", self.on_change)
        c = self.cfg
        self.dt_ns = int(round(c["dt"] * 1e9))
        self.plant = DemPlant(c, c["duration"])
        self.n_end = int(round(c["duration"] / c["dt"])) if c["duration"] > 0 else 0
        warm_up()  # kernels resident before we subscribe (no stale first samples)
        JS = node.msg("sensor_msgs/msg/JointState")
        self.JS = JS
        self.pub_meas = node.publisher(contract.MEASUREMENT)
        self.pub_truth = node.publisher(contract.TRUTH)
        self.pub_applied = node.publisher(contract.APPLIED)
        self.pub_diag = node.publisher(contract.DIAGNOSTICS)
        self.D = (node.msg("diagnostic_msgs/msg/DiagnosticArray"), node.msg("diagnostic_msgs/msg/DiagnosticStatus"),
                  node.msg("diagnostic_msgs/msg/KeyValue"))
        node.subscribe(contract.COMMAND, self.on_command)
        self.cmd_ring = np.full(64, -1, dtype=np.int64)  # stamp of the command held in each slot
        self.cmd_u = np.zeros((64, 2))
        self.u_applied = self.plant.u0.copy()
        self.last_fresh_ns = 0
        self.started = False
        self.finished = False
        self.k_next = 0
        self.t_boot = time.monotonic()
        self.epoch = 0
        self.misses = 0
        self.watchdog = 0
        self.lat = LatencyStats()
        self.tick_late = LatencyStats()
        self.tick_cost = LatencyStats()
        self.last_status = 0.0
        self.timer = node.timer(c["dt"], self.tick)
        node.timer(1.0, self.status)

    def on_change(self, values) -> str | None:
        for key in ("dt", "substeps", "command_delay", "duration"):
            if values[key] != self.cfg[key]:
                return f"{key} cannot change during a run"
        self.cfg = dict(values)
        self.plant.pc.update(values)  # disturbances and noise act from the next tick
        return None

    def on_command(self, msg) -> None:
        t = stamp_ns(msg)
        if len(msg.effort) < 2:
            return
        u = np.array(msg.effort[:2], dtype=float)
        if not np.all(np.isfinite(u)):
            self.node.logger.warn("non-finite command ignored")
            return
        if not self.started:
            return
        j = int(round((t - self.epoch) / self.dt_ns)) % self.cmd_ring.size
        self.cmd_ring[j] = t
        self.cmd_u[j] = u
        self.lat.add(self.node.now_ns() - t)

    def _ready(self) -> bool:
        c = self.cfg
        waited = time.monotonic() - self.t_boot
        if waited < c["start_delay"]:
            return False
        count = getattr(self.pub_meas, "subscription_count", None)
        if callable(count):
            count = count()
        if count is None and hasattr(self.pub_meas, "get_subscription_count"):
            count = self.pub_meas.get_subscription_count()
        if count is not None and count < c["min_subscribers"] and waited < c["start_delay"] + 30.0:
            return False
        return True

    def tick(self) -> None:
        if self.finished:
            return
        if not self.started:
            if not self._ready():
                return
            self.started = True
            self.epoch = self.node.now_ns()
            self.node.logger.info(f"t = 0: hover at {self.plant.x[0] * 1e3:.3f} mm, {self.plant.u0[0]:.2f} V")
        tick_start = self.node.now_ns()
        p = self.plant
        # sample index from the clock: a late tick integrates the skipped samples (time does not wait)
        k = max(self.k_next, int(round((self.node.now_ns() - self.epoch) / self.dt_ns)))
        t_ns = self.epoch + k * self.dt_ns
        d = self.cfg["command_delay"]
        for j in range(self.k_next, k + 1):
            if j == 0:
                self.last_fresh_ns = t_ns
                continue
            src = j - 1 - d  # over [t_j-1, t_j] the plant holds the command of sample j-1-d
            prev = self.epoch + src * self.dt_ns
            slot = src % self.cmd_ring.size
            if src < 0:
                self.u_applied = self.plant.u0  # before t = 0 the coils held the hover voltage
                self.last_fresh_ns = self.epoch
            elif self.cmd_ring[slot] == prev:
                self.u_applied = self.cmd_u[slot].copy()
                self.last_fresh_ns = prev
            else:
                self.misses += 1
                if prev - self.last_fresh_ns > self.cfg["command_timeout"] * 1e9:
                    self.u_applied = np.zeros(2)
                    self.watchdog += 1
            p.advance(self.u_applied)  # x_{j-1} -> x_j under the command of sample j-1
            if p.fault:
                self.finish(f"plant failure at t = {p.k * self.cfg['dt']:.3f} s: {p.fault}", level=2)
                return
        self.k_next = k + 1
        JS = self.JS
        x = p.x
        z = p.measurement()
        self.pub_applied.publish(joint_state(JS, t_ns, effort=self.u_applied))
        self.pub_truth.publish(joint_state(JS, t_ns, position=(x[0], x[2], p.mass), velocity=(x[1], x[3]),
                                           effort=(x[4], x[5]), names=(*contract.MAGNETS, "mass")))
        vel = (z[1], z[3]) if self.cfg["measure_velocity"] else ()
        self.pub_meas.publish(joint_state(JS, t_ns, position=(z[0], z[2]), velocity=vel, effort=(z[4], z[5])))
        done = self.node.now_ns()
        self.tick_late.add(tick_start - t_ns)
        self.tick_cost.add(done - tick_start)
        if self.n_end and p.k >= self.n_end:
            self.finish(f"finished {self.cfg['duration']:g} s", level=0)

    def stats(self) -> dict:
        lat = self.lat.summary_us()
        return {
            "cycles": self.plant.k, "t_sim_s": round(self.plant.k * self.cfg["dt"], 3), "deadline_misses": self.misses,
            "watchdog_zero_voltage": self.watchdog, "timer_overruns": getattr(self.timer, "overruns", 0),
            "latency_p50_us": round(lat["p50"], 1), "latency_p99_us": round(lat["p99"], 1), "latency_max_us": round(lat["max"], 1),
            "tick_lateness_p99_us": round(self.tick_late.summary_us()["p99"], 1),
            "tick_compute_p99_us": round(self.tick_cost.summary_us()["p99"], 1),
            "failed": self.plant.fault is not None, "fault": self.plant.fault or "",
        }

    def publish_diag(self, level: int, message: str) -> None:
        self.pub_diag.publish(diag_array(*self.D, self.node.now_ns(), "plant_sim: loop", level, message, self.stats()))

    def status(self) -> None:
        if not self.started or self.finished:
            return
        s = self.stats()
        x = self.plant.x
        print(f"t = {s['t_sim_s']:7.1f} s  gaps {x[0] * 1e3:6.3f} / {x[2] * 1e3:6.3f} mm  misses {s['deadline_misses']}"
              f"  latency p50 {s['latency_p50_us']:.0f} us p99 {s['latency_p99_us']:.0f} us"
              f"  tick late p99 {s['tick_lateness_p99_us']:.0f} us, compute p99 {s['tick_compute_p99_us']:.0f} us", flush=True)
        self.publish_diag(0 if s["deadline_misses"] == 0 else 1, "running")

    def finish(self, message: str, level: int) -> None:
        self.finished = True
        (self.node.logger.error if level else self.node.logger.info)(message)
        self.publish_diag(level, "finished: " + message)
        # give the last samples time to reach subscribers, then stop the node
        self.node.timer(0.3, self.node.shutdown)


def main(args=None) -> int:
    return run_node("plant_sim", PlantSimNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
