"""``dem-ros faults`` for real: a small subset of the catalogue against the real graph (processes over DDS)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from dem_ros.tools.faults import CATALOGUE

ROOT = Path(__file__).resolve().parents[2]


def _faults(tmp_path: Path, domain_id: int, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "faults", "--domain-id", str(domain_id),
                           "--bag-dir", str(tmp_path / "bags"), *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=900)


def test_an_unknown_row_is_a_usage_error(tmp_path, domain_id):
    r = _faults(tmp_path, domain_id, "--only", "no-such-fault")
    assert r.returncode == 2 and "unknown row(s) no-such-fault" in r.stderr and "Traceback" not in r.stderr


def test_the_catalogue_covers_the_issue():
    names = {f.name for f in CATALOGUE}
    assert {"rogue-command", "empty-position", "non-utf8-frame", "bad-cdr", "reference-step", "spike-10mm",
            "spike-50mm", "stale-stamps", "kill-controller", "kill-estimator", "kill-reference",
            "kill-recorder", "future-applied", "disk-full"} <= names


def test_the_plants_last_word_and_a_restart_outage_are_read_from_the_node_logs(tmp_path):
    from dem_ros.tools.faults import _outage_s, _plant_end

    plant = tmp_path / "plant_sim.log"
    plant.write_text("[INFO] [100.0] [plant_sim]: levitating at 8.000 mm\nt =     1.0 s  gaps\n"
                     "[WARN] [104.5] [plant_sim]: landed safely at t = 2.1 s\n")
    est = tmp_path / "estimator.log"
    est.write_text("[INFO] [90.0] [estimator]: ready\n[INFO] [106.25] [estimator]: ready\n")
    logs = {"plant_sim": str(plant), "estimator": str(est)}
    assert _plant_end(logs) == "landed safely at t = 2.1 s"
    assert _outage_s(logs, "estimator", 102_000_000_000) == 4.25  # SIGKILL at 102 s, 'ready' again at 106.25 s
    assert _outage_s(logs, "estimator", None) is None and _plant_end({}) == ""


def test_a_reference_step_and_stale_stamps_leave_the_plate_levitating_and_are_reported(tmp_path, domain_id):
    out = tmp_path / "faults.json"
    r = _faults(tmp_path, domain_id, "--only", "reference-step", "--only", "stale-stamps", "--processes", "per-process",
                "--duration", "3", "--json", str(out))
    assert r.returncode == 0, r.stdout + r.stderr[-3000:]
    rows = {row["fault"]: row for row in json.loads(out.read_text())["rows"]}
    step, stale = rows["reference-step"], rows["stale-stamps"]
    for row in (step, stale):
        assert row["passed"] and row["outcome"] == "levitating" and row["min_gap_mm"] > 5.0
        assert "controller WARN" in row["reported"]  # the controller's checks refused them, on /diagnostics
    assert step["data_lost"] == "none"
    assert "| reference-step | per process | levitating" in r.stdout  # the table
