r"""Running a study on Dask distributed, into its results directory.

Execution
---------
Runs go to Dask distributed in chunks (:func:`run_chunk`, one task each): a
``LocalCluster`` of ``--workers N`` single-threaded worker processes on
127.0.0.1 by default, or an existing cluster with ``--scheduler tcp://HOST:PORT``
(its workers must be able to import ``dem_ros``: Dask ships :func:`run_chunk`
by reference, as ``dem_ros.tools.study.run.run_chunk``). Workers load the numba
kernels before the clock starts.

Results (``--out DIR``)
-----------------------
``results.csv``  one row per run (appended as runs complete): the run's id,
                 controller, estimator, seed, duration and axis values, then
                 :data:`RESULT_FIELDS`. Re-running the same command skips the
                 rows already there (resume after an interruption); rows of
                 other code or settings are never reused (run ids: :mod:`.spec`).
``study.json``   the study's definition and the last session's throughput.
"""

from __future__ import annotations

import csv
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..common import json_text
from ..progress import Progress
from .spec import StudyError, StudySpec, core_digest, plan_runs

__all__ = ["RESULT_FIELDS", "load_results", "run_chunk", "run_study"]

RESULT_FIELDS = (
    "failed", "fail_time_s", "rms_e1_um", "rms_e2_um", "max_e1_um", "max_e2_um",
    "rms40_e1_um", "rms40_e2_um", "peak_voltage_v", "peak_current_a",
    "m_hat_kg", "R_hat_ohm", "K_hat", "wall_time_s", "worker",
)


