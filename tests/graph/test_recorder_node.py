"""The recorder node as a process: Ctrl-C finalises the bag; SIGKILL leaves it readable up to its last chunk."""

import os
import signal
import subprocess
import sys
import time

import domains

from dem_ros.bag import BagReader, check


def _domain(offset: int) -> int:
    return domains.hold()  # a domain no other test or run uses, for the rest of this process


FEED = r"""
import sys, time
from dem_ros import contract
from dem_ros.transport import make_node
from dem_ros.nodes.common import joint_state
n = make_node("feeder", transport="dds", args=[])
pub = n.publisher(contract.MEASUREMENT)
JS = n.msg("sensor_msgs/msg/JointState")
end = time.monotonic() + 3
while time.monotonic() < end and pub.subscription_count < 1:
    n.spin_once(0.05)
time.sleep(1.0)  # let the reader match us from its side too (volatile: no history)
print("MATCHED", flush=True)
t0 = time.monotonic_ns()
for k in range(int(sys.argv[1])):
    due = t0 + k * 1_000_000
    while time.monotonic_ns() < due:
        n.spin_once(max(0, due - time.monotonic_ns()) / 1e9)
    pub.publish(joint_state(JS, time.time_ns(), position=(0.008, 0.008), velocity=(0.0, 0.0), effort=(4.0, 4.0)))
print("DONE", flush=True)
time.sleep(1.0)
n.shutdown()
"""


def _record(tmp_path, sig, n_msgs, stop_after):
    domain = _domain(3 if sig == signal.SIGINT else 4)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    bag = tmp_path / "bag"
    rec = subprocess.Popen([sys.executable, "-m", "dem_ros.tools.node_main", "recorder", "--transport", "dds",
                            "--bag", str(bag)],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    end = time.monotonic() + 60
    while time.monotonic() < end and not (bag / "metadata.yaml").exists():
        time.sleep(0.05)
    feed = subprocess.Popen([sys.executable, "-c", FEED, str(n_msgs)], env=env, stdout=subprocess.PIPE, text=True)
    assert feed.stdout.readline().strip() == "MATCHED"
    if stop_after is None:  # stop once everything is published (a busy host can slow the feeder down)
        assert feed.stdout.readline().strip() == "DONE"
        time.sleep(0.5)
    else:
        time.sleep(stop_after)
    rec.send_signal(sig)
    out = rec.communicate(timeout=30)[0]
    feed.kill()
    feed.wait()
    return bag, rec.returncode, out


def test_sigint_finalises_a_complete_bag(tmp_path):
    bag, code, out = _record(tmp_path, signal.SIGINT, 2000, None)
    assert code == 0, out
    rep = check(bag)
    assert rep.ok, rep.format()
    assert rep.truncation is None
    n = BagReader(bag).topics["/dem/measurement"].count
    assert n == 2000, out  # everything published while recording was written
    assert "RECORDER" in out


def test_sigkill_leaves_a_bag_readable_up_to_its_last_chunk(tmp_path):
    bag, code, _out = _record(tmp_path, signal.SIGKILL, 5000, 2.5)
    assert code == -signal.SIGKILL
    rep = check(bag)
    assert rep.truncation is not None  # no summary/footer: check says where it stops
    text = rep.format()
    assert "truncated" in text
    r = BagReader(bag)
    msgs = [m for _, _, m in r.messages(["/dem/measurement"])]
    assert len(msgs) >= 500  # at least the chunks flushed before the kill (flushed every second)
    # and the CLI says the same, without a traceback
    res = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "bag", "check", str(bag)], capture_output=True,
                         text=True)
    assert "truncated" in res.stdout and "Traceback" not in res.stderr


def _level(st) -> int:
    return st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")


def _bare_watch(bus):
    """A node that hosts the recording watch alone, its experiment at t = 2.5 s."""
    from dem_ros import contract
    from dem_ros.nodes.recording_watch import RecordingWatch

    return RecordingWatch(bus.node("plant_sim"), contract.RECORDING_STATUS, lambda: 2.5)


def _plant_sim(bus):
    """The simulator node itself (waiting for its controller: no run, no clock of the experiment yet)."""
    from dem_ros.nodes.plant_sim import PlantSimNode

    return PlantSimNode(bus.node("plant_sim", ["--ros-args", "-p", "start_delay:=0.0", "-p", "min_subscribers:=0"]))


def _recording_watch(make_host=_bare_watch, status=None):
    """The recording watch's host (made by ``make_host`` on the bus) and the recorder's once-a-second reporter on
    one memory bus; the levels and messages of the watch's status (default ``plant_sim: recording``) as
    published."""
    from dem_ros import contract
    from dem_ros.nodes.common import Diagnostics
    from dem_ros.transport.memory import MemoryBus

    bus = MemoryBus()
    host = make_host(bus)
    seen: list[tuple[int, str]] = []
    name = status or contract.RECORDING_STATUS
    bus.node("probe").subscribe(contract.DIAGNOSTICS, lambda m: seen.extend(
        (_level(s), s.message) for s in m.status if s.name == name))
    recorder = Diagnostics(bus.node("recorder"), contract.RECORDER_STATUS)  # the recorder node's reporter
    return bus, host, recorder, seen


