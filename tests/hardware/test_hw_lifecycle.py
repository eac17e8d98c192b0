"""``hw_driver`` as a managed node on a rig, over real UDP: a lifecycle client in a process of its own lands the
levitating plate with a deactivate and lifts it off again with an activate, on each transport.

``dem-ros rig`` (the emulated board, its own process), ``hw_driver`` (its own process) and the estimator,
controller and reference composed in one container, as ``dem-ros launch --hardware rig --compose`` runs them,
the driver armed at start (``auto_arm``: the node configures itself, then activates). The client
(tests/hardware/lifecycle_client.py) is a stock rclpy one on the rclpy transport; on the dds transport it is the
project's dds client (a Fast DDS client's calls do not reach a Cyclone DDS node's services: see its docstring).
It waits until the plate levitates, asks get_state (active) and get_available_transitions, deactivates (answered
once the board reports LANDED: inactive), activates (active) and waits until the board runs the controller's
commands again (the controller saw the plate resting and lifts it off). Then what ``ros2 lifecycle nodes`` does
(stock rclpy, on either transport: discovery crosses vendors) finds ``/hw_driver`` and its five services. The
driver is stopped (SIGINT) once the controller's lift-off is done: it lands the plate and the run ends.

Settings as tests/hardware/test_hw_restart.py (a loaded 2-core machine): command delay 4 samples, the driver's own
watchdogs 0.3 s (the board's 50 ms stay what lands the plate on a real stall).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rig_events import rig_events

from dem_ros.core.scenarios import get_scenario
from dem_ros.tools.launcher import run_graph

ROOT = Path(__file__).resolve().parents[2]
CLIENT = Path(__file__).with_name("lifecycle_client.py")
DELAY = 4
LIMIT_S = 400.0  # s: the whole sequence, start-up included, on a loaded machine; then the run is stopped


def _first_landing(workdir: Path) -> dict | None:
    """The emulated board's first ``mode`` event into LAND (or LANDED): the rig announces one at each mode change,
    with its reason (its once-a-second status can miss it: a landing, LANDED and the driver's OFF that clears the
    reason all fell between two reports in a CI run)."""
    return next((ev for ev in rig_events(workdir, "mode") if ev.get("mode") in ("LAND", "LANDED")), None)


def _rig_status(workdir: Path) -> dict:
    """The emulated board's newest status (mode, true gaps, landings; once a second), {} before the first."""
    statuses = rig_events(workdir, "status")
    return statuses[-1] if statuses else {}


class Script:
    """``run_graph``'s supervisor: starts the client; notes the board's first landing (why) and, after the
    client's activate, the plate off its support (the board's true gaps); stops the driver once the client is
    done and the controller's lift-off is done (or the limit is reached)."""

    def __init__(self, workdir: Path, via: str, domain: int, support_mm: float):
        self.workdir, self.via, self.domain, self.support_mm = workdir, via, domain, support_mm
        self.start = time.monotonic()
        self.client: subprocess.Popen | None = None
        self.out = workdir.parent / f"client-{via}.log"
        self.nodes: subprocess.Popen | None = None  # then `ros2 lifecycle nodes`, stock rclpy
        self.nodes_out = workdir.parent / "client-nodes.log"
        self.phase = "client"
        self.first_landing: dict | None = None  # the board's mode line as it first landed the plate (with why)
        self.lifted: dict | None = None  # the board's status once the plate is off its support after the activate

    def _liftoffs(self) -> int:
        try:
            return (self.workdir / "container.log").read_text(errors="replace").count("lift-off done")
        except OSError:
            return 0

    def __call__(self, t: float | None, procs: dict, restart) -> set[str]:
        st = _rig_status(self.workdir)
        if self.first_landing is None:
            self.first_landing = _first_landing(self.workdir)
        flying = st.get("mode") == "RUN" and max(st.get("gaps_mm", [99, 99])) < self.support_mm - 1.0
        if self.phase != "client" and self.lifted is None and flying and st.get("landings", 0) == 1:
            self.lifted = st
        if self.client is None:
            self.client = self._start(self.via, self.out)
        elif self.phase == "client" and (self.client.poll() is not None or time.monotonic() - self.start > LIMIT_S):
            self.phase = "nodes"
            self.nodes = self._start("nodes", self.nodes_out)
        elif self.phase == "nodes" and (self.nodes is None or self.nodes.poll() is not None
                                        or time.monotonic() - self.start > LIMIT_S):
            self.phase = "lift-off"
        elif self.phase == "lift-off" and ((self._liftoffs() >= 1 and self.lifted is not None)
                                           or time.monotonic() - self.start > LIMIT_S):
            self.phase = "stop"
            procs["hw_driver"].send_signal(signal.SIGINT)  # the driver lands the plate, then exits: the run ends
        return set()

    def _start(self, via: str, out: Path) -> subprocess.Popen:
        env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        with open(out, "w") as log:
            return subprocess.Popen([sys.executable, str(CLIENT), via, str(self.domain)], cwd=ROOT, env=env,
                                    stdout=log, stderr=subprocess.STDOUT)

    def close(self) -> None:
        for p in (self.client, self.nodes):
            if p is not None and p.poll() is None:
                p.kill()
            if p is not None:
                p.wait(timeout=30)

    def result(self, out: Path | None = None) -> dict:
        out = out or self.out
        lines = out.read_text(errors="replace").splitlines() if out.exists() else []
        for line in reversed(lines):
            if line.startswith("RESULT "):
                return json.loads(line[len("RESULT "):])
        return {"error": "no RESULT line", "log": lines[-30:]}


