"""The rogue-writer table (issue #21): a second writer on each loop input, of each kind, beside a real graph.

    .venv/bin/python tests/graph/rogue_table.py --domain-id 98 [--topics command,measurement] [--kinds forged]
        [--topologies per-process,composed] [--timings lockstep,free-run] [--duration 15] [--json out.json]

Each row runs S1 (``launcher.run_graph``, dds, one process per node or composed; lockstep or free-running) with a
rogue process on the same domain. From t = ``--at`` s (experiment clock) the rogue answers every sample of the
topic's real writer with its own, stamped as the *next* sample (first in line), for ``--samples`` samples:

* ``forged``: plausible values (gaps +1 mm, voltages +5 V, reference +1 mm) from a node named ``rogue``;
* ``impersonated``: the same from a node with the source's own name (``controller``, ``plant_sim`` ...);
* ``malformed``: a third element in every array, from a node with the source's name.

A row passes when the plate kept tracking (max |truth - y_m| < 50 um from the rogue's start to the end, y_m the
reference model run offline from the run's own start, checked against the bag before the rogue), did not land,
some ``<node>: inputs`` status on /diagnostics in the bag went ERROR naming the rogue's writer GID, and the run's
verdict (from the bag, as ``dem-ros replay`` gives it) is degraded with a reason naming that GID.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
TOPICS = {"measurement": "plant_sim", "applied_voltage": "plant_sim", "state_estimate": "estimator",
          "reference": "reference", "command": "controller"}
KINDS = ("forged", "impersonated", "malformed")

ROGUE = r"""
import sys
from dem_ros import contract
from dem_ros.nodes.common import stamp_ns, set_stamp
from dem_ros.transport import make_node
topic_key, kind, name, at, samples = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5])
topic = next(t for t in contract.TOPICS if t.name == "/dem/" + topic_key)
n = make_node(name, transport="dds", args=[])
pub = n.publisher(topic)
print("GID", pub.gid.hex(), flush=True)
JS = n.msg("sensor_msgs/msg/JointState")
state = {"epoch": None, "sent": 0, "t": -1.0}
def on_meas(m):
    if m.header.frame_id == contract.FRAME:
        if state["epoch"] is None:
            state["epoch"] = stamp_ns(m)
        state["t"] = (stamp_ns(m) - state["epoch"]) * 1e-9
def on_sample(m, gid):
    if gid == pub.gid or state["t"] < at or state["sent"] >= samples or m.header.frame_id != contract.FRAME:
        return
    p, v, e = list(m.position), list(m.velocity), list(m.effort)
    if kind == "malformed":
        p, e = (p + [p[0]] if p else p), (e + [e[0]] if e else e)
    elif topic_key in ("measurement", "state_estimate", "reference"):
        p[0] += 1e-3
        p[1] += 1e-3
    else:
        e[0] += 5.0
        e[1] += 5.0
    out = JS(header=m.header, name=list(m.name), position=p, velocity=v, effort=e)
    set_stamp(out, stamp_ns(m) + 1_000_000)  # the next sample's stamp: it comes before the real one
    pub.publish(out)
    state["sent"] += 1
n.subscribe(contract.MEASUREMENT, on_meas)
n.subscribe_with_source(topic, on_sample)
while True:
    n.spin_once(0.05)
    if state["sent"] >= samples:
        print("SENT", state["sent"], flush=True)
        state["sent"] += 1
