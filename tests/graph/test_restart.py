"""Restarts and lift-off of the real controller, reference and estimator nodes, closed through the rig
emulator's board and the hardware driver one tick at a time (in-memory transport, no clock, no socket:
the loop is exact, so these outcomes do not depend on the machine's load).

Each tick: the board samples and sends a sensor frame; the driver decodes it; the frame goes out as
``/dem/applied_voltage`` and ``/dem/measurement`` (what ``hw_driver`` publishes); the nodes run; the
controller's command goes back through the driver to the board, which applies it one tick later.
"""

from __future__ import annotations

import numpy as np
import pytest
from loop_writers import publish

from dem_ros import contract
from dem_ros.core.controllers.hover import LIFTOFF_SPEED
from dem_ros.core.params import default_config
from dem_ros.hardware.driver import DriverState, HwDriver
from dem_ros.hardware.link import HELLO_REQUEST, Mode, encode
from dem_ros.hardware.rig import Board
from dem_ros.nodes.common import joint_state, stamp_ns
from dem_ros.nodes.controller import ControllerNode
from dem_ros.nodes.estimator import EstimatorNode
from dem_ros.nodes.reference import ReferenceNode
from dem_ros.transport.memory import MemoryBus

MS = 1_000_000
T0 = 1_800_000_000 * 10**9  # ROS time of board sample 0 [ns]


class RigLoop:
    """Board + driver + the real nodes on a MemoryBus, stepped one board tick at a time."""

    def __init__(self, start: str = "hover", preroll: float = 0.3, cfg: dict | None = None, **ref):
        cfg = default_config() if cfg is None else cfg
        cfg["plant_sim"]["measure_velocity"] = False
        cfg["rig"]["start"] = start
        self.cfg = cfg
        self.board = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], preroll=preroll)
        self.board.receive(encode(HELLO_REQUEST))
        self.drv = HwDriver(cfg["hw_driver"] | {"clock_sync_frames": 1, "arm_samples": 50})
        self.bus = MemoryBus(T0)
        self.JS = self.bus.msg("sensor_msgs/msg/JointState")
        self.n_pre = round(preroll / cfg["plant_sim"]["dt"])
        self.epoch_seq: int | None = None
        self.ref_args = [f"{k}:={v}" for k, v in ref.items()]
        self.nodes: dict[str, object] = {}
        self.cmds: dict[int, list[float]] = {}
        self.gaps: list[tuple[float, float]] = []  # true gaps, every tick
        self.modes: list[Mode] = []
        probe = self.bus.node("probe")
        probe.subscribe(contract.COMMAND, lambda m: self.cmds.__setitem__(stamp_ns(m), list(m.effort)))
        self.refs: dict[int, list[float]] = {}
        probe.subscribe(contract.REFERENCE, lambda m: self.refs.__setitem__(stamp_ns(m), list(m.position)))
        for name in ("estimator", "reference", "controller"):
            self.start(name)

    def start(self, name: str) -> None:
        args = ["--ros-args", *[a for x in self.ref_args for a in ("-p", x)]] if name == "reference" else None
        if name == "controller":  # cfg's controller parameters that differ from the schema's (its node declares those)
            c, d = self.cfg["controller"], default_config()["controller"]
            args = ["--ros-args", *[a for k, v in c.items() if v != d[k] for a in ("-p", f"{k}:={v!r}")]]
        node = self.bus.node(name, args)
        self.nodes[name] = {"estimator": EstimatorNode, "reference": ReferenceNode,
                            "controller": ControllerNode}[name](node)

    def kill(self, name: str) -> None:
        self.nodes.pop(name).node.shutdown()  # type: ignore[attr-defined]

    def run(self, ticks: int) -> None:
        b, drv, bus = self.board, self.drv, self.bus
        for _ in range(ticks):
            data = b.tick()
            self.gaps.append((b.plant.x[0], b.plant.x[2]))
            self.modes.append(Mode(b.sup.mode))
            if data is None:
                continue
            ros_ns = T0 + b.n * MS
            s, reply = drv.on_bytes(data, ros_ns, b.n * MS)
            if reply is not None:
                answer = b.receive(reply)  # a command, or the run's configuration (answered)
                if answer is not None:
                    drv.on_bytes(answer, ros_ns, b.n * MS)
            if s is None:
                continue
            bus.now_ns = s.stamp_ns
            if drv.state == DriverState.ACTIVE and self.epoch_seq is None:
                self.epoch_seq = s.seq + self.n_pre
            frame = contract.FRAME if self.epoch_seq is not None and s.seq >= self.epoch_seq else contract.FRAME_PREROLL
            publish(bus, contract.APPLIED, joint_state(self.JS, s.stamp_ns, effort=s.applied, frame=frame))
            publish(bus, contract.MEASUREMENT,
                    joint_state(self.JS, s.stamp_ns, position=s.gap, effort=s.current, frame=frame))
            bus.spin_once()
            u = self.cmds.get(s.stamp_ns)
            if u is not None:
                cmd = drv.command(s.stamp_ns, u, b.n * MS)
                if cmd is not None:
                    b.receive(cmd)
            drv.check(b.n * MS)

    def epoch_ns(self) -> int:
        assert self.epoch_seq is not None
        return T0 + self.epoch_seq * MS

    @property
    def ctl(self) -> ControllerNode:
        c = self.nodes["controller"]
        assert isinstance(c, ControllerNode)
        return c