@pytest.mark.parametrize("transport", ["dds", "rclpy"])
def test_a_lifecycle_client_lands_and_lifts_off_the_plate_over_udp(tmp_path, domain_id, transport):
    pytest.importorskip("rclpy", reason="rclpy not importable: pip install -e '.[ros]' (the stock clients)")
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["measure_velocity"] = False  # a rig has no gap-rate sensors
    for g in ("controller", "hw_driver", "plant_sim"):
        cfg[g]["command_delay"] = DELAY
    cfg["controller"]["max_age"] = (DELAY + 1) * cfg["controller"]["dt"]
    cfg["hw_driver"]["hold_timeout"] = cfg["hw_driver"]["link_timeout"] = 0.3  # the PC's watchdogs; the board's: 50 ms
    cfg["hw_driver"]["transition_timeout"] = 30.0  # a landing on a loaded machine: seconds, not tens of them
    workdir = tmp_path / "run"
    script = Script(workdir, transport, domain_id, cfg["rig"]["support_gap"] * 1e3)
    t0 = time.monotonic()
    try:
        facts = run_graph(cfg, duration=2 * LIMIT_S, transport=transport, bag=None,
                          meta={"scenario": "S1", "duration_s": LIMIT_S}, domain_id=domain_id, status=False,
                          workdir=workdir, hardware="rig", supervise=script, compose=True)
    finally:
        script.close()
    res = script.result()
    logs = {n: Path(p).read_text(errors="replace")[-2500:] for n, p in facts["logs"].items()}
    assert "error" not in res, (res, logs)
    steps = {s["what"]: s for s in res["steps"]}
    assert steps["levitating"]["lifecycle"] == [3, "active"], steps
    assert steps["available"]["transitions"] == ["deactivate", "shutdown"], steps
    assert steps["deactivate"]["success"] and steps["deactivate"]["lifecycle"] == [2, "inactive"], steps
    assert steps["landed"]["hw"]["board_mode"] == "landed" and steps["landed"]["hw"]["state"] == "inactive", steps
    assert steps["activate"]["success"] and steps["activate"]["lifecycle"] == [3, "active"], steps
    assert steps["levitating again"]["hw"] == {"state": "active", "board_mode": "run", "lifecycle": "active"}, steps
    # the transition events: deactivate (active -> deactivating -> inactive), then activate
    seq = [(e["id"], e["start"], e["goal"]) for e in res["events"]]
    assert seq[:4] == [(4, "active", "deactivating"), (40, "deactivating", "inactive"), (3, "inactive", "activating"),
                       (30, "activating", "active")], res["events"]
    assert [e["label"] for e in res["events"][:4]] == ["deactivate", "transition_success", "activate",
                                                       "transition_success"]
    # `ros2 lifecycle nodes` (stock rclpy, Fast DDS) finds /hw_driver and its five services, on either transport
    nodes = script.result(script.nodes_out)
    assert "/hw_driver" in nodes.get("nodes", []), nodes
    assert nodes["services"] == {
        "/hw_driver/get_state": ["lifecycle_msgs/srv/GetState"],
        "/hw_driver/change_state": ["lifecycle_msgs/srv/ChangeState"],
        "/hw_driver/get_available_states": ["lifecycle_msgs/srv/GetAvailableStates"],
        "/hw_driver/get_available_transitions": ["lifecycle_msgs/srv/GetAvailableTransitions"],
        "/hw_driver/get_transition_graph": ["lifecycle_msgs/srv/GetAvailableTransitions"]}, nodes
    assert script.phase == "stop", (script.phase, logs)
    # the board: the deactivate's landing was the driver's LAND request; after the activate the plate left its
    # support under the controller (then the stop's landing)
    assert script.first_landing is not None and script.first_landing["reason"] == "LAND requested", script.first_landing
    assert script.lifted is not None, (_rig_status(workdir), logs)
    assert facts["rig"]["landings"] >= 2, facts["rig"]
    print(f"\n{transport}: deactivate answered in {steps['deactivate']['s']:.1f} s (the landing); the board ran the"
          f" controller's commands {steps['levitating again']['t'] - steps['activate']['t']:.1f} s after the activate;"
          f" the board's last landing: {facts['rig']['reason']}; whole test {time.monotonic() - t0:.0f} s")
