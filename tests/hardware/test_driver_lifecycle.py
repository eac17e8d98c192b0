"""``hw_driver`` as a managed node: the wiring of its lifecycle to the driver, on the in-memory transport, with a test
board on loopback UDP (its real link thread; no process, no DDS).

The board here is a few lines: it answers a hello request (and then streams to the sender, as the real one does),
takes up RUN on a RUN command, LAND on a LAND command while levitating and reports LANDED ``land_frames`` samples
later, and OFF on an OFF command once down. It samples every 5 ms (its clock says 1 ms) with a command delay of 8
samples, so the test's controller, run by the test's thread, answers in time on a loaded machine. Time: the
node's timers run on the bus's clock (``bus.advance``); what a transition waits for (the board's answers) and its
deadline are real time.
"""

from __future__ import annotations

import socket
import sys
import threading
import time

import pytest

from dem_ros import contract
from dem_ros.hardware.boardcfg import config_crc
from dem_ros.hardware.driver import DriverState
from dem_ros.hardware.link import (
    PROTOCOL_VERSION,
    CommandFrame,
    ConfigAck,
    ConfigFrame,
    Hello,
    Mode,
    SensorFrame,
    decode,
    encode,
)
from dem_ros.nodes.hw_driver import HwDriverNode
from dem_ros.transport.dds import lifecycle_msgs as lm
from dem_ros.transport.lifecycle import event_topic
from dem_ros.transport.memory import MemoryBus

N_GAP = 19283  # counts of the default calibration near 5 mm (tests/hardware/test_driver.py)
N_CUR = 32768 + 8192  # and 2.5 A
#: the driver armed: ARMED, or ACTIVE already when the test's controller answered arm_samples measurements meanwhile
ARMED = (DriverState.ARMED, DriverState.ACTIVE)
#: the board's command delay (samples) and real sample period (s): 40 ms for the test's controller to answer
DELAY, PERIOD_S = 8, 0.005


class Board:
    """A board on loopback UDP that answers hellos and configurations and follows the driver's RUN / LAND / OFF
    commands."""

    def __init__(self, land_frames: int = 30) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(PERIOD_S)
        self.port = self.sock.getsockname()[1]
        self.mode = Mode.OFF
        self.land_frames = land_frames
        self.lands = True
        self.hellos = 0
        self.peer: tuple[str, int] | None = None
        self.commands: list[CommandFrame] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        seq, landing = 0, 0
        while not self.stop.is_set():
            if self.peer is not None:
                self.sock.sendto(encode(SensorFrame(seq, seq * 1000, (N_GAP, N_GAP), (N_CUR, N_CUR), (50.0, 50.0),
                                                    200.0, 0, self.mode)), self.peer)
                seq += 1
            try:
                while True:
                    data, addr = self.sock.recvfrom(256)
                    f = decode(data)
                    if isinstance(f, Hello) and f.is_request:
                        self.hellos += 1
                        self.peer = addr
                        self.sock.sendto(encode(Hello(PROTOCOL_VERSION, 7, 1000, 16, 10.0, 50, DELAY)), addr)
                    elif isinstance(f, ConfigFrame):  # the driver's configuration: taken (a board at rest)
                        crc = config_crc(f)
                        self.sock.sendto(encode(ConfigAck(crc, crc, 0, True, self.mode)), addr)
                    elif isinstance(f, CommandFrame):
                        self.commands.append(f)
                        if f.mode == Mode.LAND and self.mode in (Mode.RUN, Mode.HOLD):
                            self.mode, landing = Mode.LAND, 0
                        elif f.mode == Mode.OFF and self.mode in (Mode.LANDED, Mode.FAULT):
                            self.mode = Mode.OFF
                        elif f.mode == Mode.RUN and self.mode in (Mode.OFF, Mode.RUN, Mode.HOLD):
                            self.mode = Mode.RUN
            except (TimeoutError, BlockingIOError, OSError):
                pass
            if self.mode == Mode.LAND and self.lands:
                landing += 1
                if landing >= self.land_frames:
                    self.mode = Mode.LANDED

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)
        self.sock.close()


