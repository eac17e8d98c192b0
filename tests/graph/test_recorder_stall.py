"""A recorder process stalled for a while (a busy host) loses nothing: real graph, real DDS on loopback.

The recorder is SIGSTOPped for STALL_S mid-run and continued. While it is stopped its socket fills up (Cyclone
asks for 1 MiB, the kernel caps it at net.core.rmem_max: ~0.35 s of the graph's traffic with 4 MiB allowed,
~0.08 s with a stock 208 KiB) and the kernel drops the rest; when it runs again it NACKs the holes and the
writers resend them from their history. That works only while the writers still hold those samples: a
keep-last writer never blocks, it drops its oldest sample, acknowledged or not. With the readers' depth as
the writers' (100 samples, 100 ms) a 0.6 s stall lost 254 consecutive plant samples (a 0.3 s one nothing on
a 4 MiB host); with the writers' 1 s (``QOS_STREAM.writer_depth``) the stall plus the recovery fit.
"""

import time

import numpy as np
from process_stop import StopOnce

from dem_ros import contract
from dem_ros.bag import BagReader
from dem_ros.core.scenarios import get_scenario
from dem_ros.tools import launcher

DURATION = 4.0
#: how long the recorder is stopped: longer than its socket holds on any host (above) plus the old writers'
#: history (100 ms), 0.2x the new one (3 s); the recorder's longest stall in a failed loaded `make demo`: 0.49 s
STALL_S = 0.6
#: t (experiment clock, wall time since t = 0) at which the recorder is stopped
STALL_AT_S = 1.5


def test_a_stalled_recorder_loses_no_plant_sample(tmp_path, domain_id):
    cfg = get_scenario("S1").config()
    bag = tmp_path / "run"
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds", "config": cfg}
    stall = StopOnce("recorder", STALL_AT_S, STALL_S)
    try:
        launcher.run_graph(cfg, duration=DURATION, transport="dds", bag=bag, meta=meta, domain_id=domain_id,
                           status=False, workdir=tmp_path / "logs", supervise=stall)
    finally:
        stall.join()
    assert stall.stopped_s is not None, "the run ended before the recorder was stopped"
    assert stall.stopped_s >= STALL_S

    m = BagReader(bag).joint_state_arrays(contract.MEASUREMENT.name)
    stamps = np.sort(m["stamp_ns"])
    step = np.diff(stamps)
    dt = float(np.median(step))
    assert abs(dt - 1e6) < 1e3, dt  # 1 kHz
    holes = np.round(step / dt).astype(np.int64) - 1
    at = np.flatnonzero(holes > 0)
    assert not at.size, (f"{int(holes[at].sum())} plant samples missing from the bag in {at.size} stretch(es), "
                         f"longest {int(holes.max())}, from t = {(stamps[at[0]] - stamps[0]) * 1e-9:.3f} s")
    # the recorder wrote the whole run, pre-roll and all: nothing cut at either end
    seconds = (stamps[-1] - stamps[0]) * 1e-9
    assert seconds >= DURATION, seconds


def test_the_writers_keep_a_second_and_the_readers_a_tenth(domain_id):
    """The 1 kHz streams on the wire: writers KEEP_LAST 3000, the loop's readers KEEP_LAST 100 (they never take a
    longer backlog)."""
    from cyclonedds.qos import Policy

    from dem_ros.transport import make_node
    from dem_ros.transport.dds.node import DdsPublisher

    node = make_node("qos_probe", transport="dds", args=[])
    try:
        pub = node.publisher(contract.MEASUREMENT)
        assert isinstance(pub, DdsPublisher)
        node.subscribe(contract.MEASUREMENT, lambda _m: None)
        writer_history = pub.writer.get_qos()[Policy.History]
        assert writer_history == Policy.History.KeepLast(3000), writer_history
        end = time.monotonic() + 10
        while time.monotonic() < end and not pub.writer.get_matched_subscriptions():
            time.sleep(0.05)
        matched = [pub.writer.get_matched_subscription_data(h) for h in pub.writer.get_matched_subscriptions()]
        assert [r.qos[Policy.History] for r in matched] == [Policy.History.KeepLast(100)]  # as the writer sees it
    finally:
        node.shutdown()
