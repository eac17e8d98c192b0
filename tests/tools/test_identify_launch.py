"""``dem-ros identify`` on a real rig run: ``dem-ros launch --hardware rig`` (the emulator as its own process
behind UDP, hw_driver, the graph's nodes, the recorder) on a plant none of the defaults describe, with the
excitation reference of the bring-up guide; the bag it recorded is identified by the command.

Identification uses what the board applied (``/dem/applied_voltage``), so late or held commands on a loaded
machine do not bias it. The graph runs composed beside the driver (the rig's configuration); a run that
lost the plate fails this test with the launch's own verdict line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from dem_ros.core.identify import PARAMS
from dem_ros.tools.identify import EXCITATION, TOLERANCE

ROOT = Path(__file__).resolve().parents[2]
TRUTH = {"R1": 17.6, "R2": 23.3, "K": 4.374e-4 * 1.13, "m": 14.852 * 0.88}


def test_identify_a_recorded_rig_run_of_the_whole_graph(tmp_path, domain_id):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(domain_id))
    sets = [f"plant_sim.{k}={v}" for k, v in TRUTH.items()] + [f"plant_sim.R={TRUTH['R1']}",
                                                                "controller.command_delay=2"]
    sets += [f"{g}.{k}={v}" for g, vals in EXCITATION.items() for k, v in vals.items()]
    p = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "launch", "--hardware", "rig", "--compose",
                        "--scenario", "S1", "--duration", "14", "--transport", "dds",
                        "--bag-dir", str(tmp_path / "bags"),
                        *[a for s in sets for a in ("--set", s)], "--json", str(tmp_path / "run.json")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode in (0, 1, 3), p.stderr[-3000:]
    s = json.loads((tmp_path / "run.json").read_text())
    assert not s["failed"], p.stdout.strip().splitlines()[-1] if p.stdout.strip() else s
    q = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "identify", s["bag"], "--json",
                        str(tmp_path / "id.json")], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    print(q.stdout)
    assert q.returncode == 0, q.stdout + q.stderr
    res = json.loads((tmp_path / "id.json").read_text())
    for k in PARAMS:
        e = res["estimates"][k]
        assert abs(e["value"] / TRUTH[k] - 1) <= TOLERANCE[k], (k, e, TRUTH[k])
        assert e["ci95"][0] <= TRUTH[k] <= e["ci95"][1], (k, e, TRUTH[k])