class Rig:
    """The driver node on a memory bus before a test board; a controller node that answers every measurement."""

    def __init__(self, board: Board, **params: object) -> None:
        self.board = board
        self.bus = MemoryBus()
        args = ["--ros-args", "-p", f"url:=udp://127.0.0.1:{board.port}", "-p", "clock_sync_frames:=5",
                "-p", f"command_delay:={DELAY}", "-p", "arm_samples:=5",
                "-p", "link_timeout:=5.0", "-p", "hold_timeout:=1.0"]
        for k, v in params.items():
            args += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
        self.node = self.bus.node("hw_driver", args)
        self.events: list = []
        self.states: list = []
        probe = self.bus.node("probe")
        probe.subscribe(contract.HW_STATE, self.states.append)
        probe.subscribe(event_topic("/hw_driver"), self.events.append)
        self.hw = HwDriverNode(self.node)
        self.controller = self.bus.node("controller")
        self.cmd = self.controller.publisher(contract.COMMAND)
        self.controller.subscribe(contract.MEASUREMENT, self._answer)
        self.JS = self.bus.msg("sensor_msgs/msg/JointState")

    def _answer(self, m) -> None:
        """The controller: a hover command stamped with the measurement it answers."""
        if m.header.frame_id:
            cmd = self.JS()
            cmd.header.stamp = m.header.stamp
            cmd.effort = [50.0, 50.0]
            self.cmd.publish(cmd)

    def run_until(self, cond, timeout_s: float = 10.0, step_s: float = 0.02) -> None:
        """Run the bus (its clock in steps, the board and the link thread in real time) until ``cond()``."""
        end = time.monotonic() + timeout_s
        while not cond() and time.monotonic() < end:
            self.bus.advance(step_s)
            time.sleep(step_s / 4)
        assert cond(), f"not within {timeout_s:g} s: lifecycle {self.hw.machine.label}, driver " \
                       f"{self.hw.drv.state.name}, board {self.board.mode.name}"

    def levitating(self) -> bool:
        """Active, and the driver has seen the board run its commands."""
        return self.hw.machine.label == "active" and self.hw.drv.board_mode == Mode.RUN

    def state(self) -> str:
        return self.bus.call("/hw_driver/get_state").current_state.label

    def change(self, transition: int | str):
        t = lm.Transition(id=transition, label="") if isinstance(transition, int) else \
            lm.Transition(id=0, label=transition)
        return self.bus.call("/hw_driver/change_state", transition=t)

    def request(self, verb: str) -> None:
        msg = self.bus.msg("std_msgs/msg/String")()
        msg.data = verb
        self.bus.publish(contract.HW_REQUEST, msg)
        self.bus.spin_once()

    def steps(self) -> list[tuple[str, str]]:
        return [(e.start_state.label, e.goal_state.label) for e in self.events]


@pytest.fixture
def make_rig(monkeypatch):
    monkeypatch.setenv("DEM_ROS_RT", "0")
    interval = sys.getswitchinterval()
    made: list[tuple[Rig, Board]] = []

    def make(board_kw: dict | None = None, **params: object) -> Rig:
        board = Board(**(board_kw or {}))
        try:
            rig = Rig(board, **params)
        except BaseException:
            board.close()
            raise
        made.append((rig, board))
        return rig

    yield make
    for rig, board in made:
        rig.hw.close()
        board.close()
    sys.setswitchinterval(interval)


def test_the_node_configures_itself_at_start_and_auto_arm_makes_it_active(make_rig):
    rig = make_rig(auto_arm=True)
    assert rig.hw.machine.label == "configuring"  # until the board answers the hello
    assert rig.hw.drv.state == DriverState.ARMED  # auto_arm arms at once, as it always did
    rig.run_until(lambda: rig.hw.machine.label == "active")
    assert rig.state() == "active"
    assert rig.steps() == [("unconfigured", "configuring"), ("configuring", "inactive"), ("inactive", "activating"),
                           ("activating", "active")]
    rig.run_until(lambda: rig.board.mode == Mode.RUN and rig.hw.drv.state == DriverState.ACTIVE)  # lifted off
    assert rig.states[-1].values and any(kv.key == "lifecycle" and kv.value == "active" for kv in rig.states[-1].values)


def test_without_auto_arm_it_waits_inactive_and_the_services_answer(make_rig):
    rig = make_rig()
    rig.run_until(lambda: rig.hw.machine.label == "inactive")
    assert rig.hw.drv.state == DriverState.INACTIVE and rig.board.mode == Mode.OFF
    av = rig.bus.call("/hw_driver/get_available_transitions").available_transitions
    assert [(t.transition.label, t.goal_state.label) for t in av] == [
        ("cleanup", "cleaningup"), ("activate", "activating"), ("shutdown", "shuttingdown")]
    assert len(rig.bus.call("/hw_driver/get_transition_graph").available_transitions) == 25
    assert len(rig.bus.call("/hw_driver/get_available_states").available_states) == 11
    assert not rig.change("deactivate").success and rig.state() == "inactive"  # not valid from inactive
    assert rig.change(3).success and rig.state() == "active" and rig.hw.drv.state in ARMED
    rig.run_until(lambda: rig.board.mode == Mode.RUN)


