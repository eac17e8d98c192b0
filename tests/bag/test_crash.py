"""Crash safety: SIGKILL leaves a readable prefix; SIGINT finalizes the bag."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from rosbags.rosbag2 import Reader

from dem_ros.bag import BagReader, check

CHILD = Path(__file__).with_name("_child.py")
ROOT = Path(__file__).resolve().parents[2]


def _start(mode: str, bag: Path) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, str(CHILD), mode, str(bag)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=env)
    assert p.stdout is not None
    line = p.stdout.readline()
    assert line.strip() in {"written", "recording"}, p.stderr.read() if p.stderr else ""
    return p


def test_sigkill_leaves_bag_readable_to_last_chunk(tmp_path: Path) -> None:
    """A killed writer: reader gets a contiguous prefix of whole chunks, check says 'truncated'."""
    bag = tmp_path / "killed"
    p = _start("kill", bag)
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=10)
    assert p.returncode == -signal.SIGKILL
    with BagReader(bag) as r:
        assert r.truncated is not None
        n_chunks = len(r.chunks)
        assert n_chunks >= 2
        a = r.joint_state_arrays("/dem/measurement")
        n = len(a["stamp_ns"])
        assert n >= 1000  # >= 2000 written, most in complete chunks
        assert r.topics["/dem/measurement"].count == n
        np.testing.assert_array_equal(a["stamp_ns"], np.arange(n) * 10**6)  # no hole, starts at 0
        np.testing.assert_allclose(a["position"][:, 0], np.arange(n) * 1e-3)
        assert a["log_time_ns"][-1] == r.chunks[-1].end_ns
        assert r.run_metadata() == {"scenario": "crash"}
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["custom_data"]["dem_ros.status"] == "recording"  # provisional file is there
    rep = check(bag)
    assert not rep.ok and not rep.complete
    assert rep.truncation is not None
    assert f"truncated after chunk {n_chunks} at t=" in rep.truncation
    assert f"{n} messages recoverable" in rep.truncation
    assert "TRUNCATED" in rep.format()


def test_sigint_finalizes_complete_bag(tmp_path: Path) -> None:
    """SIGINT to a recording process: exit 130, bag complete, counters match the bag."""
    bag = tmp_path / "interrupted"
    p = _start("sigint", bag)
    p.send_signal(signal.SIGINT)
    _out, err = p.communicate(timeout=20)
    assert p.returncode == 128 + signal.SIGINT, err
    assert "Traceback" not in err
    rep = check(bag)
    assert rep.ok, rep.format()
    assert rep.complete and rep.metadata_yaml == "complete"
    with Reader(bag) as r:
        n = {c.topic: c.msgcount for c in r.connections}["/dem/measurement"]
        assert n >= 300
        assert sum(1 for _ in r.messages()) == r.message_count
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counters = json.loads(meta["custom_data"]["dem_ros.recorder_counters"])
    assert counters["/dem/measurement"]["written"] == n
    assert counters["/dem/measurement"]["dropped"] == 0