def _min_gap(loop: RigLoop, since: int = 0) -> float:
    return float(np.min(np.array(loop.gaps[since:])))


def test_a_controller_started_on_a_landed_plate_lifts_it_off_once_the_board_follows():
    """Landed on its support, zero current: the controller premagnetises (the plate stays down), waits while
    the board ignores it, and once armed lifts the plate smoothly to the reference; never near the rail."""
    loop = RigLoop(start="landed")
    pc, rig = loop.cfg["plant_sim"], loop.cfg["rig"]
    loop.run(500)  # driver inactive: the board ignores every command
    assert loop.ctl.seq.landed and not loop.ctl.seq.started
    assert _min_gap(loop) == pytest.approx(rig["support_gap"])  # nothing moved
    loop.drv.arm()
    loop.run(4000)
    assert loop.drv.state == DriverState.ACTIVE and loop.modes[-1] == Mode.RUN
    assert loop.ctl.seq.counts["liftoffs"] == 1 and loop.ctl.seq.started
    gaps = np.array(loop.gaps)
    off = int(np.argmax(gaps[:, 0] < rig["support_gap"] - 1e-6))  # the tick the plate left its support
    assert off > 1000  # premagnetised, then the force rose slowly: it stayed down for a while
    lift = gaps[off:off + 1000]
    assert lift.min() > rig["support_gap"] - 2e-3  # overshoot toward the rail < 2 mm
    assert (-np.diff(lift, axis=0) / 1e-3).max() < 3 * LIFTOFF_SPEED  # rising speed [m/s]
    assert gaps.min() > pc["trip_gap_min"] + 3e-3  # never near the rail
    loop.run(3000)  # then tracks the reference (its schedule steps magnet 1 to 5 mm at t = 1 s)
    e = np.array(loop.gaps[-1]) - np.array(loop.refs[max(loop.refs)][:2])
    assert np.all(np.abs(e) < 0.3e-3) and loop.modes[-1] == Mode.RUN


def test_a_controller_restarted_mid_run_starts_from_the_applied_voltage_without_a_kick():
    """SIGKILL-like stop of the controller for 20 ms (< hold_timeout: the board holds), then a new one:
    its first command continues the applied voltage and the plate keeps levitating."""
    loop = RigLoop()
    loop.drv.arm()
    loop.run(1500)
    assert loop.drv.state == DriverState.ACTIVE and loop.ctl.seq.started
    u_before = loop.board.applied.copy()
    loop.kill("controller")
    loop.run(20)
    loop.start("controller")
    k = len(loop.gaps)
    loop.run(2000)
    first = loop.cmds[min(t for t in loop.cmds if t > T0 + (loop.board.n - 2000) * MS)]
    assert np.all(np.abs(np.array(first) - u_before) < 5.0)  # no kick: within 5 V of what the coils held
    assert loop.modes[-1] == Mode.RUN and loop.ctl.seq.counts["starts"] == 1
    assert _min_gap(loop, k) > loop.cfg["plant_sim"]["trip_gap_min"] + 1e-3


