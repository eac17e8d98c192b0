"""The ``hw_driver`` node as a real process on real DDS (loopback), in front of ``dem-ros rig`` over UDP:
plant_sim's topic contract, the lifecycle over ``dem-ros hw`` requests, the e-stop latched and reported
on ``/dem/hw/state`` and on ``/diagnostics`` (a latched ERROR, published at once, cleared by a re-arm).

No controller runs: the driver stays inactive or armed and the emulated plate stays clamped at its
hover, so nothing here depends on the machine keeping 1 kHz.
"""

from __future__ import annotations

import itertools
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dem_ros import contract
from dem_ros.core.params import default_config
from dem_ros.tools.hw import request
from dem_ros.tools.launcher import write_params_file
from dem_ros.transport import make_node

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def graph(tmp_path, monkeypatch, domain_id):
    monkeypatch.setenv("DEM_ROS_RT", "0")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        url = f"udp://127.0.0.1:{s.getsockname()[1]}"
    cfg = default_config()
    cfg["hw_driver"]["url"] = cfg["rig"]["url"] = url
    cfg["hw_driver"]["link_timeout"] = 2.0  # an unloaded link thread on a loaded machine
    params = write_params_file(cfg, tmp_path / "params.yaml")
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    procs = []
    for name, cmd in (("rig", ["-m", "dem_ros.hardware.rig", "--params", str(params)]),
                      ("hw_driver", ["-m", "dem_ros.tools.node_main", "hw_driver", "--transport", "dds",
                                     "--ros-args", "--params-file", str(params)])):
        log = tmp_path / f"{name}.log"
        with open(log, "w") as out:
            procs.append((subprocess.Popen([sys.executable, *cmd], cwd=ROOT, env=env, stdout=out,
                                           stderr=subprocess.STDOUT), log))
    yield cfg, procs
    for p, _ in procs:
        if p.poll() is None:
            p.terminate()
    for p, _ in procs:
        p.wait(timeout=20)


def _level(st) -> int:
    return st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")


def _spin_until(node, done, procs, seen, timeout_s: float = 30.0) -> None:
    """Spin ``node`` until ``done()`` (bounded: the driver reports at 1 Hz, faults at once)."""
    end = time.monotonic() + timeout_s
    while not done() and time.monotonic() < end:
        node.spin_once(0.1)
        for p, log in procs:
            assert p.poll() is None, log.read_text()
    assert done(), f"not seen within {timeout_s:g} s; seen: {seen[-10:]}"


def test_the_driver_honours_plant_sims_contract_and_its_lifecycle_answers_requests(graph):
    cfg, procs = graph
    node = make_node("hw_test", transport="dds", args=[])
    meas, applied = [], []
    node.subscribe(contract.MEASUREMENT, meas.append)
    node.subscribe(contract.APPLIED, applied.append)
    try:
        end = time.monotonic() + 120
        while len(meas) < 50 and time.monotonic() < end:
            node.spin_once(0.1)
            for p, log in procs:
                assert p.poll() is None, log.read_text()
        assert len(meas) >= 50, [log.read_text()[-2000:] for _, log in procs]
        m = meas[-1]
        gap0 = cfg["plant_sim"]["gap0"]
        assert m.header.frame_id == contract.FRAME_PREROLL  # no t = 0 before the driver is active
        assert list(m.name) == list(contract.MAGNETS)
        assert m.position[0] == pytest.approx(gap0, abs=1e-6) and m.position[1] == pytest.approx(gap0, abs=1e-6)
        assert len(m.velocity) == 0  # a rig measures no gap rates
        assert m.effort[0] == pytest.approx(4.0, abs=0.1)  # the hover current at 8 mm
        stamps = [x.header.stamp.sec * 10**9 + x.header.stamp.nanosec for x in meas]
        assert all(b > a for a, b in itertools.pairwise(stamps))
        assert any(a.effort[0] == pytest.approx(80.0, abs=0.5) for a in applied)  # the clamp's hover voltage
    finally:
        node.shutdown()
    # /dem/hw/state is published at 10 Hz and latched: the newest one may predate the samples this
    # test saw; wait (bounded) for one that counts them
    v = request("status", timeout_s=60)
    end = time.monotonic() + 30
    while int(v["samples"]) == 0 and time.monotonic() < end:
        time.sleep(0.2)
        v = request("status", timeout_s=60)
    assert v["state"] == "inactive" and v["board_mode"] == "off"
    assert int(v["corrupt"]) == 0 and int(v["samples"]) > 0, v
    v = request("arm", timeout_s=60)
    assert v["state"] == "armed"
    probe = make_node("hw_diag_probe", transport="dds", args=[])
    seen: list[tuple[int, str]] = []
    probe.subscribe(contract.DIAGNOSTICS, lambda m: seen.extend(
        (_level(st), st.message) for st in m.status if st.name == contract.HW_LOOP_STATUS))
    try:
        _spin_until(probe, lambda: bool(seen), procs, seen)  # the 1 Hz report: the probe is matched
        v = request("estop", "test e-stop", timeout_s=60)
        assert v["state"] == "fault" and v["reason"] == "e-stop: test e-stop" and v["level"] == "2"
        # at once, the reason first (counters that grew since the last report may follow it)
        _spin_until(probe, lambda: any(lv == 2 and m.startswith("e-stop: test e-stop") for lv, m in seen), procs, seen)
        v = request("arm", timeout_s=60)  # arming clears the latched fault
        assert v["state"] == "armed" and v["reason"] == ""
        n = len(seen)
        _spin_until(probe, lambda: any(lv < 2 for lv, _ in seen[n:]), procs, seen)
    finally:
        probe.shutdown()
    v = request("disarm", timeout_s=60)
    assert v["state"] == "inactive"
    rig_log = procs[0][1]
    assert json.loads(rig_log.read_text().splitlines()[0][4:])["event"] == "listening"
