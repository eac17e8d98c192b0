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

import numpy as np

from .. import __version__, contract

__all__ = ["record_result"]


def record_result(res, root: Path) -> Path:
    from rosbags.typesys import Stores, get_typestore

    from ..bag import BagWriter

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    JS, Header, Time = T["sensor_msgs/msg/JointState"], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    root.mkdir(parents=True, exist_ok=True)
    path = root / f"{datetime.now():%Y%m%d-%H%M%S}_{res.scenario}_{res.controller}_offline"
    dt_ns = int(round(res.config["plant_sim"]["dt"] * 1e9))
    epoch = time.time_ns()
    meta = {"scenario": res.scenario, "controller": res.controller, "estimator": res.estimator, "transport": "offline",
            "dem_ros_version": __version__, "config": res.config, "offline": True}

    def js(t_ns, names, position=(), velocity=(), effort=()):
        h = Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=contract.FRAME)
        return ts.serialize_cdr(JS(header=h, name=list(names), position=np.asarray(position, float),
                                   velocity=np.asarray(velocity, float), effort=np.asarray(effort, float)),
                                "sensor_msgs/msg/JointState")

    topics = [contract.TRUTH, contract.REFERENCE, contract.COMMAND, contract.CONTROLLER_STATE, contract.RUN_INFO,
              contract.DIAGNOSTICS]
    with BagWriter(path, metadata=meta) as w:
        for t in topics:
            w.add_topic(t.name, t.type, t.qos)
        info = ts.serialize_cdr(T["std_msgs/msg/String"](data=json.dumps(meta)), "std_msgs/msg/String")
        w.write(contract.RUN_INFO.name, epoch, info)
        names_truth = (*contract.MAGNETS, "mass")
        for k in range(res.t.size):
            t_ns = epoch + k * dt_ns
            x, ref, d = res.x[k], res.ref[k], res.diag[k]
            w.write(contract.TRUTH.name, t_ns, js(t_ns, names_truth, (x[0], x[2], res.mass[k]), (x[1], x[3]), (x[4], x[5])))
            w.write(contract.REFERENCE.name, t_ns, js(t_ns, contract.REFERENCE_NAMES, np.concatenate([ref, res.r[k]])))
            w.write(contract.COMMAND.name, t_ns, js(t_ns, contract.MAGNETS, effort=res.u[k]))
            w.write(contract.CONTROLLER_STATE.name, t_ns,
                    js(t_ns, contract.CONTROLLER_STATE_NAMES, (*d[:8], 0.0, d[8], 0.0)))
        DA, DS, KV = T["diagnostic_msgs/msg/DiagnosticArray"], T["diagnostic_msgs/msg/DiagnosticStatus"], T["diagnostic_msgs/msg/KeyValue"]
        values = {"cycles": res.t.size, "deadline_misses": 0, "epoch_ns": epoch, "failed": res.failed,
                  "latency_p50_us": "nan", "latency_p99_us": "nan", "latency_max_us": "nan"}
        t_end = epoch + res.t.size * dt_ns
        st = DS(level=2 if res.failed else 0, name="plant_sim: loop", message="offline run", hardware_id="dem",
                values=[KV(key=k, value=str(v)) for k, v in values.items()])
        w.write(contract.DIAGNOSTICS.name, t_end, ts.serialize_cdr(
            DA(header=Header(stamp=Time(sec=t_end // 10**9, nanosec=t_end % 10**9), frame_id=""), status=[st]),
            "diagnostic_msgs/msg/DiagnosticArray"))
    return path