def test_a_restarted_reference_resumes_the_schedule_on_the_experiment_clock():
    """The reference killed at t = 0.5 s and restarted at 0.6 s: it rests where the plate is until the plant's
    epoch is known, then its step at t = 1 s happens at t = 1 s of the experiment, not 1 s after the restart."""
    loop = RigLoop(step_time_1=1.0)
    loop.drv.arm()
    loop.run(200)  # active after arm_samples: t = 0 is preroll later
    ep = loop.epoch_ns()
    loop.run(round((ep - T0) / MS) + 500 - loop.board.n)
    assert loop.board.n == round((ep - T0) / MS) + 500
    loop.kill("reference")
    loop.run(100)
    loop.start("reference")
    ref_node = loop.nodes["reference"]
    loop.run(50)
    assert isinstance(ref_node, ReferenceNode) and ref_node.epoch is None  # no epoch yet: resting
    # the plant's loop status (what plant_sim and hw_driver publish once a second) gives it
    D = (loop.bus.msg("diagnostic_msgs/msg/DiagnosticArray"), loop.bus.msg("diagnostic_msgs/msg/DiagnosticStatus"),
         loop.bus.msg("diagnostic_msgs/msg/KeyValue"))
    from dem_ros.nodes.common import diag_array

    loop.bus.publish(contract.DIAGNOSTICS, diag_array(*D, loop.bus.now_ns, contract.HW_LOOP_STATUS, 0, "active",
                                                      {"epoch_ns": ep}))
    loop.run(1500)
    assert ref_node.epoch == ep
    r = {round((t - ep) / MS): v for t, v in loop.refs.items() if t >= ep}
    assert r[999][8] == loop.cfg["reference"]["initial"] and r[1001][8] == loop.cfg["reference"]["target_1"]
    assert loop.modes[-1] == Mode.RUN and _min_gap(loop) > loop.cfg["plant_sim"]["trip_gap_min"] + 1e-3


@pytest.mark.parametrize("restart_before_landing", [True, False])
def test_controller_killed_the_board_lands_then_a_restarted_controller_and_arm_lift_off_again(restart_before_landing):
    """#11: controller killed mid-run -> the driver's watchdog faults, the board lands the plate on its support;
    a new controller (started during the landing, or after it) + arm -> levitating again, never near the rail."""
    loop = RigLoop()
    pc, rig = loop.cfg["plant_sim"], loop.cfg["rig"]
    loop.drv.arm()
    loop.run(1500)
    loop.kill("controller")
    loop.run(100 if restart_before_landing else 3000)
    assert loop.drv.state == DriverState.FAULT and "watchdog" in loop.drv.reason
    loop.start("controller")
    loop.run(3000 if restart_before_landing else 300)
    assert loop.modes[-1] == Mode.LANDED and loop.board.plant.x[0] == pytest.approx(rig["support_gap"])
    assert not loop.ctl.seq.started  # resting: the law waits (a law run against a landed board would wind up)
    loop.drv.arm()
    loop.run(5000)
    assert loop.drv.state == DriverState.ACTIVE and loop.modes[-1] == Mode.RUN and loop.ctl.seq.counts["liftoffs"] == 1
    assert _min_gap(loop) > pc["trip_gap_min"] + 3e-3
    e = np.array(loop.gaps[-1]) - np.array(loop.refs[max(loop.refs)][:2])
    assert np.all(np.abs(e) < 0.3e-3)


