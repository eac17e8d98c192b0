"""``plant_sim``: the simulated DEM, paced at 1 kHz against absolute deadlines.

Sample k is stamped t_k = epoch + k T on the plant's clock. To publish sample k
the plant integrates [t_k-1, t_k] holding the command computed from sample
k-1-d (``command_delay`` d; zero-order hold), then publishes
``/dem/applied_voltage``, ``/dem/plant/truth`` and ``/dem/measurement`` for t_k.
Every sample is published, in order.

Two timing modes:

* ``lockstep: true`` (default, simulation): when the command a sample needs has
  not arrived by its deadline, the plant waits for it (a counted deadline
  miss) and its clock falls behind wall time; the closed loop is then exactly
  the offline simulator's, however slow the machine. After ``lockstep_timeout``
  without it, the plant proceeds with 0 V (watchdog), so a dead controller
  cannot freeze the simulation.
* ``lockstep: false`` (hardware-like): time does not wait; a missing command is
  a counted deadline miss, the last voltage is held, and after
  ``command_timeout`` the coils get 0 V.

Before t = 0 the plant levitates in closed loop for ``preroll`` seconds
(frame_id ``dem/preroll``; a missing command then just holds the voltage).
Latency = receive time of a command - publish time of the measurement it
answers. A hardware driver replaces this node by honouring the same topics.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from .. import contract
from ..core.plant import DemPlant
from ..core.warmup import warm_up
from ..transport import Node, run_node
from .common import LatencyStats, all_finite, diag_array, joint_state, stamp_ns

__all__ = ["PlantSimNode", "main"]

RING = 256  # commands / publish times kept by sample index


class PlantSimNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("plant_sim", self.on_change)
        c = self.cfg
        self.dt_ns = int(round(c["dt"] * 1e9))
        self.plant = DemPlant(c, c["duration"])
        self.n_end = int(round(c["duration"] / c["dt"])) if c["duration"] > 0 else 0
        warm_up()  # kernels resident before we subscribe (no slow first samples)
        self.JS = node.msg("sensor_msgs/msg/JointState")
        self.pub_meas = node.publisher(contract.MEASUREMENT)
        self.pub_truth = node.publisher(contract.TRUTH)
        self.pub_applied = node.publisher(contract.APPLIED)
        self.pub_diag = node.publisher(contract.DIAGNOSTICS)
        self.D = (node.msg("diagnostic_msgs/msg/DiagnosticArray"), node.msg("diagnostic_msgs/msg/DiagnosticStatus"),
                  node.msg("diagnostic_msgs/msg/KeyValue"))
        node.subscribe(contract.COMMAND, self.on_command)
        self.cmd_stamp = np.full(RING, -1, dtype=np.int64)  # stamp of the command held in each slot
        self.cmd_u = np.zeros((RING, 2))
        self.pub_wall = np.zeros(RING, dtype=np.int64)  # when each sample was published (wall clock, ns)
        self.u_applied = self.plant.u0.copy()
        self.last_fresh_k = 0
        self.started = False
        self.finished = False
        self.n_pre = 0
        self.k_next = 0
        self.epoch = 0  # stamp of sample 0 (t = 0 of the experiment), plant clock
        self.due = 0  # wall time (monotonic ns) at which sample k_next is due
        self.wait_since = None  # lockstep: wall time we started waiting for the current sample
        self.wall0 = 0
        self.cpu0: float | None = None  # process CPU time at t = 0
        self.t_boot = time.monotonic()
        self.misses = 0
        self.preroll_misses = 0
        self.watchdog = 0
        self.lat = LatencyStats()
        self.late = LatencyStats()
        self.timer = node.timer(c["dt"], self.tick)
        node.timer(1.0, self.status)

    # -- parameters / inputs ------------------------------------------------------------------
    def on_change(self, values) -> str | None:
        for key in ("dt", "substeps", "command_delay", "duration", "lockstep", "preroll"):
            if values[key] != self.cfg[key]:
                return f"{key} cannot change during a run"
        self.cfg = dict(values)
        self.plant.pc.update(values)  # disturbances and noise act from the next sample
        return None

    def on_command(self, msg) -> None:
        if not self.started or len(msg.effort) < 2:
            return
        u = msg.effort[:2]
        if not all_finite(u):
            self.node.logger.warn("non-finite command ignored")
            return
        t = stamp_ns(msg)
        k = int(round((t - self.epoch) / self.dt_ns))
        slot = k % RING
        self.cmd_stamp[slot] = t
        self.cmd_u[slot] = u
        self.lat.add(time.monotonic_ns() - self.pub_wall[slot])
        if self.wait_since is not None:
            self.tick()  # lockstep: the command we were waiting for may have come

    def _ready(self) -> bool:
        c = self.cfg
        waited = time.monotonic() - self.t_boot
        if waited < c["start_delay"]:
            return False
        count = self.pub_meas.subscription_count
        return not (count < c["min_subscribers"] and waited < c["start_delay"] + 30.0)

    # -- the loop -----------------------------------------------------------------------------
    def tick(self) -> None:
        if self.finished:
            return
        now = time.monotonic_ns()
        if not self.started:
            if not self._ready():
                return
            self.started = True
            self.n_pre = int(round(self.cfg["preroll"] / self.cfg["dt"]))
            self.k_next = -self.n_pre
            self.epoch = self.node.now_ns() + self.n_pre * self.dt_ns
            self.due = now
            self.wall0 = now + self.n_pre * self.dt_ns
            mode = "lockstep" if self.cfg["lockstep"] else "real time"
            self.node.logger.info(f"levitating at {self.plant.x[0] * 1e3:.3f} mm, {self.plant.u0[0]:.2f} V ({mode});"
                                  f" t = 0 in {self.cfg['preroll']:g} s")
        while not self.finished and now >= self.due:
            if not self._advance(now):
                return  # lockstep: waiting for a command
            self._publish(self.k_next)
            if self.k_next == 0:
                self.cpu0 = time.process_time()
            if self.k_next >= 0:
                self.late.add(now - self.due)
            self.k_next += 1
            self.due += self.dt_ns
            if self.n_end and self.k_next > self.n_end:
                self.finish(f"finished {self.cfg['duration']:g} s", level=0)
                return
            now = time.monotonic_ns()

    def _advance(self, now: int) -> bool:
        """Integrate [t_k-1, t_k] for k = k_next; False when lockstep must wait for the command."""
        k = self.k_next
        if k == -self.n_pre:
            return True  # the first sample: nothing to integrate yet
        src = k - 1 - self.cfg["command_delay"]  # the sample whose command is held over [t_k-1, t_k]
        slot = src % RING
        if src < -self.n_pre:
            self.u_applied = self.plant.u0  # before the loop closed the coils held the hover voltage
        elif self.cmd_stamp[slot] == self.epoch + src * self.dt_ns:
            self.u_applied = self.cmd_u[slot].copy()
            self.last_fresh_k = src
            if self.wait_since is not None:
                self.wait_since = None
        else:
            timeout = (k - 1 - self.last_fresh_k) * self.cfg["dt"] > self.cfg["command_timeout"]
            if self.cfg["lockstep"]:
                if self.wait_since is None:
                    self.wait_since = now
                    if k > 0:
                        self.misses += 1
                    else:
                        self.preroll_misses += 1
                if (now - self.wait_since) * 1e-9 < self.cfg["lockstep_timeout"]:
                    return False
                self.wait_since = None
                self.u_applied = np.zeros(2)  # the controller is gone: watchdog
                self.watchdog += 1
            elif k <= 0:
                self.preroll_misses += 1  # levitating before t = 0: hold the last voltage
            else:
                self.misses += 1
                if timeout:
                    self.u_applied = np.zeros(2)
                    self.watchdog += 1
        p = self.plant
        if k <= 0:
            p.hold(self.u_applied)  # pre-roll: true dynamics, no scenario disturbances, clock at 0
        else:
            p.advance(self.u_applied)
        if p.fault:
            when = "during pre-roll" if k <= 0 else f"at t = {p.k * self.cfg['dt']:.3f} s"
            self.finish(f"plant failure {when}: {p.fault}", level=2)
            return False
        return True

    def _publish(self, k: int) -> None:
        p = self.plant
        t_ns = self.epoch + k * self.dt_ns
        frame = contract.FRAME if k >= 0 else contract.FRAME_PREROLL
        JS = self.JS
        x = p.x
        z = p.measurement() if k >= 0 else p.measurement_preroll()
        self.pub_wall[k % RING] = time.monotonic_ns()
        self.pub_applied.publish(joint_state(JS, t_ns, effort=self.u_applied, frame=frame))
        self.pub_truth.publish(joint_state(JS, t_ns, position=(x[0], x[2], p.mass), velocity=(x[1], x[3]),
                                           effort=(x[4], x[5]), names=(*contract.MAGNETS, "mass"), frame=frame))
        vel = (z[1], z[3]) if self.cfg["measure_velocity"] else ()
        self.pub_meas.publish(joint_state(JS, t_ns, position=(z[0], z[2]), velocity=vel, effort=(z[4], z[5]), frame=frame))

    # -- reporting ----------------------------------------------------------------------------
    def stats(self) -> dict:
        lat = self.lat.summary_us()
        late = self.late.summary_us()
        k = max(self.plant.k, 0)
        wall = max(time.monotonic_ns() - self.wall0, 1) * 1e-9
        cpu = time.process_time() - self.cpu0 if self.cpu0 is not None else 0.0
        return {
            "cycles": k, "t_sim_s": round(k * self.cfg["dt"], 3), "deadline_misses": self.misses,
            "preroll_misses": self.preroll_misses, "watchdog_zero_voltage": self.watchdog,
            "lockstep": self.cfg["lockstep"], "realtime_factor": round(k * self.cfg["dt"] / wall, 3) if k else 0.0,
            "epoch_ns": self.epoch, "cpu_s": round(cpu, 3), "wall_s": round(wall if k else 0.0, 3),
            "latency_p50_us": round(lat["p50"], 1), "latency_p99_us": round(lat["p99"], 1), "latency_max_us": round(lat["max"], 1),
            "lateness_p99_us": round(late["p99"], 1),
            "failed": self.plant.fault is not None, "fault": self.plant.fault or "",
        }

    def publish_diag(self, level: int, message: str, stats: dict | None = None) -> None:
        self.pub_diag.publish(diag_array(*self.D, self.node.now_ns(), "plant_sim: loop", level, message,
                                         stats if stats is not None else self.stats()))

    def status(self) -> None:
        if not self.started or self.finished:
            return
        s = self.stats()
        x = self.plant.x
        print(f"t = {s['t_sim_s']:7.1f} s  gaps {x[0] * 1e3:6.3f} / {x[2] * 1e3:6.3f} mm  misses {s['deadline_misses']}"
              f"  latency p50 {s['latency_p50_us']:.0f} us p99 {s['latency_p99_us']:.0f} us  x{s['realtime_factor']:.2f} real time",
              flush=True)
        self.publish_diag(0 if s["deadline_misses"] == 0 else 1, "running", s)

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
