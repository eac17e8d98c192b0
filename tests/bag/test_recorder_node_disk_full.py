"""The recorder node on a full disk (a real 192 KiB tmpfs): it reports at once on /diagnostics (ERROR) and in its
log, stays up, and on SIGINT exits 0 with its counters and a finalised bag (no traceback)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import domains

from dem_ros.bag import check

ROOT = Path(__file__).resolve().parents[2]

FEED = r"""
import random, sys, time
from dem_ros import contract
from dem_ros.transport import make_node
from dem_ros.nodes.common import joint_state
n = make_node("feeder", transport="dds", args=[])
pub = n.publisher(contract.MEASUREMENT)
JS = n.msg("sensor_msgs/msg/JointState")
seen = []
n.subscribe(contract.DIAGNOSTICS,
            lambda m: seen.extend(s for s in m.status if s.name == contract.RECORDER_STATUS and s.level == 2))
end = time.monotonic() + 10
while time.monotonic() < end and pub.subscription_count < 1:
    n.spin_once(0.05)
rng = random.Random(5)
end = time.monotonic() + float(sys.argv[1])
k = 0
while time.monotonic() < end and not seen:
    for _ in range(20):  # random floats: the bag does not compress, the disk fills in a few seconds
        pub.publish(joint_state(JS, time.time_ns(), position=(rng.random(), rng.random()),
                                velocity=(rng.random(), rng.random()), effort=(rng.random(), rng.random())))
        k += 1
    n.spin_once(0.005)
print("SENT", k, flush=True)
print("DIAG", seen[0].message if seen else "none", flush=True)
n.shutdown()
"""


def test_recorder_node_reports_a_full_disk_and_exits_cleanly(small_disk: Path):
    domain = domains.hold()  # a domain no other test or run uses, for the rest of this process
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    bag = small_disk / "bag"
    rec = subprocess.Popen([sys.executable, "-m", "dem_ros.tools.node_main", "recorder", "--transport", "dds",
                            "--bag", str(bag)], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and not (bag / "metadata.yaml").exists():
            time.sleep(0.05)
        feed = subprocess.run([sys.executable, "-c", FEED, "120"], env=env, capture_output=True, text=True,
                              timeout=300)
        assert feed.returncode == 0, feed.stderr
        diag = feed.stdout.splitlines()[-1]
        assert diag.startswith("DIAG recording stopped:") and "No space left on device" in diag, feed.stdout
        assert rec.poll() is None  # still up after the failure
        rec.send_signal(signal.SIGINT)
        out = rec.communicate(timeout=60)[0]
    finally:
        if rec.poll() is None:
            rec.kill()
            rec.communicate()
    assert rec.returncode == 0, out
    assert "Traceback" not in out
    assert "recording stopped" in out and "RECORDER_FAILED" in out and "RECORDER {" in out
    rep = check(bag)
    assert rep.complete, rep.format()
    assert any("No space left on device" in p for p in rep.problems), rep.format()
