"""``dem-ros rig`` as a real process behind a real link (UDP on loopback, a pty pair), the PC side driven
by :class:`HwDriver` and the graph's own estimator and controller (in this process).

What is asserted does not depend on how loaded the machine is: the handshake, the stream (in order, no
corruption), the board taking the commands (RUN), a latched fault on the PC landing the plate (LAND
from the driver), and the board's summary (never a rail contact). Timing figures come from
``dem-ros launch --hardware rig`` (docs/manual/hardware.md), not from tests.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dem_ros.core.params import default_config
from dem_ros.hardware.channel import open_channel
from dem_ros.hardware.driver import DriverState, HwDriver, Sample
from dem_ros.hardware.link import HELLO_REQUEST, Mode, encode

sys.path.insert(0, str(Path(__file__).parent))
from test_rig import Loop

ROOT = Path(__file__).resolve().parents[2]
#: samples between a measurement and the period its command is applied (board, driver and controller
#: agree): 8 ms of budget, so this test's unprioritised Python loop keeps up on a loaded machine
DELAY = 8


def free_udp_url() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"udp://127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture(params=["udp", "pty"])
def rig(request, tmp_path):
    url = free_udp_url() if request.param == "udp" else "pty://"
    log = tmp_path / "rig.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "dem_ros.hardware.rig", "--url", url, "--duration", "60",
                                 "--fault", "corrupt@0.0+5:0.05", "--set", f"hw_driver.command_delay={DELAY}"],
                                cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
                                env={"PYTHONPATH": str(ROOT), "DEM_ROS_RT": "0", "PATH": "/usr/bin:/bin",
                                     "NUMBA_CACHE_DIR": os.environ["NUMBA_CACHE_DIR"]})
    peer = None
    end = time.monotonic() + 60
    while peer is None and time.monotonic() < end and proc.poll() is None:
        for line in log.read_text().splitlines():
            if line.startswith("RIG ") and '"listening"' in line:
                peer = json.loads(line[4:])["url"]
        time.sleep(0.05)
    assert peer is not None, log.read_text()
    yield peer, proc, log
    if proc.poll() is None:
        proc.terminate()
    proc.wait(timeout=20)


def _hover_sample(cfg) -> Sample:
    g = cfg["plant_sim"]["gap0"]
    return Sample(0, 0, np.array([g, g]), np.array([4.0, 4.0]), np.array([80.0, 80.0]), 200.0, Mode.OFF, 0, 0)


def summary(log: Path) -> dict:
    for line in reversed(log.read_text().splitlines()):
        if line.startswith("RIG ") and '"summary"' in line:
            return json.loads(line[4:])
    raise AssertionError(log.read_text())


def test_a_pc_drives_the_emulated_board_over_a_real_link_and_a_fault_lands_the_plate(rig):
    url, proc, log = rig
    cfg = default_config()
    cfg["plant_sim"]["measure_velocity"] = False
    cfg["controller"]["command_delay"] = DELAY
    cfg["controller"]["max_age"] = (DELAY + 1) * 1e-3  # an on-time estimate is up to DELAY samples old
    drv = HwDriver(cfg["hw_driver"] | {"clock_sync_frames": 20, "link_timeout": 5.0, "command_timeout": 5.0,
                                       "command_delay": DELAY, "arm_samples": 5})
    law = Loop(cfg)
    Loop(cfg)(_hover_sample(cfg))  # compile the kernels before the clock matters
    ch = open_channel(url, "pc")
    seqs, modes, stamps = [], [], []
    try:
        ch.send(encode(HELLO_REQUEST))
        t_end = time.monotonic() + 30
        while drv.hello is None and time.monotonic() < t_end:
            data = ch.recv(0.5)
            if data is None:
                ch.send(encode(HELLO_REQUEST))
                continue
            drv.on_bytes(data, time.time_ns(), time.monotonic_ns())
        assert drv.hello is not None and drv.hello.rate_hz == 1000
        drv.arm()
        estop_at = None
        while time.monotonic() < t_end:
            newest = None
            data = ch.recv(0.2)
            while data is not None:  # every frame goes through the driver; the law answers the newest
                s, reply = drv.on_bytes(data, time.time_ns(), time.monotonic_ns())
                if reply is not None:
                    ch.send(reply)
                if s is not None:
                    seqs.append(s.seq)
                    modes.append(s.mode)
                    stamps.append(s.stamp_ns)
                    newest = s
                data = ch.recv(0.0)
            if newest is None:
                continue
            cmd = drv.command(newest.stamp_ns, law(newest), time.monotonic_ns())
            if cmd is not None:
                ch.send(cmd)
            flying = len(modes) - modes.count(Mode.OFF)  # samples since the board took a command (OFF -> RUN)
            if estop_at is None and (flying >= 100 or (flying and newest.mode != Mode.RUN)):
                # (a board whose commands come late holds, then lands by itself: the e-stop comes then)
                estop_at = len(seqs)
                drv.estop("test")  # a latched fault on the PC: LAND every sample from now on
            if newest.mode == Mode.LANDED:
                break
    finally:
        ch.close()
    proc.terminate()
    proc.wait(timeout=20)
    rs = summary(log)
    assert np.all(np.diff(seqs) > 0) and np.all(np.diff(stamps) > 0)  # in order, duplicates dropped
    assert estop_at is not None, (drv.status(), rs)  # the board took the PC's commands (it left OFF)
    assert drv.state == DriverState.FAULT and drv.reason == "e-stop: test"
    assert modes[-1] == Mode.LANDED  # landed by the board's law after the driver's LAND
    assert rs["failed"] == ""  # never a rail contact
    assert drv.counters["corrupt"] == drv.corrupt_reasons.get("crc", 0) >= 1  # the injected corruption, counted
    assert drv.counters["corrupt"] <= rs["corrupted_tx"]
