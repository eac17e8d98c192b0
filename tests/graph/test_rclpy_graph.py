"""The graph on rclpy, and the ROS 2 command line against the rclpy graph and the pure-DDS graph.

Needs a sourced ROS 2 (Jazzy): ``import rclpy`` and the ``ros2`` command. Where either is
missing (CI has no ROS) every test here skips and says which. Nothing is mocked: the nodes are
processes on rmw_cyclonedds (rclpy) or on the PyPI Cyclone DDS (dds), on loopback, in a domain
of their own; the ``ros2`` commands are the real ones a user types.

One S1 run per transport (module fixtures). The plant waits ``START_DELAY`` before its loop,
so the parameter changes, made while every node is up, land before the first sample.
"""

import os
import shutil
import signal
import subprocess
import threading
import time

import pytest

pytest.importorskip("rclpy", reason="rclpy not importable: no ROS 2 sourced (the rclpy graph needs one)")
if shutil.which("ros2") is None:
    pytest.skip("the ros2 command is not on PATH: no ROS 2 sourced", allow_module_level=True)

from dem_ros import contract
from dem_ros.core.scenarios import get_scenario
from dem_ros.core.simulate import simulate
from dem_ros.tools import launcher
from dem_ros.tools.runmetrics import RunMetrics

DURATION = 3.0
START_DELAY = 20.0  # s: covers the ros2 command-line calls below (each starts a Python + a DDS participant)
CLI_TIMEOUT = 60.0  # s: one ros2 call on a loaded 2-core machine (discovery is ~1 s on an idle one)


def _domain(offset: int) -> int:
    return 1 + (os.getpid() * 7 + offset) % 100


def _ros2_env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               RMW_IMPLEMENTATION="rmw_cyclonedds_cpp")
    return env


def _ros2(domain: int, *args: str) -> tuple[int, str]:
    r = subprocess.run(["ros2", *args], capture_output=True, text=True, timeout=CLI_TIMEOUT, env=_ros2_env(domain))
    return r.returncode, r.stdout + r.stderr


