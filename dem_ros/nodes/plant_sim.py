"""``plant_sim``: the simulated DEM, paced at 1 kHz against absolute deadlines.

Sample k is stamped t_k = epoch + k T on the plant's clock. To publish sample k
the plant integrates [t_k-1, t_k] holding the command computed from sample
k-1-d (``command_delay`` d; zero-order hold; :func:`dem_ros.core.hold.command_sample`), then publishes
``/dem/applied_voltage``, ``/dem/plant/truth`` and ``/dem/measurement`` for t_k.
Every sample is published, in order.

The coils are driven through the simulated board, :class:`dem_ros.board.Supervisor`
(the same class as the rig emulator's board): every applied voltage is clipped to
``u_max``, current and gap trips latch a fault, and a missing command never cuts the
coils at hover: the board holds the last voltage at most ``hold_timeout``, then lands
the plate at no more than ``landing_speed`` (``LANDED`` ends the run: the simulated
plate rests on its support). The board knows the datasheet (Table 2) m, R, K, not the
simulated truth. Holds, the landing and its reason are logged once when they engage
and reported on ``/diagnostics`` (status ``plant_sim: loop``) with their counters.

Two timing modes:

* ``lockstep: true`` (default, simulation): when the command a sample needs has
  not arrived by its deadline, the plant waits for it (a counted deadline
  miss) and its clock falls behind wall time; the closed loop is then exactly
  the offline simulator's, however slow the machine. After ``lockstep_timeout``
  without it the board lands the plate (a dead controller cannot freeze the
  simulation, nor drop the plate).
* ``lockstep: false`` (free-running, hardware-like): time does not wait; a
  missing command is a counted deadline miss and a board hold (see above).

Before t = 0 the plant levitates in closed loop for ``preroll`` seconds
(frame_id ``dem/preroll``). Until the first command arrives (at most 300 ms,
``START_GRACE_SAMPLES``) a free-running board keeps the initial hover voltage
(the simulated plate starts in exact equilibrium, so that costs nothing); from
then on a missing command is held at most ``hold_timeout``: a graph that cannot
keep up lands the plate.
Command source lock (:class:`~dem_ros.nodes.common.CommandSource`): ``/dem/command`` is taken only
from the one writer bound to the node ``command_source`` (default ``controller``; read-only), by each
sample's writer GID; other writers are refused, counted (``commands_foreign``) and reported; a writer
whose graph information comes late is held, not dropped (docs/manual/trust.md). The run does not start
(either timing mode) before that writer is bound: until then the plant waits, reporting WARN "waiting for ...".

Latency = receive time of a command - publish time of the measurement it
answers. A hardware driver replaces this node by honouring the same topics.

The node also watches the recorder (:class:`~dem_ros.nodes.recording_watch.RecordingWatch`, status
``plant_sim: recording``): a recorder that falls silent latches ERROR there, with the experiment time of its
last report.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from .. import contract
from ..board import SAFETY_KEYS, Mode, Supervisor
from ..core.hold import command_sample
from ..core.params import TABLE2
from ..core.plant import DemPlant
from ..core.warmup import warm_up
from ..runstate import announce
from ..transport import Node, run_node
from .common import ERROR, OK, WARN, CommandSource, Diagnostics, JointStates, LatencyStats, all_finite, stamp_ns
from .recording_watch import RecordingWatch

__all__ = ["PlantSimNode", "main"]

RING = 256  # commands / publish times kept by sample index
# Free-running pre-roll: before the first command the board keeps the initial hover voltage for at most
# this many samples. The simulated plate starts in exact equilibrium; with the voltage held, rounding
# errors (~1e-18 m) grow by e^(62 rad/s * 0.3 s) ~ 1e8 in 300 ms: still far below 1 nm.
START_GRACE_SAMPLES = 300


class PlantSimNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("plant_sim", self.on_change)
        c = self.cfg
        self.dt_ns = round(c["dt"] * 1e9)
        self.early_ns = self.dt_ns // 2  # a tick this much before ``due`` publishes the sample
        self.plant = DemPlant(c, c["duration"])
        self.n_end = round(c["duration"] / c["dt"]) if c["duration"] > 0 else 0
        warm_up()  # kernels resident before we subscribe (no slow first samples)
        self.js = JointStates(node.msg("sensor_msgs/msg/JointState"))
        self.names = list(contract.MAGNETS)  # shared by every message published (never modified)
        self.names_truth = [*contract.MAGNETS, "mass"]
        # /diagnostics "plant_sim: loop": published by status() once a second and at once on board events, with
        # the "<topic> topic status" of the three streams once a second
        self.diag = Diagnostics(node, contract.LOOP_STATUS, warn_on=("commands_foreign",), values=self.stats,
                                timer=False)
        self.pub_meas = self.diag.diagnosed(contract.MEASUREMENT)
        self.pub_truth = self.diag.diagnosed(contract.TRUTH)
        self.pub_applied = self.diag.diagnosed(contract.APPLIED)
        self.source = CommandSource(node, c["command_source"], self.on_command)
        self.cmd_stamp = np.full(RING, -1, dtype=np.int64)  # stamp of the command held in each slot
        self.cmd_u = np.zeros((RING, 2))
        self.pub_wall = np.zeros(RING, dtype=np.int64)  # when each sample was published (wall clock, ns)
        self.u_applied = self.plant.u0.copy()
        # the simulated board: datasheet m, R, K (not the simulated truth), the plate hovering under u0
        board = {**c, **{k: TABLE2[k] for k in ("m", "R", "K")}}
        self.board = Supervisor(board, c["dt"], mode=Mode.RUN, u0=self.plant.u0)
        self.z_board = self.plant.x.tolist()  # what the board measured at the last published sample
        self.loop_closed = False  # a first command has arrived
        self.started = False
        self.finished = False
        self.n_pre = 0
        self.k_next = 0
        self.epoch = 0  # stamp of sample 0 (t = 0 of the experiment), plant clock
        self.due = 0  # wall time (monotonic ns) at which sample k_next is due
        self.wait_since: int | None = None  # lockstep: wall time we started waiting for the current sample
        self.wall0 = 0
        self.cpu0: float | None = None  # process CPU time at t = 0
        self.t_boot = time.monotonic()
        self.misses = 0
        self.preroll_misses = 0
        self.lockstep_landing = 0
        self.landing_t: float | None = None  # experiment time [s] the board began to land the plate
        self.holds0 = 0  # board holds before t = 0 (the pre-roll's: reported apart, as its misses are)
        self.lat = LatencyStats()
        self.late = LatencyStats()
        self.timer = node.timer(c["dt"], self.tick)
        node.timer(1.0, self.status)
        # /diagnostics "plant_sim: recording": the recorder's liveness (the graph's plant node watches it)
        self.recording = RecordingWatch(node, contract.RECORDING_STATUS, self.experiment_t)

    # -- parameters / inputs ------------------------------------------------------------------
    def on_change(self, values) -> str | None:
        for key in ("dt", "substeps", "command_delay", "duration", "lockstep", "preroll", *SAFETY_KEYS):
            if values[key] != self.cfg[key]:
                return f"{key} cannot change during a run"
        self.cfg = dict(values)
        self.plant.pc.update(values)  # disturbances and noise act from the next sample
        return None

    def on_command(self, msg) -> None:
        if not self.started:
            return
        u = msg.effort[:2]
        if not all_finite(u):
            self.node.logger.warn("non-finite command ignored")
            return
        t = stamp_ns(msg)
        k = round((t - self.epoch) / self.dt_ns)
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
        if not self.source.matched:
            self.diag.set_condition(WARN, f"waiting for {self.source.source!r}'s /dem/command writer")
            return False  # never start without the controller: its first command would come too late
        self.diag.set_condition(OK)
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
            self.n_pre = round(self.cfg["preroll"] / self.cfg["dt"])
            self.k_next = -self.n_pre
            self.epoch = self.node.now_ns() + self.n_pre * self.dt_ns
            self.due = now
            self.wall0 = now + self.n_pre * self.dt_ns
            mode = "lockstep" if self.cfg["lockstep"] else "real time"
            self.node.logger.info(f"levitating at {self.plant.x[0] * 1e3:.3f} mm, {self.plant.u0[0]:.2f} V ({mode});"
                                  f" t = 0 in {self.cfg['preroll']:g} s")
        # The timer's grid and ``due`` are both 1 ms apart but their phases differ by the wake-up
        # lateness of the first tick: a tick counts for the sample due within half a period
        # (without this, a timer firing 1 us before ``due`` publishes that sample 1 ms late).
        while not self.finished and now >= self.due - self.early_ns:
            if not self._advance(now):
                return  # lockstep: waiting for a command
            self._publish(self.k_next)
            if self.k_next == 0:
                self.cpu0 = time.process_time()
                self.holds0 = self.board.counters["holds"]  # the pre-roll's holds are not the experiment's
                announce("t0", "plant_sim", epoch_ns=self.epoch)  # to the launcher (dem_ros.runstate)
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
        src = command_sample(k - 1, self.cfg["command_delay"])  # the sample whose command is held over [t_k-1, t_k]
        slot = src % RING
        board = self.board
        prev = board.mode
        if src < -self.n_pre:
            cmd = self.plant.u0  # before the loop closed the board held the hover voltage
        elif self.cmd_stamp[slot] == self.epoch + src * self.dt_ns:
            cmd = self.cmd_u[slot]
            self.wait_since = None
            self.loop_closed = True
        elif not self.loop_closed and k <= 0 and k + self.n_pre <= START_GRACE_SAMPLES and not self.cfg["lockstep"]:
            # free-running pre-roll before the first command: the simulated plate starts in exact equilibrium
            # under u0, so holding u0 costs nothing for a while (see START_GRACE_SAMPLES)
            cmd = self.plant.u0
            self.preroll_misses += 1
        else:
            cmd = None
            if self.cfg["lockstep"] and board.mode in (Mode.RUN, Mode.HOLD):
                if self.wait_since is None:
                    self.wait_since = now
                    if k > 0:
                        self.misses += 1
                    else:
                        self.preroll_misses += 1
                if (now - self.wait_since) * 1e-9 < self.cfg["lockstep_timeout"]:
                    return False
                self.wait_since = None
                self.lockstep_landing += 1
                board.land(f"no command for {self.cfg['lockstep_timeout']:g} s of wall time (lockstep_timeout:"
                           " a dead controller)")
            elif not self.cfg["lockstep"]:
                if k > 0:
                    self.misses += 1
                else:
                    self.preroll_misses += 1
        z = self.z_board  # the board computes [t_k-1, t_k) from its sample of t_k-1
        # the board measures its coils' voltage over the last period (the scenario's input perturbation included:
        # its flux check must not take that voltage for a sensor fault; /dem/applied_voltage stays what it applied)
        self.u_applied = board.step(self.epoch + (k - 1) * self.dt_ns, (z[0], z[2]), (z[4], z[5]), cmd,
                                    applied=self.plant.coil_voltage)
        if board.mode != prev:
            self._board_event(prev, k - 1)
            if self.finished:
                return False  # LANDED: the plate rests on its support (not simulated): the run ends here
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

    def _board_event(self, prev: Mode, k: int) -> None:
        """Log a board mode change once, and report landings and faults on /diagnostics at once."""
        b = self.board
        when = f"{'pre-roll ' if k < 0 else ''}t = {k * self.cfg['dt']:.3f} s"
        log = self.node.logger
        if b.mode == Mode.HOLD:
            if b.counters["hold_events"] == 1:
                log.warn(f"{when}: command missing, the board holds the last voltage (at most"
                         f" {self.cfg['hold_timeout'] * 1e3:g} ms); further holds are counted")
            return
        if b.mode == Mode.RUN:
            return
        if b.mode == Mode.LAND:
            if self.landing_t is None:
                self.landing_t = k * self.cfg["dt"]  # the verdict's "landed at t = ..." (negative: in the pre-roll)
            x = self.plant.x
            (log.error if b.fault else log.warn)(
                f"{when}: safe landing from gaps {x[0] * 1e3:.3f} / {x[2] * 1e3:.3f} mm to"
                f" {self.cfg['landing_gap'] * 1e3:g} mm at <= {self.cfg['landing_speed'] * 1e3:g} mm/s: {b.reason}")
            self.diag.publish(ERROR if b.fault else WARN, f"landing: {b.reason}")
        elif b.mode == Mode.LANDED:
            self.finish(f"landed safely at {when}"
                        f" (gaps {self.plant.x[0] * 1e3:.3f} / {self.plant.x[2] * 1e3:.3f} mm): {b.reason}",
                        level=2 if b.fault else 1)
        elif b.mode == Mode.FAULT:
            self.finish(f"board fault at {when}: {b.fault}", level=2)

    def _publish(self, k: int) -> None:
        p = self.plant
        J = self.js
        h = J.header(self.epoch + k * self.dt_ns, contract.FRAME if k >= 0 else contract.FRAME_PREROLL)
        x = p.x.tolist()
        z = (p.measurement() if k >= 0 else p.measurement_preroll()).tolist()
        self.z_board = z  # the board's sample of t_k: it computes the voltage of [t_k, t_k+1) from it
        u = self.u_applied
        self.pub_wall[k % RING] = time.monotonic_ns()
        self.pub_applied.publish(J.make(h, self.names, effort=[float(u[0]), float(u[1])]))
        self.pub_truth.publish(J.make(h, self.names_truth, [x[0], x[2], p.mass], [x[1], x[3]], [x[4], x[5]]))
        vel = [z[1], z[3]] if self.cfg["measure_velocity"] else []
        self.pub_meas.publish(J.make(h, self.names, [z[0], z[2]], vel, [z[4], z[5]]))

    # -- reporting ----------------------------------------------------------------------------
    def experiment_t(self) -> float | None:
        """The experiment time of the newest published sample [s]; None before t = 0."""
        k = self.k_next - 1
        return k * self.cfg["dt"] if self.started and k >= 0 else None

    def stats(self) -> dict:
        lat = self.lat.summary_us()
        late = self.late.summary_us()
        k = max(self.plant.k, 0)
        wall = max(time.monotonic_ns() - self.wall0, 1) * 1e-9
        cpu = time.process_time() - self.cpu0 if self.cpu0 is not None else 0.0
        return {
            "cycles": k, "t_sim_s": round(k * self.cfg["dt"], 3), "deadline_misses": self.misses,
            "preroll_misses": self.preroll_misses, **self.board_stats(), **self.source.values(),
            "lockstep": self.cfg["lockstep"], "realtime_factor": round(k * self.cfg["dt"] / wall, 3) if k else 0.0,
            "epoch_ns": self.epoch, "cpu_s": round(cpu, 3), "wall_s": round(wall if k else 0.0, 3),
            "latency_p50_us": round(lat["p50"], 1), "latency_p99_us": round(lat["p99"], 1),
            "latency_max_us": round(lat["max"], 1), "lateness_p99_us": round(late["p99"], 1),
            "failed": self.plant.fault is not None, "fault": self.plant.fault or "",
        }

    def board_stats(self) -> dict:
        """The board's mode, counters and landing, as /diagnostics values."""
        b = self.board
        c = b.counters
        return {
            # holds and misses count the same samples (the experiment's, from t = 0): a free-running board holds
            # at each missed deadline; the pre-roll's are apart (preroll_holds, preroll_misses)
            "board_mode": b.mode.name, "holds": c["holds"] - (self.holds0 if self.k_next > 0 else c["holds"]),
            "preroll_holds": self.holds0 if self.k_next > 0 else c["holds"], "hold_events": c["hold_events"],
            "longest_hold_ms": c["longest_hold_us"] / 1000,
            "clipped": c["clipped"], "trips": c["trips"], "landing": c["landings"] > 0 or b.mode == Mode.LANDED,
            "landed": c["landed"] > 0, "landing_reason": b.reason if c["landings"] else "",
            "board_fault": b.fault, "lockstep_timeouts": self.lockstep_landing,
            **({"landing_t_s": round(self.landing_t, 3)} if self.landing_t is not None else {}),
        }

    def status(self) -> None:
        if self.finished:
            return
        if not self.started:
            self.diag.report()  # waiting for the command source (or discovery)
            return
        s = self.stats()
        x = self.plant.x
        late = "waits" if self.cfg["lockstep"] else "misses"  # lockstep: the plant waited for a late command
        lat = (f"  latency p50 {s['latency_p50_us']:.0f} us p99 {s['latency_p99_us']:.0f} us"
               if math.isfinite(s["latency_p50_us"]) else "")  # none before the first command
        print(f"t = {s['t_sim_s']:7.1f} s  gaps {x[0] * 1e3:6.3f} / {x[2] * 1e3:6.3f} mm  {late} {s['deadline_misses']}"
              f"  holds {s['holds']}  board {s['board_mode']}{lat}  x{s['realtime_factor']:.2f} real time",
              flush=True)
        level = ERROR if s["landing"] else OK if s["deadline_misses"] == 0 and s["holds"] == 0 else WARN
        self.diag.report(level, "landing" if s["landing"] else "running", s)

    def finish(self, message: str, level: int) -> None:
        self.finished = True
        log = self.node.logger
        (log.error if level >= 2 else log.warn if level == 1 else log.info)(message)
        self.diag.publish(level, "finished: " + message)
        announce("finished", "plant_sim", message=message, level=level)
        # give the last samples time to reach subscribers, then stop the node
        self.node.timer(0.3, self.node.shutdown)


def main(args=None) -> int:
    return run_node("plant_sim", PlantSimNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
