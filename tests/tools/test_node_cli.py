"""``dem-ros node NAME --transport X`` and integer literals for double parameters, over real DDS.

There is no ROS 2 on this machine: the rclpy half of "``ros2 param set /controller w 60``
succeeds" (a pre-set callback in ``transport/rclpy_node.py`` turning the INTEGER into a
DOUBLE) cannot run here; these tests send exactly what ``ros2 param set`` sends (a
``ParameterValue`` of type INTEGER) to the dds node, and run ``dem-ros param set``.
"""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dem_ros.transport import param_get, rclpy_available
from dem_ros.transport.dds import msgs
from dem_ros.transport.dds.client import call_service

ROOT = Path(__file__).resolve().parents[2]


def _env(domain_id: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""), ROS_DOMAIN_ID=str(domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    return env


def _cli(*argv: str) -> list[str]:
    return [sys.executable, "-m", "dem_ros.tools.cli", *argv]


def _wait_for(proc: subprocess.Popen, word: str, timeout: float) -> str:
    """Read the node's output until a line containing ``word``; fail on exit or timeout."""
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    seen = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sel.select(timeout=0.2):
            line = proc.stdout.readline()
            if not line:
                break
            seen.append(line)
            if word in line:
                return line
    raise AssertionError(f"no {word!r} from the node (rc={proc.poll()}): {''.join(seen)[-2000:]}")


@pytest.fixture
def domain(domain_id) -> int:
    return domain_id


@pytest.mark.skipif(rclpy_available(), reason="needs a machine without rclpy: --transport rclpy must then fail")
def test_transport_after_the_node_name_is_honoured(domain):
    """Before the fix, ``--transport`` after NAME became a ROS argument and was ignored (auto -> dds ran)."""
    proc = subprocess.run(_cli("node", "controller", "--transport", "rclpy"), env=_env(domain), cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "rclpy" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_readme_node_command_and_integer_for_a_double_parameter(domain):
    # the README's command, as typed
    node = subprocess.Popen(_cli("node", "controller", "--transport", "dds", "--ros-args", "--params-file",
                                 "config/dem_ros.yaml"),
                            env=_env(domain), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # warm-up loads numba's cache (or compiles it once): minutes on a cold, loaded 2-core machine
        _wait_for(node, "ready", timeout=600)
        assert param_get("controller", "w", timeout_s=10) == 50.0

        # what `ros2 param set /controller w 60` sends: a ParameterValue of type INTEGER
        value = msgs.ParameterValue(type=2, integer_value=60)
        rep = call_service("controller", "set_parameters",
                           msgs.SetParameters_Request(parameters=[msgs.Parameter(name="w", value=value)]),
                           timeout_s=10)
        assert rep.results[0].successful, rep.results[0].reason
        got = param_get("controller", "w", timeout_s=10)
        assert got == 60.0 and isinstance(got, float)

        # and the same through our own command line
        out = subprocess.run(_cli("param", "set", "controller", "w", "61", "--timeout", "10"), env=_env(domain),
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert "Set parameter successful" in out.stdout
        assert param_get("controller", "w", timeout_s=10) == 61.0
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=20)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
        node.stdout.close()
