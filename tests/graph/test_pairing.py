"""Nodes pair their inputs by stamp, whatever order the topics arrive in (real node code on a real executor)."""

import numpy as np

from dem_ros import contract
from dem_ros.core.estimator import make_estimator
from dem_ros.core.params import default_config
from dem_ros.nodes.common import joint_state, stamp_ns
from dem_ros.nodes.estimator import EstimatorNode
from dem_ros.transport.dds.executor import DdsExecutor
from dem_ros.transport.dds.node import DdsNode, Participant


def test_estimator_uses_the_voltage_of_each_measurements_stamp(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "0")
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")  # nothing leaves this process
    ex = DdsExecutor(Participant.get(), intra_process=True)
    src = DdsNode("source", [], executor=ex, ignore_undeclared=True)
    est_node = DdsNode("estimator", [], executor=ex, ignore_undeclared=True)
    sink = DdsNode("sink", [], executor=ex, ignore_undeclared=True)
    try:
        node = EstimatorNode(est_node)
        out = {}
        sink.subscribe(contract.ESTIMATE, lambda m: out.__setitem__(stamp_ns(m), list(m.position) + list(m.velocity)))
        JS = src.msg("sensor_msgs/msg/JointState")
        pm, pa = src.publisher(contract.MEASUREMENT), src.publisher(contract.APPLIED)
        rng = np.random.default_rng(7)
        n, T = 200, 1_000_000
        z = 0.008 + 1e-6 * rng.standard_normal((n, 2))
        i = 1.0 + 0.01 * rng.standard_normal((n, 2))
        u = 80.0 + rng.standard_normal((n, 2))
        # arrival order across the two topics: a measurement before its voltage, or after the next
        # sample's voltage (the plant runs one sample ahead with command_delay 1), never two samples off
        events = [(k + rng.uniform(-0.9, 0.3), pa, joint_state(JS, k * T, effort=u[k])) for k in range(n)]
        events += [(k + rng.uniform(-0.1, 0.9), pm, joint_state(JS, k * T, position=z[k], effort=i[k]))
                   for k in range(n)]
        events.sort(key=lambda e: e[0])
        assert events[0][1] is pa  # (the very first voltage comes first: the filter starts from it)
        for _, pub, msg in events:
            pub.publish(msg)
            ex.spin_once(0.0)
        assert node.unpaired == 0
        ref = make_estimator(default_config()["estimator"], None, False)
        for k in range(n):
            xh = ref.step(np.array([z[k, 0], 0.0, z[k, 1], 0.0, i[k, 0], i[k, 1]]), u[k])
            np.testing.assert_allclose(out[k * T], [xh[0], xh[2], xh[1], xh[3]], rtol=0, atol=1e-12)
    finally:
        ex.shutdown()