"""


def _env(domain: int) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    return env


def _read(bag: Path) -> dict[str, Any]:
    from rosbags.highlevel import AnyReader

    from dem_ros import contract

    truth: dict[int, tuple[float, float]] = {}
    refs: dict[int, list[tuple[float, float]]] = {}
    inputs: list[tuple[int, str, str, dict[str, str]]] = []
    loop: dict[str, str] = {}
    with AnyReader([bag]) as reader:
        for conn, _t, raw in reader.messages(connections=reader.connections):
            if conn.topic not in (contract.TRUTH.name, contract.REFERENCE.name, contract.DIAGNOSTICS.name):
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            t = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
            if conn.topic == contract.TRUTH.name and len(msg.position) >= 2:
                truth[t] = (float(msg.position[0]), float(msg.position[1]))
            elif conn.topic == contract.REFERENCE.name and msg.header.frame_id == contract.FRAME:
                if len(msg.position) >= 2:
                    refs.setdefault(t, []).append((float(msg.position[0]), float(msg.position[1])))
            elif conn.topic == contract.DIAGNOSTICS.name:
                for st in msg.status:
                    level = st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")
                    values = {kv.key: kv.value for kv in st.values}
                    if st.name.endswith(": inputs"):
                        inputs.append((level, st.name, st.message, values))
                    elif st.name == contract.LOOP_STATUS:
                        loop = values
    return {"truth": truth, "refs": refs, "inputs": inputs, "loop": loop}


def judge(bag: Path, cfg: dict, at: float, gid: str) -> dict[str, Any]:
    """max |truth - y_m| (um) from ``at`` on, landing, and whether an inputs status named ``gid`` at ERROR."""
    from dem_ros.core.reference import reference_trajectory

    b = _read(bag)
    if not b["refs"] or not b["truth"]:
        return {"ok": False, "detail": "no reference or truth in the bag"}
    dt_ns = round(cfg["reference"]["dt"] * 1e9)
    epoch = min(b["refs"])  # the first experiment reference (k = 0, before the rogue: a single writer)
    start = np.array(b["refs"][epoch][0])
    n = max(round((max(b["truth"]) - epoch) / dt_ns) + 1, 1)
    _r, yd = reference_trajectory(cfg["reference"], n, start)
    ks = np.array([round((t - epoch) / dt_ns) for t in b["truth"]])
    g = np.array(list(b["truth"].values()))
    keep = (ks >= 0) & (ks < n)
    ks, g = ks[keep], g[keep]
    e = np.abs(g - yd[ks, :2])
    # the offline model against the bag before the rogue: one writer, so the first reference of each stamp
    pre = [(round((t - epoch) / dt_ns), v[0]) for t, v in b["refs"].items() if (t - epoch) < at * 1e9 - dt_ns]
    model_err = max((abs(yd[k, j] - y[j]) for k, y in pre if 0 <= k < n for j in (0, 1)), default=float("nan"))
    after = ks * cfg["reference"]["dt"] >= at
    max_err = float(np.max(e[after])) * 1e6 if after.any() else float("nan")
    landed = b["loop"].get("landing", "False") == "True" or b["loop"].get("failed", "False") == "True"
    errors = [(name, msg) for level, name, msg, _v in b["inputs"] if level >= 2 and gid and gid in msg]
    refused = max((int(v.get("refused", 0)) for _l, _n, _m, v in b["inputs"]), default=0)
    malformed = max((int(v.get("malformed", 0)) for _l, _n, _m, v in b["inputs"]), default=0)
    verdict, reasons = _verdict(bag)
    named = any(gid[:8] in why for why in reasons) if gid else False  # the reason names the refused writer
    return {"max_error_um": round(max_err, 2), "model_check_um": round(model_err * 1e6, 3), "landed": landed,
            "reported": sorted({n for n, _m in errors}), "refused": refused, "malformed": malformed,
            "verdict": verdict, "verdict_reasons": reasons,
            "ok": bool(max_err < 50.0 and not landed and errors and verdict == "degraded" and named)}


def _verdict(bag: Path) -> tuple[str, list[str]]:
    """The run's verdict and its reasons as ``dem-ros replay`` computes them from the bag alone."""
    from dem_ros.tools.runmetrics import load_run

    m, _series = load_run(bag)
    return m.verdict, list(m.verdict_reasons)


