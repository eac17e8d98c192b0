"""Record an offline run (``dem-ros sim --record DIR``) as a bag shaped like a graph run's.

Same topics, types and stamps convention (sample k at epoch + k T) as the node graph,
so ``dem-ros replay`` and ``dem-ros bag check`` treat both alike: /dem/plant/truth,
/dem/reference, /dem/command, /dem/controller/state, /dem/run_info and a final
plant diagnostics record carrying the epoch.
"""

from __future__ import annotations

import json
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__, contract

__all__ = ["record_result"]


def record_result(res: Any, root: Path) -> Path:
    """Write the offline run ``res`` (a SimResult) as a bag under ``root``; return the bag's path.

    Messages are the DDS transport's classes encoded by its codec (:func:`dem_ros.transport.serialize`),
    the bytes a graph run records.
    """
    from ..bag import BagWriter
    from ..nodes.common import diag_array, joint_state, named_vector
    from ..transport import serialize
    from ..transport.dds.msgs import message_class

    JS = message_class("sensor_msgs/msg/JointState")
    DA, DS, KV = (message_class(f"diagnostic_msgs/msg/{n}")
                  for n in ("DiagnosticArray", "DiagnosticStatus", "KeyValue"))
    String = message_class("std_msgs/msg/String")
    root.mkdir(parents=True, exist_ok=True)
    path = root / f"{datetime.now():%Y%m%d-%H%M%S}_{res.scenario}_{res.controller}_offline"
    dt_ns = round(res.config["plant_sim"]["dt"] * 1e9)
    epoch = time.time_ns()
    meta = {"scenario": res.scenario, "controller": res.controller, "estimator": res.estimator, "transport": "offline",
            "dem_ros_version": __version__, "config": res.config, "offline": True}

    topics = [contract.TRUTH, contract.REFERENCE, contract.COMMAND, contract.CONTROLLER_STATE, contract.RUN_INFO,
              contract.DIAGNOSTICS]
    with BagWriter(path, metadata=meta) as w:
        for t in topics:
            w.add_topic(t.name, t.type, t.qos)
        w.write(contract.RUN_INFO.name, epoch, serialize(String(data=json.dumps(meta))))
        names_truth = (*contract.MAGNETS, "mass")
        for k in range(res.t.size):
            t_ns = epoch + k * dt_ns
            x, ref, d = res.x[k], res.ref[k], res.diag[k]
            w.write(contract.TRUTH.name, t_ns, serialize(joint_state(
                JS, t_ns, (x[0], x[2], res.mass[k]), (x[1], x[3]), (x[4], x[5]), names=names_truth)))
            w.write(contract.REFERENCE.name, t_ns, serialize(named_vector(
                JS, t_ns, contract.REFERENCE_NAMES, np.concatenate([ref, res.r[k]]))))
            w.write(contract.COMMAND.name, t_ns, serialize(joint_state(JS, t_ns, effort=res.u[k])))
            w.write(contract.CONTROLLER_STATE.name, t_ns, serialize(named_vector(
                JS, t_ns, contract.CONTROLLER_STATE_NAMES, (*d[:8], 0.0, d[8], 0.0))))
        values = {"cycles": res.t.size, "deadline_misses": 0, "epoch_ns": epoch, "failed": res.failed,
                  "latency_p50_us": "nan", "latency_p99_us": "nan", "latency_max_us": "nan"}
        t_end = epoch + res.t.size * dt_ns
        w.write(contract.DIAGNOSTICS.name, t_end, serialize(
            diag_array(DA, DS, KV, t_end, contract.LOOP_STATUS, 2 if res.failed else 0, "offline run", values)))
    return path
