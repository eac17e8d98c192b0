"""The rclpy transport in a running graph, with rclpy from the ``ros`` extra (Jazzy on Fast DDS; no ROS install).

* Both vendors in one graph: the controller on rclpy / Fast DDS, every other node on the dds transport /
  Cyclone DDS. The loop closes, and the plant's ``/dem/command`` source lock holds: the commands of the
  Fast DDS controller are attributed to ``/controller`` through the Cyclone side's graph
  (``ros_discovery_info`` + DCPSPublication) and no command counts as foreign.
* A stock rclpy client (``rcl_interfaces/srv/SetParameters``, as ``ros2 param set`` sends it) sets
  ``/controller w`` five times while the rclpy graph runs free, composed; every call is answered, and
  the changes reach the controller (its ``/parameter_events`` in the bag). The client process starts with the
  graph and finds the service meanwhile; it makes its calls once the run is under way (t = 0).

Real node processes on a leased domain, on loopback; the bag read back.
"""

import json
import os
import subprocess
import sys
import threading
import time

import domains
import pytest

pytest.importorskip("rclpy",
                    reason="rclpy not importable: pip install -e '.[ros]' (make test does where the wheels exist)")

from dem_ros import contract
from dem_ros.bag import BagReader
from dem_ros.core.scenarios import get_scenario
from dem_ros.core.simulate import simulate
from dem_ros.tools import launcher
from dem_ros.tools.runmetrics import RunMetrics

DURATION = 3.0
#: the stock client's answer bound the issue sets (a call measured from request to response)
ANSWER_S = 1.0


def _plant_loop_values(bag) -> dict[str, str]:
    last: dict[str, str] = {}
    for _, _, msg in BagReader(bag).messages([contract.DIAGNOSTICS.name]):
        for st in msg.status:
            if st.name == contract.LOOP_STATUS:
                last = {kv.key: kv.value for kv in st.values}
    return last


def test_controller_on_rclpy_fastdds_closes_the_loop_of_a_dds_cyclone_graph(tmp_path):
    cfg = get_scenario("S1").config()
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds+rclpy", "config": cfg}
    bag = tmp_path / "run"
    facts = launcher.run_graph(cfg, duration=DURATION, transport="dds", node_transports={"controller": "rclpy"},
                               bag=bag, meta=meta, domain_id=domains.hold(), status=False, workdir=tmp_path / "logs")
    assert facts["recorder"] is not None
    s = RunMetrics.from_bag(bag)
    assert not s.failed, s
    assert s.loop is not None and s.loop.cycles == int(DURATION * 1000), s.loop
    offline = simulate({g: dict(v) for g, v in cfg.items()}, controller="adaptive", estimator="kf",
                       duration=DURATION).metrics()
    for graph_rms, off_rms in zip(s.rms_error_um, offline["rms_error_um"], strict=True):
        assert graph_rms <= max(2 * off_rms, off_rms + 10.0), (s.rms_error_um, offline["rms_error_um"])
    v = _plant_loop_values(bag)
    assert v.get("command_source") == "controller", v
    # the lock bound one writer (the rclpy controller's, by its GID) and refused none
    assert len(v.get("command_writer", "")) == 32 and v.get("commands_foreign") == "0", v
    # the vendors, by the threads each node process raised to real time (when it did: DEM_ROS_RT):
    # Fast DDS's receive threads are dds.udp.*, Cyclone's recv (dem_ros.realtime)
    threads = {n: _fifo_threads(tmp_path / "logs" / f"{n}.log") for n in ("controller", "plant_sim")}
    if threads["controller"] and threads["plant_sim"]:
        assert any(t.startswith("dds.udp.") for t in threads["controller"]) and "recv" not in threads["controller"]
        assert "recv" in threads["plant_sim"] and not any(t.startswith("dds.udp.") for t in threads["plant_sim"])


def _fifo_threads(log) -> list[str]:
    """The threads a node process set to SCHED_FIFO, from its REALTIME line (empty without real time)."""
    for line in log.read_text(errors="replace").splitlines():
        if line.startswith("REALTIME "):
            return [t.split(" (")[0] for t in json.loads(line[len("REALTIME "):])["fifo_threads"]]
    return []


CLIENT = r"""
import json, sys, time
import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor

rclpy.init(args=[], domain_id=int(sys.argv[1]))
node = rclpy.create_node("stock_param_client")
ex = SingleThreadedExecutor()
ex.add_node(node)
cli = node.create_client(SetParameters, "/controller/set_parameters")
end = time.monotonic() + 120
while not cli.service_is_ready() and time.monotonic() < end:
    ex.spin_once(timeout_sec=0.05)
if not cli.service_is_ready():
    print(json.dumps({"error": "no /controller/set_parameters within 120 s"}), flush=True)
    sys.exit(1)
sys.stdin.readline()  # the test's go: the run is under way
out = []
for w in sys.argv[2:]:
    req = SetParameters.Request(parameters=[Parameter(name="w", value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=float(w)))])
    t0 = time.monotonic()
    fut = cli.call_async(req)
    limit = t0 + 30
    while not fut.done() and time.monotonic() < limit:
        ex.spin_once(timeout_sec=0.005)
    took = time.monotonic() - t0
    res = fut.result().results[0] if fut.done() else None
    out.append({"w": float(w), "s": took, "ok": bool(res and res.successful),
                "reason": res.reason if res else "no answer"})
print(json.dumps({"calls": out}), flush=True)
node.destroy_node()
rclpy.shutdown()
"""


