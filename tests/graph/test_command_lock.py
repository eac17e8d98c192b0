"""The command source lock with real processes over real DDS on loopback (issue #12 item 3).

* A rogue process publishes 1e6 V on /dem/command for every measurement of the run, stamped as that
  measurement (the worst case: it can arrive before the controller's command for the same sample). The plant applies
  only the controller's commands: the plate tracks S1 as without the rogue (truth from the bag, read back with rosbags),
  and the plant reports the rogue (commands_foreign, WARN on /diagnostics, one log line).
* A free-running plant_sim does not start its run before the controller's /dem/command writer is on the
  graph (last session a per-process free run landed because the plant started first).

What the lock cannot do (no DDS-Security in the PyPI cyclonedds wheel): stop a process that forges the
controller's GID or names itself "controller"; see docs/manual/topics.md.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from dem_ros import contract
from dem_ros.core.scenarios import get_scenario
from dem_ros.realtime import REPORT_PREFIX
from dem_ros.tools import launcher

ROOT = Path(__file__).resolve().parents[2]

ROGUE = r"""
import sys, time
from dem_ros import contract
from dem_ros.nodes.common import joint_state, stamp_ns
from dem_ros.transport import make_node
n = make_node("rogue", transport="dds", args=[])
pub = n.publisher(contract.COMMAND)
JS = n.msg("sensor_msgs/msg/JointState")
sent = [0]
def on_meas(m):
    if m.header.frame_id == contract.FRAME:
        pub.publish(joint_state(JS, stamp_ns(m), effort=(1e6, 1e6)))  # the sample's own stamp: first in line
        sent[0] += 1
n.subscribe(contract.MEASUREMENT, on_meas)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    n.spin_once(0.05)
print("SENT", sent[0], flush=True)
"""


def _domain(offset: int) -> int:
    return 1 + (os.getpid() * 13 + offset) % 100


def _env(domain: int) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    return env


def _bag(bag: Path) -> dict:
    """Truth gaps (n, 2) [m], applied voltages (n, 2) [V], commands' first elements, plant loop statuses."""
    from rosbags.highlevel import AnyReader

    out: dict = {"gaps": [], "applied": [], "commands": [], "diags": []}
    with AnyReader([bag]) as reader:
        for conn, _t, raw in reader.messages(connections=reader.connections):
            if conn.topic not in (contract.TRUTH.name, contract.APPLIED.name, contract.COMMAND.name,
                                  contract.DIAGNOSTICS.name):
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == contract.TRUTH.name:
                out["gaps"].append(msg.position[:2])
            elif conn.topic == contract.APPLIED.name:
                out["applied"].append(msg.effort[:2])
            elif conn.topic == contract.COMMAND.name:
                out["commands"].append(msg.effort[0])
            else:
                for st in msg.status:
                    if st.name == contract.LOOP_STATUS:
                        level = st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")
                        out["diags"].append((level, st.message, {kv.key: kv.value for kv in st.values}))
    out["gaps"] = np.asarray(out["gaps"], float)
    out["applied"] = np.asarray(out["applied"], float)
    return out


