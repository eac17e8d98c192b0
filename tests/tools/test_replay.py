"""Offline analysis of recorded runs: the committed sample bag (bags/sample_S1: 8 s of S1 recorded from the graph)
and, for what-if re-runs, a bag this version records."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dem_ros.tools.replay import analyse, what_if

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_S1"


def test_replay_reproduces_the_metrics_recorded_at_run_time():
    recorded = json.loads((SAMPLE / "summary.json").read_text())
    m, _ = analyse(SAMPLE)
    assert m.rms_error_um == pytest.approx(recorded["rms_error_um"], rel=1e-12)
    assert m.max_error_um == pytest.approx(recorded["max_error_um"], rel=1e-12)
    assert m.loop is not None
    assert m.loop.cycles == recorded["loop"]["cycles"]
    assert m.loop.deadline_misses == recorded["loop"]["deadline_misses"]
    assert m.final_estimates == pytest.approx(recorded["final_estimates"], rel=1e-12)
    assert not m.failed and m.error_source == "truth" and m.samples == 8001


@pytest.fixture(scope="module")
def fresh_bag(tmp_path_factory, module_domain_id):
    """3 s of S1 recorded from the composed graph by this version of the code (its controller is the one re-run).

    Composed: the recorder gets every sample in process (no DDS reader between the loop and the bag), so the
    recorded controller inputs are complete and a re-run sees exactly what the node saw.
    """
    out = tmp_path_factory.mktemp("fresh")
    r = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "launch", "--scenario", "S1", "--duration", "3",
                        "--compose", "--bag-dir", str(out), "--domain-id", str(module_domain_id)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    (bag,) = [p for p in out.iterdir() if p.is_dir() and not p.name.endswith("_logs")]
    return bag


def test_what_if_with_the_recorded_law_reproduces_the_recorded_commands(fresh_bag):
    res = what_if(fresh_bag)
    assert res["samples"] >= 3000 and res["parameters_not_recorded"] == []
    assert res["reproduces_recording"], res["max_abs_diff_v"]
    assert res["max_abs_diff_v"] < 1e-9


def test_what_if_with_other_gains_differs_and_still_levitates_commands(fresh_bag):
    res = what_if(fresh_bag, sets=["k1=60", "k2=1300"])
    # other gains give other commands: far above the 1e-9 V to which the recorded law reproduces them (the first
    # seconds of S1 are a quiet hover and the start of a smooth step, so the change is small: millivolts or less)
    assert res["max_abs_diff_v"] > 1e-6, res["max_abs_diff_v"]
    assert max(abs(v) for u in res["u_replayed"] for v in u) < 200.0


def test_what_if_on_a_bag_of_an_earlier_version_names_the_parameters_it_lacked():
    # the sample was recorded before the law's integral action (ki) and coil rows existed: the re-run uses
    # their defaults, so it is not the law that ran, and the result says so
    res = what_if(SAMPLE)
    assert res["samples"] == 9001
    assert {"ki", "coil_weight"} <= set(res["parameters_not_recorded"])


def test_replay_cli_writes_json_and_figures(tmp_path):
    r = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "replay", str(SAMPLE),
                        "--json", str(tmp_path / "m.json"),
                        "--plot", str(tmp_path / "fig")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["samples"] == 8001 and m["scenario"] == "S1"
    assert {p.name for p in (tmp_path / "fig").iterdir()} >= {"tracking.png", "error.png", "inputs.png", "loop.png",
                                                              "estimates.png"}


@pytest.mark.parametrize("make", ["missing", "text", "truncated", "foreign"])
def test_corrupt_or_foreign_input_is_a_clear_error(tmp_path, make):
    if make == "missing":
        path = tmp_path / "nope"
    elif make == "text":
        path = tmp_path / "x.mcap"
        path.write_text("not an mcap file\n")
    elif make == "truncated":
        data = next(SAMPLE.glob("*.mcap")).read_bytes()
        path = tmp_path / "cut.mcap"
        path.write_bytes(data[:300])
    else:  # an MCAP without our topics
        from rosbags.typesys import Stores, get_typestore

        from dem_ros.bag import BagWriter
        from dem_ros.contract import QoS

        ts = get_typestore(Stores.ROS2_JAZZY)
        String = ts.types["std_msgs/msg/String"]
        path = tmp_path / "foreign"
        with BagWriter(path) as w:
            w.add_topic("/chatter", "std_msgs/msg/String", QoS())
            w.write("/chatter", 1, ts.serialize_cdr(String(data="hi"), "std_msgs/msg/String"))
    for cmd in (["replay", str(path)], ["replay", str(path), "--controller", "adaptive"]):
        r = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", *cmd], capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 2, (make, r.stdout, r.stderr)
        assert "Traceback" not in r.stderr and "error:" in r.stderr, r.stderr