def run_row(topic: str, kind: str, *, compose: bool, free_run: bool, duration: float, at: float, samples: int,
            domain: int, workdir: Path) -> dict[str, Any]:
    from dem_ros.core.scenarios import get_scenario
    from dem_ros.core.warmup import warm_up
    from dem_ros.tools import launcher

    warm_up()
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["lockstep"] = not free_run
    name = "rogue" if kind == "forged" else TOPICS[topic]
    bag = workdir / f"{topic}-{kind}-{'composed' if compose else 'pp'}-{'free' if free_run else 'lock'}"
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds", "config": cfg}
    rogue = subprocess.Popen([sys.executable, "-c", ROGUE, topic, kind, name, str(at), str(samples)],
                             env=_env(domain), cwd=str(ROOT), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out: dict[str, Any] = {}

    def graph() -> None:
        try:
            out["facts"] = launcher.run_graph(cfg, duration=duration, transport="dds", bag=bag, meta=meta,
                                              domain_id=domain, status=False, workdir=bag.with_name(bag.name + "_logs"),
                                              compose=compose)
        except Exception as exc:  # reported in the row
            out["error"] = f"{type(exc).__name__}: {exc}"

    t0 = time.monotonic()
    th = threading.Thread(target=graph)
    th.start()
    th.join(timeout=900)
    rogue.kill()
    text, err = rogue.communicate(timeout=20)
    gid = next((line.split()[1] for line in text.splitlines() if line.startswith("GID ")), "")
    sent = sum(1 for line in text.splitlines() if line.startswith("SENT"))
    row: dict[str, Any] = {"topic": "/dem/" + topic, "kind": kind, "writer": name,
                           "processes": "composed" if compose else "per process",
                           "timing": "free-run" if free_run else "lockstep", "rogue_gid": gid,
                           "rogue_done": bool(sent), "wall_s": round(time.monotonic() - t0, 1)}
    if th.is_alive() or "error" in out:
        row.update(ok=False, detail=out.get("error", "the graph did not finish"))
        return row
    row.update(judge(bag, cfg, at, gid))
    if not gid:
        row.update(ok=False, detail="the rogue did not start: " + err[-300:])
    return row


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| topic | rogue | processes | timing | max \\|truth - y_m\\| [um] | landed | reported (ERROR) | "
             "refused | malformed | verdict | pass |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| `{r['topic']}` | {r['kind']} ({r['writer']}) | {r['processes']} | {r['timing']} | "
                     f"{r.get('max_error_um', '-')} | {r.get('landed', '-')} | "
                     f"{', '.join(r.get('reported', [])) or '-'}"
                     f" | {r.get('refused', '-')} | {r.get('malformed', '-')} | {r.get('verdict', '-')}"
                     f" | {'yes' if r.get('ok') else 'NO'} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domain-id", type=int, required=True)
    p.add_argument("--topics", default=",".join(TOPICS))
    p.add_argument("--kinds", default=",".join(KINDS))
    p.add_argument("--topologies", default="per-process,composed")
    p.add_argument("--timings", default="lockstep,free-run")
    p.add_argument("--duration", type=float, default=15.0)
    p.add_argument("--at", type=float, default=5.0)
    p.add_argument("--samples", type=int, default=2000)
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    workdir = Path(tempfile.mkdtemp(prefix="dem_ros_rogue_"))
    rows = []
    for timing in a.timings.split(","):
        for topo in a.topologies.split(","):
            for topic in a.topics.split(","):
                for kind in a.kinds.split(","):
                    r = run_row(topic, kind, compose=topo == "composed", free_run=timing == "free-run",
                                duration=a.duration, at=a.at, samples=a.samples, domain=a.domain_id, workdir=workdir)
                    r["load"] = os.getloadavg()[0]
                    rows.append(r)
                    print(json.dumps(r), flush=True)
                    if a.json:
                        a.json.write_text(json.dumps(rows, indent=1))
    print(table(rows))
    return 0 if all(r.get("ok") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
