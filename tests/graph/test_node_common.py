"""The nodes' shared helpers: loop statistics and the cheap finite/clip checks of the 1 kHz path."""

import math

import numpy as np

from dem_ros.nodes.common import LatencyStats, all_finite, clipped


def test_latency_histogram_matches_numpy_percentiles_to_a_bin():
    rng = np.random.default_rng(3)
    x = rng.lognormal(12.5, 0.6, 50_000).astype(np.int64)  # ~270 us median, tail to a few ms
    s = LatencyStats()
    for v in x.tolist():
        s.add(v)
    p50, p99 = np.percentile(x / 1e3, [50, 99])
    out = s.summary_us()
    assert abs(out["p50"] - p50) <= 1.0 and abs(out["p99"] - p99) <= 1.0, (out, p50, p99)
    assert out["max"] == x.max() / 1e3


def test_latency_beyond_the_histogram_reports_the_exact_maximum():
    s = LatencyStats(bin_ns=1000, bins=100)  # 100 us range
    for v in (50_000, 60_000, 5_000_000):
        s.add(v)
    assert s.percentiles_us((0, 50, 100)) == [50.5, 60.5, 5000.0]
    assert all(math.isnan(v) for v in LatencyStats().summary_us().values())


def test_all_finite_and_clipped():
    assert all_finite([1.0, -2.0]) and all_finite(np.array([0.0, 3.0]))
    assert not all_finite([1.0, float("nan")]) and not all_finite(np.array([np.inf, 0.0]))
    assert clipped(np.array([150.0, -300.0, 2.0]), 100.0) == [100.0, -100.0, 2.0]


def test_joint_states_builds_what_joint_state_builds_and_the_same_bytes():
    from dem_ros.contract import FRAME_PREROLL, MAGNETS
    from dem_ros.nodes.common import JointStates, joint_state
    from dem_ros.transport import serialize
    from dem_ros.transport.dds.msgs import JointState

    x = np.array([5.01e-3, -1.2e-4, 4.99e-3, 3.0e-5, 2.51, 2.49])
    t = 1_795_469_903_881_727_163
    J = JointStates(JointState)
    h = J.header(t, FRAME_PREROLL)
    xl = x.tolist()
    new = J.make(h, list(MAGNETS), [xl[0], xl[2]], [xl[1], xl[3]], [xl[4], xl[5]])
    old = joint_state(JointState, t, position=(x[0], x[2]), velocity=(x[1], x[3]), effort=(x[4], x[5]),
                      frame=FRAME_PREROLL)
    assert new == old and serialize(new) == serialize(old)
    assert (new.header.stamp.sec, new.header.stamp.nanosec) == (1_795_469_903, 881_727_163)
    only_effort = J.make(J.header(t), list(MAGNETS), effort=[50.0, 51.0])
    assert serialize(only_effort) == serialize(joint_state(JointState, t, effort=(50.0, 51.0)))
    assert only_effort.position == [] and only_effort.velocity == []


def test_meas_into_fills_in_place_as_meas_array_builds():
    from dem_ros.nodes.common import joint_state, meas_array, meas_into
    from dem_ros.transport.dds.msgs import JointState

    out = np.full(6, np.nan)
    for vel in ((1e-4, -2e-4), ()):
        m = joint_state(JointState, 0, position=(5e-3, 6e-3), velocity=vel, effort=(2.5, 2.6))
        z, has_v = meas_array(m)
        assert meas_into(m, out) == has_v == bool(vel)
        np.testing.assert_array_equal(out, z)
