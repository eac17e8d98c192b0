"""Subprocess body for the crash tests: record until killed or interrupted.

usage: python _child.py kill|sigint BAG
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from bagutil import joint_state_cdr

from dem_ros.bag import BagWriter, Recorder, finalize_on_signals
from dem_ros.contract import MEASUREMENT, RUN_INFO, TOPICS

mode, bag = sys.argv[1], Path(sys.argv[2])
names = ["magnet_1", "magnet_2"]

if mode == "kill":
    w = BagWriter(bag, chunk_size=8 * 1024, metadata={"scenario": "crash"})
    for t in TOPICS:
        w.add_topic(t.name, t.type, t.qos)
    k = 0
    announced = False
    while True:  # until SIGKILL
        w.write(MEASUREMENT.name, 10**9 + k * 10**6, joint_state_cdr(names, [k * 1e-3, 0.0], [], [1.0, 2.0], k * 10**6))
        k += 1
        if k == 2000 and not announced:
            print("written", flush=True)
            announced = True
        if k > 2000:
            time.sleep(0.0002)
else:
    rec = Recorder(bag, [MEASUREMENT, RUN_INFO], {"scenario": "sigint"}, chunk_size=8 * 1024)
    finalize_on_signals(rec)
    k = 0
    t0 = time.perf_counter()
    while True:  # until SIGINT
        deadline = t0 + k * 1e-3
        d = deadline - time.perf_counter()
        if d > 0:
            time.sleep(d)
        rec.on_message(MEASUREMENT.name, 10**9 + k * 10**6,
                       joint_state_cdr(names, [k * 1e-3, 0.0], [], [1.0, 2.0], k * 10**6))
        k += 1
        if k == 300:
            print("recording", flush=True)
