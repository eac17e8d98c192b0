"""The board imports no middleware (a port's reference; STYLE 1): checked in a fresh interpreter."""

from __future__ import annotations

import json
import pkgutil
import subprocess
import sys

import dem_ros.board

FORBIDDEN = ("rclpy", "cyclonedds", "rosbags", "mcap", "dem_ros.transport", "dem_ros.nodes", "dem_ros.tools")

PROBE = """
import importlib, json, pkgutil, sys
import dem_ros.board
names = ["dem_ros.board"] + [m.name for m in pkgutil.walk_packages(dem_ros.board.__path__, "dem_ros.board.")]
for n in names:
    importlib.import_module(n)
from dem_ros.board import Supervisor
from dem_ros.core.params import SCHEMA
Supervisor(SCHEMA.defaults("plant_sim"), 1e-3).step(0, (0.008, 0.008), (4.0, 4.0), (80.0, 80.0))
bad = sorted(f for f in sys.argv[1:] if any(m == f or m.startswith(f + ".") for m in sys.modules))
print(json.dumps({"imported": names, "bad": bad}))
"""


def _probe(*forbidden: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", PROBE, *forbidden], capture_output=True, text=True, timeout=600,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_board_imports_no_middleware():
    result = _probe(*FORBIDDEN)
    expected = {m.name for m in pkgutil.walk_packages(dem_ros.board.__path__, "dem_ros.board.")}
    assert {"dem_ros.board.supervisor", "dem_ros.board.modes", "dem_ros.board.rig_io"} <= expected
    assert expected <= set(result["imported"])
    assert result["bad"] == []


def test_probe_detects_an_import():
    """Control: the same probe reports a module that *is* imported (dem_ros.core), so it can fail."""
    assert _probe("dem_ros.core")["bad"] == ["dem_ros.core"]