def _run(transport: str, offset: int, tmp_path_factory) -> dict:
    """S1 on ``transport``, recorded; the ros2 command line used while it runs."""
    domain = _domain(offset)
    root = tmp_path_factory.mktemp(f"graph_{transport}")
    bag = root / "run"
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["start_delay"] = START_DELAY
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": transport, "config": cfg}
    out: dict = {}

    def run() -> None:
        try:
            out["facts"] = launcher.run_graph(cfg, duration=DURATION, transport=transport, bag=bag, meta=meta,
                                              domain_id=domain, status=False, workdir=root / "logs")
        except Exception as exc:  # reported below with the logs' place
            out["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    # every node up: the launcher starts plant_sim last, once the others said "ready"; a node process
    # prints its REALTIME line when its set-up is done and it starts spinning (dem_ros.realtime)
    marks = {root / "logs" / "controller.log": "ready", root / "logs" / "plant_sim.log": "REALTIME"}
    end = time.monotonic() + 180
    while time.monotonic() < end and not all(p.exists() and m in p.read_text(errors="replace")
                                             for p, m in marks.items()):
        time.sleep(0.1)
    # the first command the controller sends, as `ros2 topic echo` shows it (started before the loop)
    echo = subprocess.Popen(["ros2", "topic", "echo", "--once", contract.COMMAND.name], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=_ros2_env(domain))
    cli = {
        "nodes": _ros2(domain, "node", "list", "--no-daemon"),
        "set_int": _ros2(domain, "param", "set", "--no-daemon", "/controller", "w", "60"),
        "get": _ros2(domain, "param", "get", "--no-daemon", "/controller", "w"),
        "rejected": _ros2(domain, "param", "set", "--no-daemon", "/controller", "k1", "0.5"),
        "get_k1": _ros2(domain, "param", "get", "--no-daemon", "/controller", "k1"),
    }
    try:
        echo_out, _ = echo.communicate(timeout=START_DELAY + 120)
    except subprocess.TimeoutExpired:
        echo.kill()
        echo_out = "(timed out) " + (echo.communicate()[0] or "")
    cli["echo"] = (echo.returncode, echo_out)
    t.join(timeout=600)
    assert not t.is_alive(), "the graph did not finish"
    assert "error" not in out, f"the graph failed: {out.get('error')!r} (logs in {root / 'logs'})"
    return {"bag": bag, "facts": out["facts"], "cli": cli, "cfg": cfg, "domain": domain}


@pytest.fixture(scope="module")
def rclpy_run(tmp_path_factory):
    return _run("rclpy", 11, tmp_path_factory)


@pytest.fixture(scope="module")
def dds_run(tmp_path_factory):
    return _run("dds", 12, tmp_path_factory)


@pytest.fixture(params=["rclpy", "dds"])
def run(request):
    return request.getfixturevalue(f"{request.param}_run")


def test_ros2_node_list_shows_the_graph(run):
    code, text = run["cli"]["nodes"]
    assert code == 0, text
    names = set(text.split())
    assert {"/controller", "/estimator", "/reference", "/plant_sim", "/recorder"} <= names, text


def test_ros2_param_set_integer_literal_on_a_double(run):
    """`ros2 param set /controller w 60`: the CLI sends an INTEGER; the double parameter takes 60.0."""
    code, text = run["cli"]["set_int"]
    assert code == 0 and "Set parameter successful" in text, text
    code, text = run["cli"]["get"]
    assert code == 0 and "60.0" in text, text


def test_ros2_param_set_rejected_with_the_reason(run):
    code, text = run["cli"]["rejected"]
    assert "Setting parameter failed" in text and "Hurwitz" in text, text
    code, text = run["cli"]["get_k1"]
    assert code == 0 and "70.0" in text, text


def test_ros2_topic_echo_shows_a_command(run):
    code, text = run["cli"]["echo"]
    assert code == 0, text
    assert "effort:" in text and "magnet_1" in text, text


def test_parameter_change_recorded_and_loop_tracks(run):
    from dem_ros.bag import BagReader

    events = [m for _, _, m in BagReader(run["bag"]).messages([contract.PARAMETER_EVENTS.name])]
    changed = [(e.node, p.name, p.value.double_value) for e in events for p in e.changed_parameters]
    assert ("/controller", "w", 60.0) in changed
    s = RunMetrics.from_bag(run["bag"])
    assert not s.failed, s
    assert s.loop is not None and s.loop.cycles == int(DURATION * 1000)
    cfg = {g: dict(v) for g, v in run["cfg"].items()}
    offline = simulate(cfg, controller="adaptive", estimator="kf", duration=DURATION).metrics()
    for graph_rms, off_rms in zip(s.rms_error_um, offline["rms_error_um"], strict=True):
        assert graph_rms <= max(2 * off_rms, off_rms + 10.0), (s.rms_error_um, offline["rms_error_um"])


def test_bag_read_back_with_rosbags(run):
    from rosbags.highlevel import AnyReader

    counts = run["facts"]["recorder"]
    assert counts is not None
    assert all(v["dropped"] == 0 and v["received"] == v["written"] for v in counts.values()), counts
    with AnyReader([run["bag"]]) as reader:
        n: dict[str, int] = {}
        for conn, _t, _raw in reader.messages():
            n[conn.topic] = n.get(conn.topic, 0) + 1
    assert n == {k: v["written"] for k, v in counts.items() if v["written"]}


def test_ros2_bag_info_reads_the_bag(run):
    code, text = _ros2(run["domain"], "bag", "info", str(run["bag"]))
    if code != 0 and "invalid choice: 'bag'" in text:
        pytest.skip("ros2 bag (rosbag2) is not part of this ROS 2 install")
    assert code == 0, text
    assert "mcap" in text and contract.COMMAND.name in text, text


def test_rclpy_run_on_rclpy(rclpy_run):
    """The run really was on rclpy: the bag says so, as the recorder saw it."""
    from dem_ros.bag import BagReader

    assert BagReader(rclpy_run["bag"]).run_metadata()["transport"] == "rclpy"


def test_ros2_run_starts_an_installed_node(tmp_path):
    """`ros2 run dem_ros controller` where the package is installed into a ROS 2 overlay."""
    domain = _domain(13)
    r = subprocess.run(["ros2", "pkg", "prefix", "dem_ros"], capture_output=True, text=True, timeout=CLI_TIMEOUT)
    if r.returncode != 0:
        pytest.skip("dem_ros is not installed into a sourced ROS 2 overlay (colcon build --packages-select dem_ros)")
    log = tmp_path / "controller.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(["ros2", "run", "dem_ros", "controller", "--ros-args", "-p", "k1:=80.0"],
                                stdout=out, stderr=subprocess.STDOUT, env=_ros2_env(domain), start_new_session=True)
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and "ready" not in log.read_text(errors="replace") and proc.poll() is None:
            time.sleep(0.1)
        assert "ready" in log.read_text(errors="replace"), log.read_text(errors="replace")
        code, text = _ros2(domain, "param", "get", "--no-daemon", "/controller", "k1")
        assert code == 0 and "80.0" in text, text
    finally:
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C, as a terminal sends it: to ros2 run and the node
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, log.read_text(errors="replace")