def run_chunk(jobs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Worker side: simulate each job, return its result fields (see :data:`RESULT_FIELDS`)."""
    from ...core.simulate import simulate

    out = []
    worker = f"{os.uname().nodename}:{os.getpid()}"
    for job in jobs:
        res = simulate(job["cfg"], controller=job["controller"], estimator=job["estimator"],
                       duration=job["duration"], scenario=job["scenario"])
        m = res.metrics()
        fe = m.get("final_estimates") or {}
        out.append({
            "run_id": job["run_id"],
            "failed": int(m["failed"]),
            "fail_time_s": "" if m["fail_time_s"] is None else m["fail_time_s"],
            "rms_e1_um": m["rms_error_um"][0], "rms_e2_um": m["rms_error_um"][1],
            "max_e1_um": m["max_error_um"][0], "max_e2_um": m["max_error_um"][1],
            "rms40_e1_um": m["rms_error_after_40s_um"][0], "rms40_e2_um": m["rms_error_after_40s_um"][1],
            "peak_voltage_v": m["peak_voltage_v"], "peak_current_a": m["peak_current_a"],
            "m_hat_kg": fe.get("m_kg", ""), "R_hat_ohm": fe.get("R_ohm", ""), "K_hat": fe.get("K", ""),
            "wall_time_s": m["wall_time_s"], "worker": worker,
        })
    return out


def _warm_worker() -> str:
    """Load every kernel in a worker (numba cache) so that timing starts warm."""
    from ...core.params import default_config
    from ...core.simulate import simulate

    cfg = default_config()
    for est in ("kf", "none"):
        simulate(cfg, controller="adaptive", estimator=est, duration=0.01)
        simulate(cfg, controller="decentralized_pid", estimator=est, duration=0.01)
    return str(os.getpid())


# ---------------------------------------------------------------------------
# results file
# ---------------------------------------------------------------------------
def _header(spec: StudySpec) -> list[str]:
    return ["run_id", "controller", "estimator", "seed", "duration_s", *(a.name for a in spec.axes), *RESULT_FIELDS]


def load_results(path: Path, header: list[str] | None = None) -> dict[str, dict[str, str]]:
    """Complete rows of ``results.csv`` by run id; a torn last line (killed mid-write) is dropped."""
    if not path.is_file():
        return {}
    with path.open(newline="") as f:
        reader = csv.reader(f)
        try:
            head = next(reader)
        except StopIteration:
            return {}
        if header is not None and head != header:
            raise StudyError(
                f"{path} holds another study (columns {', '.join(head[5:len(head) - len(RESULT_FIELDS)]) or 'none'}); "
                "use another --out or remove it")
        rows = {}
        torn = False
        for r in reader:
            if len(r) != len(head) or not r[-1]:
                torn = True
                continue
            rows[r[0]] = dict(zip(head, r, strict=True))
    if torn and header is not None:  # rewrite without the torn line, so appends stay aligned
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=header)
            w.writeheader()
            w.writerows(rows.values())
    return rows


# ---------------------------------------------------------------------------
# execution on Dask
# ---------------------------------------------------------------------------
def _open_client(scheduler: str | None, workers: int, timeout: float):
    import logging

    from distributed import Client, LocalCluster

    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, silence_logs=logging.ERROR)
        return Client(cluster), cluster
    try:
        client = Client(scheduler, timeout=timeout)
    except (OSError, TimeoutError) as exc:
        raise StudyError(f"cannot reach the Dask scheduler at {scheduler} within {timeout:g} s ({exc})") from None
    try:
        client.wait_for_workers(1, timeout=timeout)
    except (OSError, TimeoutError):
        client.close()
        raise StudyError(f"the Dask scheduler at {scheduler} has no workers (waited {timeout:g} s)") from None
    return client, None


def run_study(spec: StudySpec, out: Path, *, workers: int = 1, scheduler: str | None = None,
              chunk: int | None = None, progress: bool = True, timeout: float = 30.0) -> dict[str, Any]:
    """Run the missing rows of the study into ``out/results.csv``; return the session's figures."""
    jobs = plan_runs(spec)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.csv"
    header = _header(spec)
    done = load_results(path, header)
    todo = [j for j in jobs if j["run_id"] not in done]
    _write_spec(spec, out, [j["run_id"] for j in jobs])
    stats: dict[str, Any] = {"runs": len(jobs), "already_done": len(jobs) - len(todo), "ran": 0}
    if not todo:
        return stats
    if not path.is_file() or path.stat().st_size == 0:
        with path.open("w", newline="") as f:
            csv.writer(f).writerow(header)
    t_start = time.perf_counter()
    bar = Progress("dem-ros study", len(jobs), "runs", done=len(jobs) - len(todo), enabled=progress)
    bar.stage("starting the Dask workers")
    client, cluster = _open_client(scheduler, workers, timeout)
    try:
        from distributed import KilledWorker, as_completed

        addrs = list(client.scheduler_info()["workers"])
        n_workers = len(addrs)
        # every worker loads (or compiles: minutes on a busy machine) its kernels before the clock
        # starts; as tasks, so that the worker's event loop keeps answering the scheduler meanwhile
        # (client.run would execute in that loop and block it)
        bar.stage("the workers load the compiled kernels (on a first run: compile them, minutes)")
        try:
            client.gather([client.submit(_warm_worker, workers=[a], allow_other_workers=False, pure=False)
                           for a in addrs])
        except (OSError, KilledWorker) as exc:
            raise StudyError("lost the Dask cluster while its workers loaded the kernels "
                             f"({type(exc).__name__}: {exc})") from None
        t_ready = time.perf_counter()
        size = chunk or max(1, min(16, len(todo) // (8 * max(n_workers, 1))))
        chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
        by_id = {j["run_id"]: j for j in todo}
        bar.stage("")
        futures = [client.submit(run_chunk, c, pure=False) for c in chunks]
        with path.open("a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=header)
            try:
                for fut in as_completed(futures):
                    try:
                        rows = fut.result()
                    except ModuleNotFoundError as exc:
                        raise StudyError(f"a Dask worker cannot import {exc.name} "
                                         "(start the workers with dem_ros on their PYTHONPATH)") from None
                    except (OSError, KilledWorker) as exc:
                        raise StudyError(f"lost the Dask cluster ({type(exc).__name__}: {exc}); "
                                         f"{bar.done} rows are saved, run the same command to resume") from None
                    for r in rows:
                        j = by_id[r["run_id"]]
                        w.writerow({"run_id": j["run_id"], "controller": j["controller"], "estimator": j["estimator"],
                                    "seed": j["seed"], "duration_s": j["duration"], **j["values"], **r})
                    f.flush()
                    bar.step(len(rows), failed=sum(int(r["failed"]) for r in rows))
            finally:
                for fut in futures:
                    fut.cancel()
        t_end = time.perf_counter()
    finally:
        bar.close()
        client.close()
        if cluster is not None:
            cluster.close()
    stats.update({
        "ran": len(todo), "workers": n_workers, "chunk": size, "startup_s": t_ready - t_start,
        "elapsed_s": t_end - t_ready, "runs_per_s": len(todo) / (t_end - t_ready),
        "simulated_s_per_run": spec.duration, "scheduler": scheduler or "LocalCluster(127.0.0.1)",
        "load_average": list(os.getloadavg()),
    })
    _write_spec(spec, out, [j["run_id"] for j in jobs], stats)
    return stats


def _write_spec(spec: StudySpec, out: Path, run_ids: list[str], stats: Mapping[str, Any] | None = None) -> None:
    p = out / "study.json"
    old = json.loads(p.read_text()) if p.is_file() else {}
    doc = {
        "scenario": spec.scenario, "mode": spec.mode, "samples": spec.samples, "seed": spec.seed,
        "duration_s": spec.duration, "controllers": list(spec.controllers),
        "estimator": spec.estimator or spec.base["estimator"]["type"],
        "axes": [{"name": a.name, "unit": a.unit, "values": list(a.values) if a.values is not None else None,
                  "range": None if a.values is not None else [a.low, a.high]} for a in spec.axes],
        "runs": len(run_ids), "core_digest": core_digest(),
        "last_session": stats if stats is not None else old.get("last_session"),
        "run_ids": run_ids,
    }
    p.write_text(json_text(doc))
