"""Composition: several nodes on one DDS executor, topics between them delivered in memory.

Real DDS (own domain per test); the remote side is another process.
"""

import subprocess
import sys
import time
from dataclasses import replace

import pytest

from dem_ros import contract
from dem_ros.core.params import ConfigError
from dem_ros.nodes.common import joint_state
from dem_ros.transport import _check_composable, serialize
from dem_ros.transport.dds.executor import DdsExecutor
from dem_ros.transport.dds.node import DdsNode, Participant
from dem_ros.transport.rosargs import initial_parameters, parse_ros_args


def _composed(*names):
    ex = DdsExecutor(Participant.get(), intra_process=True)
    return ex, [DdsNode(n, [], executor=ex, ignore_undeclared=True) for n in names]


def _js(node, t):
    return joint_state(node.msg("sensor_msgs/msg/JointState"), t, position=(0.008, 0.007), effort=(1.0, 2.0))


def test_intra_process_delivery_is_fifo_zero_copy_and_skips_dds(domain_id):
    ex, (a, b) = _composed("talker", "listener")
    try:
        got = []
        b.subscribe(contract.MEASUREMENT, lambda m: got.append(("meas", m)))
        b.subscribe(contract.REFERENCE, lambda m: got.append(("ref", m)))
        b.subscribe_raw(contract.MEASUREMENT, lambda d: got.append(("raw", d)))
        pm, pr = a.publisher(contract.MEASUREMENT), a.publisher(contract.REFERENCE)
        assert pm.subscription_count == 2  # the two intra-process subscriptions; no remote one
        m1, r1, m2 = _js(a, 1), _js(a, 2), _js(a, 3)
        pm.publish(m1)
        pr.publish(r1)
        pm.publish(m2)
        assert got == []  # delivered by the executor, not inside publish()
        ex.spin_once(0.0)
        assert [k for k, _ in got] == ["meas", "raw", "ref", "meas", "raw"]
        assert got[0][1] is m1 and got[3][1] is m2  # the published object itself
        assert got[1][1] == serialize(m1) and got[1][1][:4] == b"\x00\x01\x00\x00"
        assert pm._remote_subscribers() == 0  # nothing was written to DDS
    finally:
        ex.shutdown()
    assert ex.stopped


def test_a_background_node_runs_after_the_whole_chain_of_a_round(domain_id):
    """The recorder of a container (a background node) is set up first and subscribes to every
    topic; still the chain measurement -> estimate -> command runs to its end before any of the
    recorder's callbacks, its timers included, and the recorder gets every message in publish order."""
    ex, (rec, plant, est, ctl) = _composed("recorder", "plant_sim", "estimator", "controller")
    try:
        ex.set_background(rec)
        calls = []
        for t in (contract.MEASUREMENT, contract.ESTIMATE, contract.COMMAND):
            rec.subscribe(t, lambda m, n=t.name: calls.append(("recorder", n)))
        rec_timer = rec.timer(1e-6, lambda: calls.append(("recorder", "timer")))
        pub_est, pub_cmd = est.publisher(contract.ESTIMATE), ctl.publisher(contract.COMMAND)
        est.subscribe(contract.MEASUREMENT, lambda m: (calls.append(("estimator", "in")), pub_est.publish(m)))
        ctl.subscribe(contract.ESTIMATE, lambda m: (calls.append(("controller", "in")), pub_cmd.publish(m)))
        plant.subscribe(contract.COMMAND, lambda m: calls.append(("plant_sim", "command")))
        time.sleep(1e-3)  # the recorder's timer is due
        plant.publisher(contract.MEASUREMENT).publish(_js(plant, 1))
        ex.spin_once(0.0)
        assert calls == [("estimator", "in"), ("controller", "in"), ("plant_sim", "command"),
                         ("recorder", "timer"), ("recorder", contract.MEASUREMENT.name),
                         ("recorder", contract.ESTIMATE.name), ("recorder", contract.COMMAND.name)]
        rec_timer.cancel()
    finally:
        ex.shutdown()


def test_due_timers_fire_shortest_period_first_each_followed_by_what_it_set_off(domain_id):
    """Rate-monotonic: a 1 s diagnostics timer registered before the 1 kHz tick and due in the
    same round runs after the tick and the chain it set off."""
    ex, (ctl, plant) = _composed("controller", "plant_sim")
    try:
        calls = []
        slow = ctl.timer(1.0, lambda: calls.append("diagnostics"))
        pub = plant.publisher(contract.MEASUREMENT)
        fast = plant.timer(1e-3, lambda: (calls.append("tick"), pub.publish(_js(plant, 1))))
        ctl.subscribe(contract.MEASUREMENT, lambda m: calls.append("controller"))
        slow.next_ns = fast.next_ns = time.monotonic_ns()  # both due now
        ex.spin_once(0.0)
        assert calls == ["tick", "controller", "diagnostics"]
    finally:
        ex.shutdown()


