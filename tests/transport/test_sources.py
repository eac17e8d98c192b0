"""Sample sources: the writer GID of each received sample and the GIDs of a named node's writers on a topic
(``Node.subscribe_with_source``, ``Node.publisher_gids``), on the memory transport and on real DDS (other
processes on loopback, and intra-process composition)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from dem_ros import contract
from dem_ros.nodes.common import joint_state
from dem_ros.transport.api import GID_SIZE, gid16, node_fqn
from dem_ros.transport.memory import MemoryBus

ROOT = Path(__file__).resolve().parents[2]


#: the lease the killed talker's participant announces (Cyclone's default: 10 s): a killed process's writers leave
#: the graph when its lease runs out, the path checked below, in 2 s instead of 10
SHORT_LEASE = "<CycloneDDS><Domain><Discovery><LeaseDuration>2s</LeaseDuration></Discovery></Domain></CycloneDDS>"


def child_env(domain_id: int, lease: str | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    if lease is not None:
        env["CYCLONEDDS_URI"] = lease  # after the transport's own configuration (dds/wire.py), as a user's is
    return env

TALKER = r"""
import sys, time
from dem_ros import contract
from dem_ros.nodes.common import joint_state
from dem_ros.transport import make_node
n = make_node(sys.argv[1], transport="dds", args=[])
pub = n.publisher(contract.COMMAND)
JS = n.msg("sensor_msgs/msg/JointState")
print("READY", flush=True)
k = 0
while True:
    k += 1
    pub.publish(joint_state(JS, k, effort=(float(sys.argv[2]), 0.0)))
    n.spin_once(0.01)
"""


def test_names_and_gids_normalise():
    assert node_fqn("controller", "/") == "/controller"
    assert node_fqn("controller", "/rig1") == "/rig1/controller"
    assert node_fqn("/other/controller", "/rig1") == "/other/controller"
    g24 = bytes(range(16)) + b"\0" * 8  # a Humble GID: the GUID zero-padded to 24 bytes
    assert gid16(g24) == gid16(list(range(16))) == bytes(range(16)) and GID_SIZE == 16


def test_memory_sources_name_the_writer_and_leave_with_the_node():
    bus = MemoryBus()
    ctl, rogue, plant = bus.node("controller"), bus.node("rogue"), bus.node("plant_sim")
    got: list[tuple[float, bytes]] = []
    plant.subscribe_with_source(contract.COMMAND, lambda m, gid: got.append((m.effort[0], gid)))
    JS = bus.msg(contract.COMMAND.type)
    p_ctl, p_rogue = ctl.publisher(contract.COMMAND), rogue.publisher(contract.COMMAND)
    p_ctl.publish(joint_state(JS, 1, effort=(1.0, 0.0)))
    p_rogue.publish(joint_state(JS, 2, effort=(2.0, 0.0)))
    bus.publish(contract.COMMAND, joint_state(JS, 3, effort=(3.0, 0.0)))  # from outside the graph: no writer
    bus.spin_once()
    assert got == [(1.0, p_ctl.gid), (2.0, p_rogue.gid), (3.0, b"")]
    assert len(p_ctl.gid) == GID_SIZE and p_ctl.gid != p_rogue.gid
    assert plant.publisher_gids(contract.COMMAND, "controller") == {p_ctl.gid}
    assert plant.publisher_gids(contract.COMMAND, "/rogue") == {p_rogue.gid}
    assert plant.publisher_gids(contract.MEASUREMENT, "controller") == frozenset()
    ctl.shutdown()
    assert plant.publisher_gids(contract.COMMAND, "controller") == frozenset()


def _wait(pred, timeout, spin):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        spin()
        v = pred()
        if v:
            return v
    return pred()


def test_dds_sources_of_other_processes(domain_id, wait_line):
    from dem_ros.transport.dds.node import DdsNode

    procs = [subprocess.Popen([sys.executable, "-c", TALKER, name, volts], env=child_env(domain_id, lease),
                              cwd=str(ROOT), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name, volts, lease in (("controller", "1.0", SHORT_LEASE), ("rogue", "1e6", None))]
    node = DdsNode("plant_sim", [])
    try:
        for p in procs:
            wait_line(p, "READY", 60)
        got: dict[float, set[bytes]] = {}
        node.subscribe_with_source(contract.COMMAND, lambda m, gid: got.setdefault(m.effort[0], set()).add(gid))
        ctl = _wait(lambda: node.publisher_gids(contract.COMMAND, "controller"), 30, lambda: node.spin_once(0.05))
        rogue = _wait(lambda: node.publisher_gids(contract.COMMAND, "/rogue"), 30, lambda: node.spin_once(0.05))
        assert len(ctl) == 1 and len(rogue) == 1 and ctl != rogue, (ctl, rogue)
        _wait(lambda: len(got) == 2, 30, lambda: node.spin_once(0.05))
        assert got == {1.0: set(ctl), 1e6: set(rogue)}, got  # every sample names its own writer
        assert node.publisher_gids(contract.COMMAND, "nobody") == frozenset()
        assert node.publisher_gids(contract.MEASUREMENT, "controller") == frozenset()  # writers of that topic only
        procs[0].kill()
        procs[0].wait(10)
        gone = _wait(lambda: not node.publisher_gids(contract.COMMAND, "controller"), 30, lambda: node.spin_once(0.05))
        assert gone, "a dead controller's writer is still listed"
    finally:
        node.shutdown()
        for p in procs:
            p.kill()
            p.wait(10)
            p.stdout.close()
            p.stderr.close()


def test_dds_sources_within_a_composed_process(domain_id):
    from dem_ros.transport.dds.executor import DdsExecutor
    from dem_ros.transport.dds.node import DdsNode, Participant

    ex = DdsExecutor(Participant.get(), intra_process=True)
    ctl, plant = (DdsNode(n, [], executor=ex, ignore_undeclared=True) for n in ("controller", "plant_sim"))
    try:
        got = []
        plant.subscribe_with_source(contract.COMMAND, lambda m, gid: got.append((m.effort[0], gid)))
        pub = ctl.publisher(contract.COMMAND)
        pub.publish(joint_state(ctl.msg(contract.COMMAND.type), 1, effort=(5.0, 0.0)))
        ex.spin_once(0.0)
        assert got == [(5.0, pub.gid)] and len(pub.gid) == GID_SIZE
        mine = _wait(lambda: plant.publisher_gids(contract.COMMAND, "controller"), 10, lambda: ex.spin_once(0.05))
        assert mine == {pub.gid}
    finally:
        ex.shutdown()
