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
