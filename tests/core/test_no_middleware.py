"""The numerical core imports no middleware (STYLE 1): checked in a fresh interpreter."""

from __future__ import annotations

import json
import pkgutil
import subprocess
import sys

import dem_ros.core

FORBIDDEN = ("rclpy", "cyclonedds", "rosbags", "mcap")

PROBE = """
import importlib, json, pkgutil, sys
import dem_ros.core
names = ["dem_ros.core"] + [m.name for m in pkgutil.walk_packages(dem_ros.core.__path__, "dem_ros.core.")]
for n in names:
    importlib.import_module(n)
# exercise the code paths a simulation takes, too (lazy imports inside functions)
from dem_ros.core.scenarios import load_scenarios
from dem_ros.core.simulate import simulate
simulate(load_scenarios()["S1"].config(), duration=0.01)
bad = sorted({m.split(".")[0] for m in sys.modules} & set(sys.argv[1:]))
print(json.dumps({"imported": names, "bad": bad}))
"""


def _probe(*forbidden: str) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, *forbidden], capture_output=True, text=True, timeout=600, check=False
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_core_imports_no_middleware():
    result = _probe(*FORBIDDEN)
    expected = {m.name for m in pkgutil.walk_packages(dem_ros.core.__path__, "dem_ros.core.")}
    assert expected <= set(result["imported"])
    assert {"dem_ros.core.model", "dem_ros.core.simulate", "dem_ros.core.controllers.kernels"} <= expected
    assert result["bad"] == []


def test_probe_detects_an_import():
    """Control: the same probe reports a module that *is* imported (json), so it can fail."""
    assert _probe("json")["bad"] == ["json"]