def test_remote_subscriber_gets_every_sample_and_locals_get_one_copy(domain_id, spawn, wait_line):
    import json

    ex, (a, b) = _composed("talker_c", "local_listener")
    try:
        local = []
        b.subscribe(contract.MEASUREMENT, lambda m: local.append(m.header.stamp.nanosec))
        pub = a.publisher(contract.MEASUREMENT)
        listener = spawn(domain_id, "listener", 300, "c")
        wait_line(listener, "READY", 30)
        end = time.monotonic() + 20
        while time.monotonic() < end and pub._writer.get_publication_matched_status().current_count < 1:
            ex.spin_once(0.05)
        time.sleep(0.3)  # the publisher re-reads its remote count every 100 ms
        sent = 0
        t0 = time.monotonic()
        while listener.poll() is None and time.monotonic() - t0 < 10 and sent < 3000:
            pub.publish(_js(a, sent))
            sent += 1
            ex.spin_once(0.001)
        stats = json.loads(wait_line(listener, "STATS", 20))
    finally:
        ex.shutdown()
    assert stats["count"] >= 300  # over DDS, from an intra-process publisher
    assert local == list(range(sent))  # each sample once, in order: IgnoreLocal keeps DDS from echoing it


def test_node_shut_down_from_a_callback_leaves_the_others_running(domain_id):
    ex, (a, b) = _composed("keeper", "quitter")
    try:
        fired = {"keeper": 0, "quitter": 0}
        a.timer(0.001, lambda: fired.__setitem__("keeper", fired["keeper"] + 1))

        def quit_now():
            fired["quitter"] += 1
            b.shutdown()  # inside the executor's dispatch: released after it

        b.timer(0.001, quit_now)
        b.subscribe(contract.COMMAND, lambda m: None)
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            ex.spin_once(0.01)
        assert fired["quitter"] == 1 and fired["keeper"] > 50
        assert b.is_shutdown and not a.is_shutdown and not ex.stopped
        assert all(r[3] is not b for r in ex.readers) and all(t.node is not b for t in ex.timers)
    finally:
        a.shutdown()
    assert ex.stopped


def test_global_parameter_overrides_go_to_the_nodes_that_declare_them():
    ra = parse_ros_args(["--ros-args", "-p", "k1:=80.0", "-p", "sigma_gap:=2e-6"])
    assert initial_parameters("controller", ra, "controller", strict=False)["k1"] == 80.0
    assert initial_parameters("estimator", ra, "estimator", strict=False)["sigma_gap"] == 2e-6
    with pytest.raises(ConfigError):  # one node alone: an undeclared name is an error
        initial_parameters("estimator", ra, "estimator")
    _check_composable(["--ros-args", "-p", "k1:=80.0"], ["controller", "plant_sim"])
    with pytest.raises(ConfigError, match="bogus: not a parameter of any node"):
        _check_composable(["--ros-args", "-p", "bogus:=1"], ["controller", "plant_sim"])
    with pytest.raises(ConfigError, match="same name"):
        _check_composable(["--ros-args", "-r", "__node:=x"], ["controller", "plant_sim"])


@pytest.mark.parametrize("args, text", [
    (["--ros-args", "-p", "bogus:=1"], "bogus: not a parameter of any node"),
    (["--nodes", "controller,nope"], "--nodes"),
])
def test_container_bad_arguments_are_clear_errors(domain_id, args, text):
    r = subprocess.run([sys.executable, "-m", "dem_ros.tools.node_main", "container", "--transport", "dds", *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and text in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_node_targeted_remap_in_a_container_remaps_only_that_node(domain_id):
    """``-r controller:/dem/command:=/x`` given to a container: the controller publishes on /x, the plant
    still subscribes to /dem/command (rosargs.py used to drop the node prefix and remap every node)."""
    args = ["--ros-args", "-r", "controller:/dem/command:=/x"]
    ex = DdsExecutor(Participant.get(), intra_process=True)
    ctl = DdsNode("controller", args, executor=ex, ignore_undeclared=True)
    plant = DdsNode("plant_sim", args, executor=ex, ignore_undeclared=True)
    try:
        got = {"plant": [], "x": []}
        plant.subscribe(contract.COMMAND, got["plant"].append)
        plant.subscribe(replace(contract.COMMAND, name="/x"), got["x"].append)
        JS = ctl.msg("sensor_msgs/msg/JointState")
        ctl.publisher(contract.COMMAND).publish(JS(name=list(contract.MAGNETS), effort=[1.0, 2.0]))
        ex.spin_once(0.0)
        assert ctl.resolve(contract.COMMAND.name) == "/x" and plant.resolve(contract.COMMAND.name) == "/dem/command"
        assert len(got["x"]) == 1 and got["plant"] == []
    finally:
        ex.shutdown()
