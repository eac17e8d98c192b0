"""Truncated launches, for real: ``dem-ros launch`` as a process, one of its nodes SIGKILLed mid-run.

A run cut short must exit non-zero and say why: a node other than the plant dying ends the run at once
("node ... exited early": failed, cut short); the plant dying leaves a bag with fewer samples than planned
(failed: "N of M planned samples"). The process killed is found by its command line, which names
this test's own params file: nothing else on the machine can match.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _pid_of(node: str, marker: str) -> int | None:
    """The pid of ``dem_ros.tools.node_main <node>`` whose command line contains ``marker``."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        args = [a.decode(errors="replace") for a in cmd]
        if "dem_ros.tools.node_main" in args and node in args and any(marker in a for a in args):
            return int(d.name)
    return None


def _launch_and_kill(tmp_path: Path, node: str, domain_id: int) -> subprocess.CompletedProcess:
    bag_dir = tmp_path / "bags"
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(domain_id))
    p = subprocess.Popen([sys.executable, "-m", "dem_ros.tools.cli", "launch", "--scenario", "S1", "--duration", "8",
                          "--bag-dir", str(bag_dir), "--domain-id", str(domain_id), "--transport", "dds"],
                         cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    killed = False
    while p.poll() is None and time.monotonic() < deadline:
        logs = list(bag_dir.glob("*_logs/plant_sim.log"))
        # the run is under way once the plant reports the experiment's time (its status line)
        if logs and "t =" in logs[0].read_text(errors="replace") and not killed:
            pid = _pid_of(node, str(bag_dir))
            if pid is not None:
                time.sleep(1.0)  # well into the run
                os.kill(pid, signal.SIGKILL)
                killed = True
        time.sleep(0.1)
    out, err = p.communicate(timeout=120)
    assert killed, f"the {node} was never found running; launch stderr:\n{err[-2000:]}"
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def test_a_launch_whose_estimator_dies_is_failed_exit_1_naming_it(tmp_path, domain_id):
    r = _launch_and_kill(tmp_path, "estimator", domain_id)
    assert r.returncode == 1, r.stderr[-2000:]
    assert "node estimator exited early with code -9" in r.stderr, r.stderr[-2000:]
    first = r.stdout.splitlines()[0]
    assert first.split()[:2] == ["verdict", "failed:"] and "cut short: node estimator exited early" in first, r.stdout


def test_a_launch_whose_plant_dies_before_the_duration_is_failed_exit_1_saying_so(tmp_path, domain_id):
    r = _launch_and_kill(tmp_path, "plant_sim", domain_id)
    assert r.returncode == 1, r.stderr[-2000:]
    assert "dem-ros launch: failed:" in r.stderr and "of 8000 planned samples" in r.stderr, r.stderr[-2000:]
    assert r.stdout.splitlines()[0].split()[:2] == ["verdict", "failed:"], r.stdout
