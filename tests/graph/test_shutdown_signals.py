"""Ctrl-C under ``ros2 launch``: SIGINT to each real node process stops it with exit 0, no traceback,
its bag complete - on both transports, one process per node and composed (``container``).

ros2 launch sends SIGINT to every process it started, and escalates to SIGTERM 5 s later (the issue's
``failed to terminate '5' seconds after receiving 'SIGINT'``). Real processes on a leased domain; the
plant runs (lockstep) while the signal comes, so the recorder is writing when it is told to stop.

How fast they stop is a measured figure (the issue asks for 2 s), not asserted here: after SIGINT a
node leaves SCHED_FIFO for its shutdown work, and beside other real-time processes on a 2-core machine
that work can wait tens of seconds for a CPU. The bound below only catches a node that ignores SIGINT.
"""

import json
import os
import signal
import subprocess
import sys
import time

import domains
import pytest

from dem_ros.bag import BagReader, check

TRANSPORTS = ["dds", "rclpy"]
#: a node still running this long after SIGINT ignored it
STOP_S = 120.0
#: the nodes' start-up on a loaded machine (numba kernels from the cache, DDS discovery)
READY_S = 120.0
#: SIGINT comes at the plant's second status line ("t = ...", once a second): its first /diagnostics report, sent
#: with the first line, is then a second old and recorded. At the first line (22 samples in) it could still be on its
#: way when the signal came (CI at acb704f, composed dds: /diagnostics written 0)
STATUS_LINES = 2
#: the plant's parameters: a run that never ends by itself, started as soon as its command writer and measurement
#: readers are matched (start_delay 0: the default's 3 s floor gives discovery time before a run's first samples,
#: which nothing here looks at; the nodes are up before the plant starts, as the launcher has them)
PLANT_ARGS = ["--ros-args", "-p", "duration:=600.0", "-p", "start_delay:=0.0"]


def _transport_or_skip(transport: str) -> None:
    if transport == "rclpy":
        pytest.importorskip("rclpy", reason="rclpy not importable: pip install -e '.[ros]' (make test does)")


def _start(name: str, transport: str, domain: int, log, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "dem_ros.tools.node_main", name, "--transport", transport, *extra],
                            env=env, stdout=log, stderr=subprocess.STDOUT)


def _wait_for(paths_marks: dict, procs: list[subprocess.Popen], timeout: float, times: int = 1) -> None:
    """Until each log holds its mark ``times`` times (``times`` applies to every mark)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if all(p.read_text(errors="replace").count(m) >= times for p, m in paths_marks.items()):
            return
        dead = [p.args for p in procs if p.poll() is not None]
        assert not dead, f"exited before SIGINT: {dead}; logs: " + " | ".join(
            p.read_text(errors="replace")[-2000:] for p in paths_marks)
        time.sleep(0.05)
    raise AssertionError("not ready in time: " + " | ".join(p.read_text(errors="replace")[-2000:] for p in paths_marks))


def _interrupt(procs: dict[str, subprocess.Popen]) -> dict[str, float]:
    """SIGINT to every process at once (as ros2 launch does); seconds until each exited."""
    t0 = time.monotonic()
    for p in procs.values():
        p.send_signal(signal.SIGINT)
    took: dict[str, float] = {}
    end = t0 + STOP_S
    while len(took) < len(procs) and time.monotonic() < end:
        for name, p in procs.items():
            if name not in took and p.poll() is not None:
                took[name] = time.monotonic() - t0
        time.sleep(0.01)
    for name, p in procs.items():  # bounded: a process that ignored SIGINT is killed, the assert says so
        if name not in took:
            p.kill()
            p.wait()
            took[name] = float("inf")
    return took


def _check_stopped(procs: dict[str, subprocess.Popen], took: dict[str, float], logs: dict) -> None:
    for name, p in procs.items():
        text = logs[name].read_text(errors="replace")
        assert p.returncode == 0, f"{name}: exit {p.returncode}\n{text[-3000:]}"
        assert "Traceback" not in text and "KeyboardInterrupt" not in text, f"{name}:\n{text[-3000:]}"
        assert took[name] < STOP_S, f"{name} took {took[name]:.2f} s to stop after SIGINT\n{text[-2000:]}"


def _check_bag(bag, log) -> None:
    """Finalised, and everything the recorder received is in it (its RECORDER line at exit)."""
    rep = check(bag)
    assert rep.ok and rep.truncation is None, rep.format()
    line = [ln for ln in log.read_text(errors="replace").splitlines() if ln.startswith("RECORDER ")]
    assert line, log.read_text(errors="replace")[-2000:]
    counts = json.loads(line[-1][len("RECORDER "):])
    assert all(c["dropped"] == 0 and c["received"] == c["written"] for c in counts.values()), counts
    topics = BagReader(bag).topics
    assert all(topics[t].count == c["written"] for t, c in counts.items() if c["written"]), counts
    assert counts["/diagnostics"]["written"] > 0, counts


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_sigint_stops_every_node_process(transport, tmp_path):
    _transport_or_skip(transport)
    domain = domains.hold()
    bag = tmp_path / "bag"
    names = ["recorder", "reference", "estimator", "controller", "plant_sim"]
    logs = {n: tmp_path / f"{n}.log" for n in names}
    procs: dict[str, subprocess.Popen] = {}
    try:
        for n in names:
            extra = {"recorder": ["--bag", str(bag)], "plant_sim": PLANT_ARGS}.get(n, [])
            with open(logs[n], "wb") as out:
                procs[n] = _start(n, transport, domain, out, *extra)
            if n == "controller":  # the plant starts last, as the launcher does
                _wait_for({logs[k]: "ready" for k in names[:4]}, list(procs.values()), READY_S)
        _wait_for({logs["recorder"]: "ready"}, list(procs.values()), READY_S)
        _wait_for({logs["plant_sim"]: "t ="}, list(procs.values()), READY_S, times=STATUS_LINES)
        took = _interrupt(procs)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    _check_stopped(procs, took, logs)
    _check_bag(bag, logs["recorder"])


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_sigint_stops_the_composed_graph(transport, tmp_path):
    _transport_or_skip(transport)
    domain = domains.hold()
    bag = tmp_path / "bag"
    logs = {"container": tmp_path / "container.log"}
    procs: dict[str, subprocess.Popen] = {}
    try:
        with open(logs["container"], "wb") as out:
            procs["container"] = _start("container", transport, domain, out, "--bag", str(bag), *PLANT_ARGS)
        _wait_for({logs["container"]: "t ="}, list(procs.values()), READY_S, times=STATUS_LINES)
        took = _interrupt(procs)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    _check_stopped(procs, took, logs)
    _check_bag(bag, logs["container"])