def test_deactivate_lands_the_plate_and_answers_once_the_board_reports_landed(make_rig):
    rig = make_rig(auto_arm=True)
    rig.run_until(rig.levitating)
    rep = rig.change("deactivate")
    assert rig.state() == "deactivating" and not rep.success  # not answered yet: the landing goes on
    assert rig.hw.drv.state == DriverState.INACTIVE
    rig.run_until(lambda: rig.hw.machine.label != "deactivating")
    assert rig.board.mode == Mode.LANDED and any(c.mode == Mode.LAND for c in rig.board.commands)
    assert rig.state() == "inactive" and rep.success  # answered now
    assert rig.steps()[-2:] == [("active", "deactivating"), ("deactivating", "inactive")]
    assert rig.events[-1].transition.label == "transition_success" and rig.events[-1].transition.id == 40
    # activate: armed again; the board leaves its latched landing (OFF) and lifts off under the controller
    assert rig.change("activate").success and rig.state() == "active"
    rig.run_until(lambda: rig.board.mode == Mode.RUN and rig.hw.drv.state == DriverState.ACTIVE)


def test_a_landing_the_board_does_not_confirm_in_time_is_an_error(make_rig):
    rig = make_rig({"land_frames": 10**9}, auto_arm=True, transition_timeout=0.3)
    rig.run_until(rig.levitating)
    rep = rig.change("deactivate")
    rig.run_until(lambda: rig.hw.machine.label != "deactivating")
    assert not rep.success and rig.state() == "unconfigured"  # through errorprocessing: still landing (LAND)
    assert rig.steps()[-2:] == [("deactivating", "errorprocessing"), ("errorprocessing", "unconfigured")]
    assert rig.hw.drv.state == DriverState.INACTIVE and rig.board.mode == Mode.LAND


def test_a_driver_fault_while_active_goes_through_errorprocessing_and_an_arm_activates_again(make_rig):
    """As ros2_control's hardware components: an error -> on_error (the plate is landed) -> unconfigured."""
    rig = make_rig(auto_arm=True)
    rig.run_until(rig.levitating)
    rig.request("estop test")
    assert rig.hw.drv.state == DriverState.FAULT
    assert rig.state() == "unconfigured"  # reflected at once
    assert rig.steps()[-3:] == [("active", "deactivating"), ("deactivating", "errorprocessing"),
                                ("errorprocessing", "unconfigured")]
    rig.run_until(lambda: rig.board.mode == Mode.LANDED)  # the latched fault sends LAND
    assert rig.hw.ch is not None  # the link stays open: the board's reports go on
    rig.request("arm")  # dem-ros hw arm: configure (the board answered on this link) and activate
    assert rig.state() == "active" and rig.hw.drv.state in ARMED and rig.hw.answer.startswith("armed")
    rig.run_until(lambda: rig.board.mode == Mode.RUN)


def test_hw_disarm_is_a_deactivate_and_an_arm_during_the_landing_calls_it_off(make_rig):
    rig = make_rig({"land_frames": 10**9}, auto_arm=True)
    rig.run_until(rig.levitating)
    rig.request("disarm")
    assert rig.state() == "deactivating" and rig.hw.answer.startswith("disarmed")
    rig.run_until(lambda: rig.board.mode == Mode.LAND)
    rig.request("arm")  # the landing called off: the deactivate fails, back to active
    assert rig.state() == "active" and rig.hw.drv.state in ARMED
    assert rig.events[-1].transition.label == "transition_failure"


def test_the_end_of_the_run_disarm_is_followed_as_a_deactivate(make_rig):
    rig = make_rig(auto_arm=True)
    rig.run_until(rig.levitating)
    with rig.hw.lock:
        rig.hw.drv.disarm()  # what the reader thread does after `duration`
    rig.run_until(lambda: rig.hw.machine.label == "inactive")
    assert rig.board.mode == Mode.LANDED and rig.steps()[-1] == ("deactivating", "inactive")


def test_cleanup_closes_the_link_and_configure_opens_it_and_handshakes_again(make_rig):
    rig = make_rig()
    rig.run_until(lambda: rig.hw.machine.label == "inactive")
    assert rig.change("cleanup").success and rig.state() == "unconfigured"
    assert rig.hw.ch is None and not rig.hw.reader.is_alive()
    hellos = rig.board.hellos
    rep = rig.change("configure")
    assert rig.state() == "configuring" and rig.hw.ch is not None
    rig.run_until(lambda: rig.hw.machine.label == "inactive")
    assert rep.success and rig.board.hellos > hellos


def test_a_configure_the_board_does_not_answer_fails_after_the_timeout(make_rig):
    rig = make_rig(transition_timeout=0.3)
    rig.run_until(lambda: rig.hw.machine.label == "inactive")
    rig.change("cleanup")
    rig.board.close()  # nobody answers now
    rep = rig.change("configure")
    rig.run_until(lambda: rig.hw.machine.label != "configuring")
    assert not rep.success and rig.state() == "unconfigured"


def test_shutdown_lands_then_finalizes_and_the_node_ends(make_rig):
    rig = make_rig(auto_arm=True)
    rig.run_until(rig.levitating)
    rep = rig.change("shutdown")
    assert rig.state() == "shuttingdown"
    rig.run_until(lambda: rig.node.is_shutdown)
    assert rep.success and rig.hw.machine.label == "finalized" and rig.board.mode == Mode.LANDED
