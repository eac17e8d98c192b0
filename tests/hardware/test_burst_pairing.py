"""A burst of samples from the hw_driver's link, taken topic by topic: the estimator pairs every
measurement with the applied voltage of its own stamp (real node code, in-memory transport).

Over a serial link (and UDP under load) several sensor frames arrive at once; the driver publishes
``/dem/applied_voltage`` then ``/dem/measurement`` for each, and the DDS executor takes each topic's
reader in turn, so the estimator can get measurements k, k+1, k+2 before the voltages of k+1, k+2
(the "measurement without the applied voltage of its stamp" warnings over serial). They wait, in
stamp order, for their voltages.
"""

from __future__ import annotations

import numpy as np
from loop_writers import publish

from dem_ros import contract
from dem_ros.core.estimator import make_estimator
from dem_ros.core.model import hover_state
from dem_ros.core.params import default_config
from dem_ros.nodes.common import joint_state, stamp_ns
from dem_ros.nodes.estimator import PENDING_MAX, EstimatorNode
from dem_ros.transport.memory import MemoryBus

T = 1_000_000  # ns
CFG = default_config()
X0, U0 = hover_state(CFG["plant_sim"], 0.008)


def _setup():
    bus = MemoryBus()
    node = EstimatorNode(bus.node("estimator", []))
    est: dict[int, np.ndarray] = {}
    bus.node("probe").subscribe(contract.ESTIMATE, lambda m: est.__setitem__(stamp_ns(m), np.array(m.position)))
    return bus, node, est


def _u(k: int) -> tuple[float, float]:
    return (float(U0[0]) + 0.5 * (k % 7), float(U0[1]) - 0.3 * (k % 5))  # a different voltage every sample


def _meas(JS, t: int):
    return joint_state(JS, t, position=(X0[0], X0[2]), effort=(X0[4], X0[5]), frame=contract.FRAME_PREROLL)


def test_measurements_of_a_burst_wait_for_their_own_voltages():
    bus, node, est = _setup()
    JS = bus.msg("sensor_msgs/msg/JointState")
    t0 = bus.now_ns
    n = 60
    for k in range(0, n, 4):  # bursts of 4 frames: the voltage of the first, then the 4 measurements, then 3 voltages
        ts = [t0 + (k + j) * T for j in range(4)]
        publish(bus, contract.APPLIED, joint_state(JS, ts[0], effort=_u(k)))
        for t in ts:
            publish(bus, contract.MEASUREMENT, _meas(JS, t))
        for j in range(1, 4):
            publish(bus, contract.APPLIED, joint_state(JS, ts[j], effort=_u(k + j)))
        bus.spin_once()
    assert node.counts["unpaired"] == 0
    ref = make_estimator(CFG["estimator"], None, False)  # the same filter fed in order, each sample its own voltage
    z = np.array([X0[0], 0.0, X0[2], 0.0, X0[4], X0[5]])
    for k in range(n):
        x = ref.step(z, np.array(_u(k)))
        assert np.allclose(est[t0 + k * T][:2], [x[0], x[2]], rtol=0, atol=1e-12), k


def test_a_voltage_that_never_comes_delays_no_more_than_pending_max_samples():
    bus, node, est = _setup()
    JS = bus.msg("sensor_msgs/msg/JointState")
    t0 = bus.now_ns
    publish(bus, contract.APPLIED, joint_state(JS, t0, effort=_u(0)))
    publish(bus, contract.MEASUREMENT, _meas(JS, t0))
    for k in range(1, 2 * PENDING_MAX + 1):  # the voltages stop: measurements only
        publish(bus, contract.MEASUREMENT, _meas(JS, t0 + k * T))
        bus.spin_once()
    assert len(est) == PENDING_MAX + 1  # each one waited PENDING_MAX samples at most, then went on with the latest
    assert node.counts["unpaired"] == PENDING_MAX
