"""Nodes pair their inputs by stamp, whatever order the topics arrive in (real node code, in-memory transport)."""

import numpy as np

from dem_ros import contract
from dem_ros.core.estimator import make_estimator
from dem_ros.core.params import default_config
from dem_ros.nodes.common import joint_state, stamp_ns
from dem_ros.nodes.estimator import EstimatorNode
from dem_ros.transport.memory import MemoryBus


def test_estimator_uses_the_voltage_of_each_measurements_stamp():
    bus = MemoryBus()
    src, est_node, sink = bus.node("plant_sim"), bus.node("estimator"), bus.node("sink")  # plant_sim: the bound writer
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
    # pre-roll frames: a filter started in the pre-roll publishes from its first sample (no convergence wait)
    events += [(k + rng.uniform(-0.1, 0.9), pm,
                joint_state(JS, k * T, position=z[k], effort=i[k], frame=contract.FRAME_PREROLL))
               for k in range(n)]
    events.sort(key=lambda e: e[0])
    assert events[0][1] is pa  # (the very first voltage comes first: the filter starts from it)
    for _, pub, msg in events:
        pub.publish(msg)
        bus.spin_once()
    assert node.counts["unpaired"] == 0
    ref = make_estimator(default_config()["estimator"], None, False)
    for k in range(n):
        xh = ref.step(np.array([z[k, 0], 0.0, z[k, 1], 0.0, i[k, 0], i[k, 1]]), u[k])
        np.testing.assert_allclose(out[k * T], [xh[0], xh[2], xh[1], xh[3]], rtol=0, atol=1e-12)
    assert est_node.callback_errors == {}