def _stall(bus, seconds: float) -> None:
    """The host (or the executor) stalls for ``seconds``: then each timer fires once, as the DDS and rclpy
    timers do (missed periods are skipped, never burst), in the order of the bus (the watch's first)."""
    bus.now_ns += round(seconds * 1e9)
    for t in bus.timers:
        if t.next_ns <= bus.now_ns:
            t.next_ns += (bus.now_ns - t.next_ns) // t.period_ns * t.period_ns  # the latest missed deadline
    bus.spin_once()


def test_a_stall_of_the_host_is_not_a_dead_recorder():
    """Review defect: the watch latched ERROR when the recorder had been silent > 2.5 s of wall time at one
    of its own checks: after a 3 s stall its timer fired before the recorder's and latched a false, permanent
    'recording lost'. Counted in its own checks: one missed report is not a dead recorder."""
    from dem_ros.nodes.common import ERROR, OK

    bus, _watch, _recorder, seen = _recording_watch()
    bus.advance(3.5)
    assert seen and all(level == OK for level, _ in seen), seen
    _stall(bus, 3.0)
    bus.advance(5.0)
    assert all(level != ERROR for level, _ in seen), seen
    assert seen[-1][0] == OK, seen[-3:]
    assert not any("fault: the recorder" in line[2] for line in bus.log)


def test_a_silent_recorder_is_reported_with_the_experiment_time_of_its_last_report():
    """A recorder killed or hung says nothing: the watch latches ERROR on its status when the recorder's
    once-a-second report is missing at RECORDER_MISSED of its own once-a-second checks in a row (2 to 3 s after
    its last report), names the experiment time of that report and logs it once."""
    from dem_ros.nodes.common import ERROR, OK
    from dem_ros.nodes.recording_watch import RECORDER_MISSED

    bus, watch, recorder, seen = _recording_watch()
    bus.advance(3.0)
    assert seen and all(level == OK for level, _ in seen), seen  # alive: it reports every second
    assert watch.values()["recorder"] == "alive" and watch.values()["recorder_last_t_s"] == 2.5
    assert recorder.timer is not None
    recorder.timer.cancel()  # the recorder dies (its last report at t = 3 s)
    bus.advance(RECORDER_MISSED - 0.01)
    assert all(level == OK for level, _ in seen), seen  # not before 2 s
    bus.advance(1.02)
    level, message = seen[-1]  # by 3 s after the last report
    assert level == ERROR and "the recorder has sent no status" in message, seen[-3:]
    assert "its last at t = 2.500 s of the experiment" in message, message
    assert watch.values()["recorder"] == "silent"
    bus.advance(5.0)
    assert seen[-1][0] == ERROR  # latched
    assert sum("fault: the recorder has sent no status" in line[2] for line in bus.log) == 1


def _alive_then_silenced(bus, host, recorder, seen) -> tuple[int, str]:
    """3 s with the recorder reporting (the host's watch says ``alive``), then 3 s after its timer stopped: the
    watch's last (level, message)."""
    bus.advance(3.0)
    assert seen and host.recording.values()["recorder"] == "alive", seen
    assert recorder.timer is not None
    recorder.timer.cancel()
    bus.advance(3.0)
    return seen[-1]


def test_the_plant_simulator_watches_the_recorder_and_the_reference_no_longer_does():
    """The watch lives in the plant node (the one every graph has): ``plant_sim: recording``; the reference node
    publishes no recording status of its own."""
    from dem_ros import contract
    from dem_ros.nodes.common import ERROR
    from dem_ros.nodes.reference import ReferenceNode

    def plant_and_reference(bus):
        plant = _plant_sim(bus)
        ReferenceNode(bus.node("reference"))
        return plant

    bus, plant, recorder, seen = _recording_watch(plant_and_reference)
    names: set[str] = set()
    bus.node("names").subscribe(contract.DIAGNOSTICS, lambda m: names.update(s.name for s in m.status))
    level, message = _alive_then_silenced(bus, plant, recorder, seen)
    assert level == ERROR and "its last at before t = 0 of the experiment" in message, message
    assert contract.RECORDING_STATUS in names and "reference: recording" not in names, sorted(names)
    assert any(line[1] == "/plant_sim" and "fault: the recorder has sent no status" in line[2] for line in bus.log)


def test_the_hardware_driver_watches_the_recorder(monkeypatch):
    """On a rig the driver stands in for the plant: the same watch, on ``hw_driver: recording`` (here before
    the board answered: no experiment yet)."""
    import socket

    from dem_ros import contract
    from dem_ros.nodes.common import ERROR
    from dem_ros.nodes.hw_driver import HwDriverNode

    monkeypatch.setenv("DEM_ROS_RT", "0")
    interval = sys.getswitchinterval()
    board = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # a board that never answers
    board.bind(("127.0.0.1", 0))
    made: list[HwDriverNode] = []

    def driver(bus):
        made.append(HwDriverNode(bus.node("hw_driver", ["--ros-args", "-p",
                                                        f"url:=udp://127.0.0.1:{board.getsockname()[1]}"])))
        return made[-1]

    try:
        bus, hw, recorder, seen = _recording_watch(driver, contract.HW_RECORDING_STATUS)
        level, message = _alive_then_silenced(bus, hw, recorder, seen)
        assert level == ERROR and "the recorder has sent no status" in message and "before t = 0" in message, seen
    finally:
        for hw in made:
            hw.stop.set()
            hw.reader.join(timeout=5)
            if hw.ch is not None:
                hw.ch.close()
        board.close()
        sys.setswitchinterval(interval)
