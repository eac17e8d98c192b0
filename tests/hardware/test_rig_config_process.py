"""The board's configuration over a real link: ``dem-ros rig`` as a process on loopback UDP, built with other values
than the PC's (its u_max, hold_timeout and command delay), the PC side driven by :class:`HwDriver` and the graph's
estimator and controller in this process; with the Python board and with the firmware's supervisor (rig.board=c).

1. A PC whose configuration the board refuses (no braking away from the rail at an end): the driver faults with the
   board's reason before arming, arming again does not help, the board keeps its defaults and never leaves OFF.
2. A second PC with the launch's values: the board takes them (its answer's CRC is the PC's, its next hello states
   the new watchdog and command delay), the driver arms, the board flies the controller's commands, an e-stop on the
   PC lands the plate.

What is asserted does not depend on how loaded the machine is (as tests/hardware/test_rig_process.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dem_ros.core.params import default_config
from dem_ros.hardware.boardcfg import config_crc, config_frame
from dem_ros.hardware.channel import open_channel
from dem_ros.hardware.driver import DriverState, HwDriver
from dem_ros.hardware.link import HELLO_REQUEST, Mode, encode

sys.path.insert(0, str(Path(__file__).parent))
from test_rig import Loop
from test_rig_process import _hover_sample, free_udp_url, summary

ROOT = Path(__file__).resolve().parents[2]
DELAY = 8  # the run's command delay (the board is built with 1): 8 ms of budget for this unprioritised loop


@pytest.fixture(params=["python", "c"])
def rig(request, tmp_path):
    if request.param == "c":
        from dem_ros.hardware.cboard import FirmwareError, library_path

        try:
            library_path()
        except FirmwareError as exc:
            pytest.skip(f"the firmware cannot be built here: {exc}")
    url = free_udp_url()
    log = tmp_path / "rig.log"
    with open(log, "w") as out:  # built with another u_max and hold_timeout than the PC's, and command delay 1
        proc = subprocess.Popen([sys.executable, "-m", "dem_ros.hardware.rig", "--url", url, "--duration", "90",
                                 "--set", "plant_sim.u_max=150", "--set", "plant_sim.hold_timeout=0.04",
                                 "--set", f"rig.board={request.param}"],
                                cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
                                env={"PYTHONPATH": str(ROOT), "DEM_ROS_RT": "0", "PATH": "/usr/bin:/bin",
                                     "NUMBA_CACHE_DIR": os.environ["NUMBA_CACHE_DIR"],
                                     "XDG_CACHE_HOME": os.environ.get("XDG_CACHE_HOME",
                                                                      str(Path.home() / ".cache"))})
    peer = None
    end = time.monotonic() + 60
    while peer is None and time.monotonic() < end and proc.poll() is None:
        for line in log.read_text().splitlines():
            if line.startswith("RIG ") and '"listening"' in line:
                peer = json.loads(line[4:])["url"]
        time.sleep(0.05)
    assert peer is not None, log.read_text()
    yield peer, proc, log, request.param
    if proc.poll() is None:
        proc.terminate()
    proc.wait(timeout=20)


def _pump(ch, drv: HwDriver, until, timeout_s: float):
    """Every frame through the driver and its replies back, until ``until()`` or the timeout; the newest sample."""
    end = time.monotonic() + timeout_s
    newest = None
    while not until() and time.monotonic() < end:
        data = ch.recv(0.1)
        if data is None:
            if drv.hello is None:
                ch.send(encode(HELLO_REQUEST))
            continue
        s, reply = drv.on_bytes(data, time.time_ns(), time.monotonic_ns())
        if reply is not None:
            ch.send(reply)
        newest = s or newest
    return newest


def test_the_pc_configures_the_board_and_refuses_to_arm_one_that_refuses_the_runs_values(rig):
    url, proc, log, kind = rig
    cfg = default_config()
    cfg["plant_sim"]["measure_velocity"] = False
    cfg["controller"]["command_delay"] = DELAY
    cfg["controller"]["max_age"] = (DELAY + 1) * 1e-3
    hw = cfg["hw_driver"] | {"clock_sync_frames": 20, "link_timeout": 5.0, "hold_timeout": 0.5,
                             "command_delay": DELAY, "arm_samples": 5}
    law = Loop(cfg)
    Loop(cfg)(_hover_sample(cfg))  # compile the kernels before the clock matters

    # 1. a PC whose configuration the board refuses: one clear reason, never armed
    bad = HwDriver(hw | {"N1": 500.0})
    ch = open_channel(url, "pc")
    try:
        ch.send(encode(HELLO_REQUEST))
        _pump(ch, bad, lambda: bad.state == DriverState.FAULT, 30)
        assert bad.hello is not None and (bad.hello.command_delay, bad.hello.watchdog_ms) == (1, 40)  # its own
        assert bad.reason.startswith("the board refuses the run's configuration: no_braking"), bad.status()
        assert bad.reason.endswith("it keeps its compiled-in defaults (CRC 0x"
                                   f"{bad.board_config.active_crc:08x})")  # type: ignore[union-attr]
        bad.arm()  # the operator insists: the configuration again, refused again
        _pump(ch, bad, lambda: bad.state == DriverState.FAULT and bad.counters["config_refused"] >= 2, 30)
        assert bad.state == DriverState.FAULT and bad.board_mode == Mode.OFF and not bad.configured
    finally:
        ch.close()

    # 2. the launch's values: taken, confirmed by CRC, the board flies
    drv = HwDriver(hw)
    crc = config_crc(config_frame(hw))
    ch = open_channel(url, "pc")
    seqs, modes = [], []
    try:
        ch.send(encode(HELLO_REQUEST))
        _pump(ch, drv, lambda: drv.configured, 30)
        st = drv.status()
        assert st["board_config"] == "confirmed" and st["board_config_crc"] == f"{crc:08x}", st
        drv.hello = None  # ask again: the board's hello now states the run's watchdog and command delay
        ch.send(encode(HELLO_REQUEST))
        _pump(ch, drv, lambda: drv.hello is not None and drv.configured, 30)
        assert drv.hello is not None and (drv.hello.command_delay, drv.hello.watchdog_ms) == (DELAY, 500)
        drv.arm()
        estop_at = None
        t_end = time.monotonic() + 40
        while time.monotonic() < t_end:
            newest = None
            data = ch.recv(0.2)
            while data is not None:
                s, reply = drv.on_bytes(data, time.time_ns(), time.monotonic_ns())
                if reply is not None:
                    ch.send(reply)
                if s is not None:
                    seqs.append(s.seq)
                    modes.append(s.mode)
                    newest = s
                data = ch.recv(0.0)
            if newest is None:
                continue
            cmd = drv.command(newest.stamp_ns, law(newest), time.monotonic_ns())
            if cmd is not None:
                ch.send(cmd)
            flying = len(modes) - modes.count(Mode.OFF)
            if estop_at is None and (flying >= 100 or (flying and newest.mode != Mode.RUN)):
                estop_at = len(seqs)
                drv.estop("test")
            if newest.mode == Mode.LANDED:
                break
    finally:
        ch.close()
    proc.terminate()
    proc.wait(timeout=20)
    rs = summary(log)
    assert estop_at is not None and Mode.RUN in modes, (drv.status(), rs)  # armed: the board took the commands
    assert modes[-1] == Mode.LANDED and rs["failed"] == ""
    assert rs["board"].startswith(kind) and rs["configured"] and rs["config_crc"] == f"{crc:08x}", rs
    assert rs["configs_refused"] >= 2 and rs["configs"] >= rs["configs_refused"] + 1, rs