def test_a_rogue_publisher_of_1e6_volts_changes_nothing_and_is_reported(tmp_path):
    from dem_ros.core.warmup import warm_up

    warm_up()  # numba's on-disk cache filled once, for the node processes
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["lockstep"] = True  # the closed loop is the offline one however loaded the machine
    cfg["plant_sim"]["start_delay"] = 6.0
    domain = _domain(1)
    logs, bag = tmp_path / "logs", tmp_path / "run"
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds", "config": cfg}
    out: dict = {}

    def graph():
        try:
            out["facts"] = launcher.run_graph(cfg, duration=3.0, transport="dds", bag=bag, meta=meta,
                                              domain_id=domain, status=False, workdir=logs)
        except Exception as exc:
            out["error"] = exc

    # the rogue from the start: it answers every measurement of the run (t >= 0) before the controller can
    rogue = subprocess.Popen([sys.executable, "-c", ROGUE, "600"], env=_env(domain), cwd=str(ROOT),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t = threading.Thread(target=graph)
    t.start()
    try:
        t.join(timeout=600)
        assert not t.is_alive(), "the graph did not finish"
    finally:
        rogue.kill()
        rogue.communicate(timeout=10)
    assert "error" not in out, out.get("error")
    r = _bag(bag)
    plant_log = (logs / "plant_sim.log").read_text(errors="replace")
    rogue_cmds = sum(1 for u in r["commands"] if u == 1e6)
    assert rogue_cmds >= 10, f"the rogue's commands did not reach the graph ({rogue_cmds} in the bag)"
    # nothing the rogue sent was applied: the board would clip 1e6 V to u_max = 200 V
    assert r["applied"].max() < 150.0, r["applied"].max()
    assert r["gaps"].min() > 0.0045 and r["gaps"].max() < 0.0085, (r["gaps"].min(), r["gaps"].max())
    _level, message, last = r["diags"][-1]
    foreign = int(last["commands_foreign"])
    assert message.startswith("finished") and last["failed"] == "False" and last["landing"] == "False", last
    assert foreign >= rogue_cmds // 2, (foreign, rogue_cmds)  # what the plant saw (the bag: what the recorder saw)
    warned = [d for d in r["diags"] if d[0] >= 1 and "commands_foreign +" in d[1]]
    assert warned, [d[:2] for d in r["diags"]]
    assert (plant_log.count("/dem/command from writer") == 1
            and "refused: not the bound writer of 'controller'" in plant_log)
    # the run's verdict says so: degraded (exit 3), naming the node that refused and the writer's GID
    from dem_ros.tools.runmetrics import load_run

    m, _ = load_run(bag)
    reasons = [x for x in m.verdict_reasons if "refused" in x]
    assert m.verdict == "degraded" and reasons and reasons[0].startswith("plant_sim refused"), (
        m.verdict, m.verdict_reasons)
    print(f"\nrogue: {rogue_cmds} commands of 1e6 V in the bag, {foreign} dropped by the plant; max applied "
          f"{r['applied'].max():.2f} V; gaps {r['gaps'].min() * 1e3:.3f}..{r['gaps'].max() * 1e3:.3f} mm")


PLANT_ALONE = r"""
import sys
from dem_ros.nodes.plant_sim import main
sys.exit(main(["--ros-args", "-p", "lockstep:=false", "-p", "start_delay:=0.0", "-p", "min_subscribers:=0",
               "-p", "preroll:=0.2", "-p", "duration:=0.5"]))
"""

CONTROLLER = r"""
import sys
from dem_ros.nodes.controller import main
sys.exit(main([]))
"""


def test_free_running_plant_waits_for_the_controllers_command_writer(tmp_path, monkeypatch):
    """Without a controller the plant's loop never starts: it says so on /diagnostics report after report; a
    controller started then is bound and the plate levitates."""
    from dem_ros.transport import make_node

    domain = _domain(2)
    env = _env(domain)
    log = tmp_path / "plant.log"
    ctl = None
    with log.open("w") as f:
        plant = subprocess.Popen([sys.executable, "-c", PLANT_ALONE], env=env, cwd=str(ROOT), stdout=f,
                                 stderr=subprocess.STDOUT, text=True)
    try:
        end = time.monotonic() + 120
        # the plant node logs no 'ready': its loop has started when run_node prints its real-time report
        while time.monotonic() < end and REPORT_PREFIX not in log.read_text() and plant.poll() is None:
            time.sleep(0.1)
        assert REPORT_PREFIX in log.read_text(), log.read_text()[-2000:]
        # start_delay 0, no subscriber needed: only the missing controller holds it back. The plant's own word for
        # it: its loop status, WARN "waiting for 'controller''s /dem/command writer", in three reports in a row
        monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
        probe = make_node("probe", transport="dds", args=[])
        waiting: list[str] = []
        probe.subscribe(contract.DIAGNOSTICS, lambda m: waiting.extend(
            st.message for st in m.status if st.name == contract.LOOP_STATUS))
        end = time.monotonic() + 60
        while time.monotonic() < end and len(waiting) < 3 and plant.poll() is None:
            probe.spin_once(0.05)
        probe.shutdown()
        assert len(waiting) >= 3 and all("waiting for 'controller'" in w for w in waiting), waiting
        text = log.read_text()
        assert plant.poll() is None and "levitating at" not in text, text[-2000:]
        ctl = subprocess.Popen([sys.executable, "-c", CONTROLLER], env=env, cwd=str(ROOT),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        end = time.monotonic() + 120
        while time.monotonic() < end and "levitating at" not in log.read_text():
            time.sleep(0.1)
        assert "levitating at" in log.read_text(), log.read_text()[-2000:]
    finally:
        for p in (plant, ctl):
            if p is not None:
                p.kill()
                p.wait(10)
