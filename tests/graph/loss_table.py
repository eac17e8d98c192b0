"""The loss table (issue #21 item 4): S1 with a share of every process's UDP datagrams dropped (loopback).

    .venv/bin/python tests/graph/loss_table.py --domain-id 98 --rates 0.01,0.05,0.1 [--duration 30]
        [--topologies per-process,composed] [--timings lockstep,free-run] [--json out.json]

The loss comes from tests/graph/loss/udp_drop.c, an LD_PRELOAD shim built here with the system's C compiler:
every UDP datagram a node process sends is dropped with probability ``rate`` from a seeded sequence (this kernel
has no netem). A row passes when the plate did not land and the run did not fail (the plant's last loop status
in the bag) and the run reached its end; the shim's counts (dropped of sent) come from the node logs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
SHIM = Path(__file__).with_name("loss") / "udp_drop.c"


def build_shim(out_dir: Path) -> Path:
    """Compile the shim (``cc``); its path."""
    so = out_dir / "udp_drop.so"
    subprocess.run(["cc", "-shared", "-fPIC", "-O2", "-o", str(so), str(SHIM), "-ldl"], check=True)
    return so


def _last_loop_status(bag: Path) -> dict[str, str]:
    from rosbags.highlevel import AnyReader

    from dem_ros import contract

    last: dict[str, str] = {}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == contract.DIAGNOSTICS.name]
        for conn, _t, raw in reader.messages(connections=conns):
            for st in reader.deserialize(raw, conn.msgtype).status:
                if st.name == contract.LOOP_STATUS:
                    last = {kv.key: kv.value for kv in st.values} | {"message": st.message}
    return last


def run_row(rate: float, *, compose: bool, free_run: bool, duration: float, domain: int, shim: Path,
            workdir: Path, seed: int = 1) -> dict[str, Any]:
    from dem_ros.core.scenarios import get_scenario
    from dem_ros.core.warmup import warm_up
    from dem_ros.tools import launcher

    warm_up()
    cfg = get_scenario("S1").config()
    cfg["plant_sim"]["lockstep"] = not free_run
    name = f"loss{rate:g}-{'composed' if compose else 'pp'}-{'free' if free_run else 'lock'}"
    bag, logs = workdir / name, workdir / (name + "_logs")
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds", "config": cfg}
    saved = {k: os.environ.get(k) for k in ("LD_PRELOAD", "DEM_UDP_DROP", "DEM_UDP_DROP_SEED")}
    os.environ.update(LD_PRELOAD=str(shim), DEM_UDP_DROP=str(rate), DEM_UDP_DROP_SEED=str(seed))
    row: dict[str, Any] = {"loss": rate, "processes": "composed" if compose else "per process",
                           "timing": "free-run" if free_run else "lockstep", "load": os.getloadavg()[0]}
    t0 = time.monotonic()
    try:
        launcher.run_graph(cfg, duration=duration, transport="dds", bag=bag, meta=meta, domain_id=domain,
                           status=False, workdir=logs, compose=compose)
    except Exception as exc:  # the row says why
        row.update(ok=False, detail=f"{type(exc).__name__}: {exc}"[:300])
        return row
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    row["wall_s"] = round(time.monotonic() - t0, 1)
    last = _last_loop_status(bag)
    drops = [line for p in logs.glob("*.log") for line in p.read_text(errors="replace").splitlines()
             if line.startswith("udp_drop:")]
    d = [tuple(map(int, line.split()[2::2])) for line in drops]  # (dropped, sent)
    row.update(landing=last.get("landing"), failed=last.get("failed"), end=last.get("message", "")[:80],
               holds=last.get("holds"), misses=last.get("deadline_misses"),
               datagrams_dropped=sum(x for x, _ in d), datagrams_sent=sum(y for _, y in d))
    row["ok"] = last.get("landing") == "False" and last.get("failed") == "False" and row["end"].startswith("finished")
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domain-id", type=int, required=True)
    p.add_argument("--rates", default="0.01")
    p.add_argument("--topologies", default="per-process,composed")
    p.add_argument("--timings", default="lockstep,free-run")
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    workdir = Path(tempfile.mkdtemp(prefix="dem_ros_loss_"))
    shim = build_shim(workdir)
    rows = []
    for rate in map(float, a.rates.split(",")):
        for timing in a.timings.split(","):
            for topo in a.topologies.split(","):
                r = run_row(rate, compose=topo == "composed", free_run=timing == "free-run", duration=a.duration,
                            domain=a.domain_id, shim=shim, workdir=workdir)
                rows.append(r)
                print(json.dumps(r), flush=True)
                if a.json:
                    a.json.write_text(json.dumps(rows, indent=1))
    return 0 if all(r.get("ok") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