def _past_t0(log) -> bool:
    """Whether the plant's status lines (``t = <s> s ...``, once a second; 0.0 until t = 0) show the run under way."""
    text = log.read_text(errors="replace") if log.exists() else ""
    lines = text.replace("\r", "\n").splitlines()
    return any(float(ln.split()[2]) > 0.0 for ln in lines if ln.startswith("t =") and len(ln.split()) > 2)


#: the free-running graph's length: the five calls (each answered within ANSWER_S, asserted) are made from t = 0
STOCK_RUN_S = 8.0


def test_a_stock_rclpy_client_sets_parameters_of_the_free_running_rclpy_graph(tmp_path):
    domain = domains.hold()
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["lockstep"] = False
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "rclpy", "config": cfg}
    bag = tmp_path / "run"
    out: dict = {}

    def run() -> None:
        try:
            out["facts"] = launcher.run_graph(cfg, duration=STOCK_RUN_S, transport="rclpy", compose=True, bag=bag,
                                              meta=meta, domain_id=domain, status=False, workdir=tmp_path / "logs")
        except Exception as exc:  # reported below
            out["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    values = ["61", "62", "63", "64", "65"]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    client = subprocess.Popen([sys.executable, "-c", CLIENT, str(domain), *values], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        log = tmp_path / "logs" / "container.log"
        end = time.monotonic() + 180
        while time.monotonic() < end and not _past_t0(log) and t.is_alive():
            time.sleep(0.1)
        stdout, stderr = client.communicate(input="go\n", timeout=400)  # the calls, now
    finally:
        if client.poll() is None:
            client.kill()
            client.wait()
    r = subprocess.CompletedProcess(client.args, client.returncode, stdout, stderr)
    t.join(timeout=300)
    assert not t.is_alive(), "the graph did not finish"
    assert "error" not in out, out.get("error")
    assert r.returncode == 0, r.stdout + r.stderr
    calls = json.loads(r.stdout.strip().splitlines()[-1])["calls"]
    assert [c["ok"] for c in calls] == [True] * 5, calls
    slow = [c for c in calls if c["s"] >= ANSWER_S]
    assert not slow, calls
    events = [m for _, _, m in BagReader(bag).messages([contract.PARAMETER_EVENTS.name])]
    changed = [p.value.double_value for e in events if e.node == "/controller" for p in e.changed_parameters
               if p.name == "w"]
    assert changed == [61.0, 62.0, 63.0, 64.0, 65.0], changed


def test_dem_ros_param_reaches_the_rclpy_graph_through_rclpys_own_clients(tmp_path):
    """``dem-ros param`` on a graph of rclpy nodes (Fast DDS): get, set, and the node's reason for a refusal (the
    dds transport's client speaks rmw_cyclonedds' request header, which these services do not read)."""
    domain = domains.hold()
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["lockstep"] = False
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "rclpy", "config": cfg}
    out: dict = {}

    def run() -> None:
        try:
            out["facts"] = launcher.run_graph(cfg, duration=20.0, transport="rclpy", compose=True, bag=None,
                                              meta=meta, domain_id=domain, status=False, workdir=tmp_path / "logs")
        except Exception as exc:  # reported below
            out["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    env = {k: v for k, v in os.environ.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}  # the CLI's own default
    env["ROS_DOMAIN_ID"] = str(domain)

    def param(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "param", *argv, "--timeout", "30"],
                              capture_output=True, text=True, env=env, timeout=120)

    try:
        log = tmp_path / "logs" / "container.log"
        end = time.monotonic() + 180
        while time.monotonic() < end and not _past_t0(log) and t.is_alive():
            time.sleep(0.1)
        got = param("get", "controller", "w")
        setting = param("set", "controller", "w", "57")
        again = param("get", "/controller", "w")
        refused = param("set", "controller", "dt", "0.002")  # valid by the schema, read-only on the running node
    finally:
        t.join(timeout=300)
    assert not t.is_alive() and "error" not in out, out.get("error")
    assert (got.returncode, got.stdout.strip()) == (0, "50.0"), got.stdout + got.stderr
    assert setting.returncode == 0 and "Set parameter successful" in setting.stdout, setting.stdout + setting.stderr
    assert (again.returncode, again.stdout.strip()) == (0, "57.0"), again.stdout + again.stderr
    assert refused.returncode == 1 and "read-only parameter: dt" in refused.stderr, refused.stderr
