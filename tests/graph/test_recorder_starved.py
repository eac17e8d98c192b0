"""A starved recorder states exactly how many plant samples its bag lacks (issue #21 item 2): real graph, real
DDS on loopback. The recorder is SIGSTOPped for 2 s mid-run: its socket overflows and the writers' history
(3 s) may or may not cover the recovery; whatever the bag lacks, the recorder's count of lost plant samples (the
/dem/measurement stamp grid, bag/recorder.StampGrid) equals the holes in the bag's own stamps, to the sample."""


import numpy as np
from process_stop import StopOnce

from dem_ros import contract
from dem_ros.bag import BagReader
from dem_ros.core.scenarios import get_scenario
from dem_ros.tools import launcher

DURATION = 6.0
STALL_S = 2.0
STALL_AT_S = 1.5


def test_a_starved_recorder_counts_every_plant_sample_its_bag_lacks(tmp_path, domain_id):
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["lockstep"] = True  # the plant runs on, however loaded the machine
    bag = tmp_path / "run"
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds", "config": cfg}
    stall = StopOnce("recorder", STALL_AT_S, STALL_S)
    try:
        facts = launcher.run_graph(cfg, duration=DURATION, transport="dds", bag=bag, meta=meta, domain_id=domain_id,
                                   status=False, workdir=tmp_path / "logs", supervise=stall)
    finally:
        stall.join()
    assert stall.stopped_s is not None and stall.stopped_s >= STALL_S, "the run ended before the recorder was stopped"
    stamps = np.unique(BagReader(bag).joint_state_arrays(contract.MEASUREMENT.name)["stamp_ns"])
    missing = int(np.rint((stamps[-1] - stamps[0]) / 1e6)) + 1 - stamps.size
    counted = facts["recorder"][contract.MEASUREMENT.name]["lost"]
    assert counted == missing, (counted, missing)
    print(f"\nrecorder stopped {stall.stopped_s:.2f} s: {missing} plant samples missing from the bag, "
          f"{counted} counted lost by the recorder")
