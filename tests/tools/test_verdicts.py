"""One verdict for every run (dem_ros.tools.verdict): the rules, and the failed cases on real runs.

The rules are checked on facts (no process). The failed cases run the real command line (``python -m
dem_ros.tools.cli launch ...``: real node processes over DDS on this test's own domain): a link with no board
behind it, a plate landed mid-run. Each must exit 1 with ``failed`` and its reason, the same in the summary's
first line (or the one error line, when the run never started) and in the JSON. A run cut short (its plant
killed) is tests/tools/test_faults_launch.py; a bag of a run cut short, tests/tools/test_exit_codes.py.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from dem_ros.tools.verdict import DEGRADED, FAILED, OK, RunFacts, judge

ROOT = Path(__file__).resolve().parents[2]


def test_a_complete_run_is_ok_and_exits_0():
    v = judge(RunFacts(planned_samples=3000, samples=3000))
    assert (v.status, v.reasons, v.exit_code) == (OK, (), 0)
    assert v.line() == "verdict  ok"


def test_problems_of_the_record_alone_make_a_degraded_run_exit_3():
    v = judge(RunFacts(planned_samples=3000, samples=3000, problems=["12 plant sample(s) missing from the bag"]))
    assert (v.status, v.exit_code) == (DEGRADED, 3)
    assert v.reasons == ("12 plant sample(s) missing from the bag",)


@pytest.mark.parametrize(("facts", "reason"), [
    (RunFacts(planned_samples=3000, samples=0, reached_t0=False), "never reached t = 0"),
    (RunFacts(planned_samples=3000, samples=1200), "1200 of 3000 planned samples (1.200 of 3 s)"),
    (RunFacts(planned_samples=3000, samples=3000, landing=(0.0, "its link watchdog")),
     "landed before the planned end at t = 0.000 s: its link watchdog"),
    (RunFacts(planned_samples=3000, samples=3000, failure=(1.5, "rail contact")),
     "failed at t = 1.500 s: rail contact"),
    (RunFacts(planned_samples=3000, samples=3000, board_ran=False), "the board never reached RUN"),
    (RunFacts(planned_samples=3000, samples=0, reached_t0=False, not_started="no board answered at udp://x:1"),
     "no board answered at udp://x:1"),
    (RunFacts(planned_samples=3000, samples=3000, cut_short="node estimator exited early"),
     "cut short: node estimator exited early"),
])
def test_each_failed_case_is_failed_with_its_reason_and_exits_1(facts, reason):
    v = judge(facts)
    assert v.status == FAILED and v.exit_code == 1
    assert any(r.startswith(reason) for r in v.reasons), v.reasons
    assert v.to_dict() == {"verdict": "failed", "verdict_reasons": list(v.reasons)}


def test_a_failed_run_keeps_the_problems_of_its_record_among_its_reasons():
    v = judge(RunFacts(planned_samples=10, samples=5, problems=["bag truncated"]))
    assert v.status == FAILED and v.reasons[-1] == "bag truncated"


def test_the_earliest_failure_or_landing_bounds_the_figures():
    f = RunFacts(failure=(2.0, "x"), landing=(0.5, "y"))
    assert f.cut_time() == 0.5
    assert RunFacts(failure=(None, "x")).cut_time() is None


def _launch(tmp_path: Path, domain: int, *args: str, timeout: float = 600) -> tuple[subprocess.CompletedProcess, dict]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    js = tmp_path / "run.json"
    r = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "launch", "--domain-id", str(domain),
                        "--transport", "dds", "--bag-dir", str(tmp_path / "bags"), "--json", str(js), *args],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=timeout)
    return r, (json.loads(js.read_text()) if js.exists() else {})


def test_no_board_behind_the_link_is_one_failed_line_exit_1_and_no_bag(tmp_path, domain_id):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a port nothing listens on (it is closed below)
        s.bind(("127.0.0.1", 0))
        url = f"udp://127.0.0.1:{s.getsockname()[1]}"
    r, d = _launch(tmp_path, domain_id, "--hardware", url, "--duration", "5")
    assert r.returncode == 1, r.stderr[-3000:]
    said = [ln for ln in r.stderr.splitlines() if ln.startswith("dem-ros launch: failed")]
    assert len(said) == 1 and f"no board answered at {url}" in said[0] and "check that" in said[0], r.stderr[-3000:]
    assert d["verdict"] == "failed" and f"no board answered at {url}" in d["verdict_reasons"][0]
    assert "Traceback" not in r.stderr
    bags = [p for p in (tmp_path / "bags").iterdir() if not p.name.endswith("_logs")]
    assert bags == []  # the node logs stay (the error's evidence), no bag


def test_a_plate_landed_mid_run_is_failed_with_when_and_why_exit_1(tmp_path, domain_id):
    """Lockstep (deterministic): a 40 kg load ramped in at t = 1 s pulls the plate off its support side beyond
    trip_gap_max; the simulated board trips and lands it; the run ends there, 2 s before its plan."""
    r, d = _launch(tmp_path, domain_id, "--duration", "3", "--set", "plant_sim.mass_delta=40",
                   "--set", "plant_sim.mass_ramp_start=1", "--set", "plant_sim.mass_ramp_end=1.2")
    assert r.returncode == 1, r.stderr[-3000:]
    first = r.stdout.splitlines()[0].split(None, 1)
    assert first[0] == "verdict" and first[1].startswith("failed: landed before the planned end at t = 1."), r.stdout
    assert "trip_gap_max" in first[1] and "of 3000 planned samples" in first[1]
    assert d["verdict"] == "failed" and d["verdict_reasons"][0].startswith("landed before the planned end at t = 1.")
    assert d["metrics_until_s"] is not None and 1.0 < d["metrics_until_s"] < 1.5  # figures before the landing only
    assert f"dem-ros launch: {first[1]}" in r.stderr


def test_a_composed_run_with_the_controller_apart_runs_it_in_its_own_process(tmp_path, domain_id):
    """``--compose --apart controller`` (what the rig's kill-controller row runs): the container holds the other
    nodes, the controller has a process (and log) of its own; lockstep, so the run is the offline one."""
    r, d = _launch(tmp_path, domain_id, "--duration", "2", "--compose", "--apart", "controller")
    assert r.returncode == 0 and d["verdict"] == "ok", (d.get("verdict_reasons"), r.stderr[-3000:])
    assert d["composed"] and d["apart"] == ["controller"]
    assert "composed, controller in a process of its own" in r.stdout
    logs = Path(d["bag"] + "_logs")
    controller, container = (logs / "controller.log").read_text(), (logs / "container.log").read_text()
    assert "[controller]: ready" in controller and "[controller]" not in container
    assert "[estimator]: ready" in container and "[plant_sim]" in container