def test_a_landing_during_the_lift_off_then_an_arm_at_once_lifts_off_again_without_a_trip():
    """The board lands the plate while the controller lifts it off (here the driver's LAND, as a host stall's
    watchdog would), and the operator arms again as soon as it is LANDED: the controller has stopped its law (the
    board applies 0 V: controller.OFF_SAMPLES), premagnetises and lifts off afresh. Before, the law ran on through
    the landing (its lift-off reference still running, so the resting watch never fired) and the re-armed board
    applied its wound-up command: the plate rose at 100-210 mm/s and the stopping-distance trip landed it at every
    re-arm (the HIL restart test, beside two busy processes)."""
    loop = RigLoop(start="landed")
    pc, rig = loop.cfg["plant_sim"], loop.cfg["rig"]
    loop.run(300)
    loop.drv.arm()
    for _ in range(400):  # until the plate is well off its support, mid-lift-off
        loop.run(20)
        if loop.ctl.seq.liftoff is not None and loop.gaps[-1][0] < rig["support_gap"] - 0.4e-3:
            break
    assert loop.ctl.seq.liftoff is not None, "no lift-off under way"
    loop.drv.disarm()  # LAND
    for _ in range(400):
        loop.run(10)
        if loop.modes[-1] == Mode.LANDED:
            break
    assert loop.modes[-1] == Mode.LANDED
    landed_at = len(loop.modes)
    loop.drv.arm()  # at once, as the HIL test's operator does
    loop.run(6000)
    assert loop.ctl.seq.counts["landed_stops"] >= 1 and loop.ctl.seq.counts["liftoffs"] == 2, loop.ctl.seq.counts
    assert loop.board.sup.counters["trips"] == 0, loop.board.sup.reason
    assert loop.modes[-1] == Mode.RUN and Mode.LAND not in loop.modes[landed_at:]
    assert _min_gap(loop) > pc["trip_gap_min"] + 3e-3
    rise = -np.diff(np.array(loop.gaps[landed_at:]), axis=0).max() / 1e-3
    assert rise < 4 * LIFTOFF_SPEED, f"the second lift-off rose at {rise * 1e3:.1f} mm/s"
    e = np.array(loop.gaps[-1]) - np.array(loop.refs[max(loop.refs)][:2])
    assert np.all(np.abs(e) < 0.3e-3)


@pytest.mark.parametrize("delay", [2, 3, 4, 6])
def test_a_lift_off_with_a_command_delay_is_as_smooth_as_without(delay):
    """The lift-off of the first test, the commands taking ``delay`` samples to the coils and the controller
    predicting over them (as a loaded rig runs them; the HIL tests at 4): within 3 x LIFTOFF_SPEED up, never back
    within 0.25 mm of its support once 1 mm off it, never within 3 mm of trip_gap_min, no landing (the figures,
    before and after the law's hover fit took in the departing plate's acceleration: docs/results.md)."""
    cfg = default_config()
    for g in ("controller", "hw_driver", "plant_sim"):
        cfg[g]["command_delay"] = delay
    cfg["controller"]["max_age"] = (delay + 1) * cfg["controller"]["dt"]
    loop = RigLoop(start="landed", cfg=cfg)
    loop.run(300)
    loop.drv.arm()
    loop.run(5000)
    gaps = np.array(loop.gaps)
    rig, pc = loop.cfg["rig"], loop.cfg["plant_sim"]
    off = int(np.argmax(gaps[:, 0] < rig["support_gap"] - 1e-6))
    rise = (-np.diff(gaps[off:], axis=0) / 1e-3).max()
    assert Mode.LAND not in loop.modes and loop.modes[-1] == Mode.RUN, loop.board.sup.reason
    up = int(np.argmax(gaps.max(axis=1) < rig["support_gap"] - 1e-3))  # both magnets 1 mm off the support
    assert up > off and gaps[up:].max() < rig["support_gap"] - 0.25e-3, gaps[up:].max()
    assert rise < 3 * LIFTOFF_SPEED and gaps.min() > pc["trip_gap_min"] + 3e-3, (rise, gaps.min())

