r"""``dem-ros study``: robustness of the controllers over plant truth, on Dask distributed.

A study runs every *cell* of a grid (or every sample of a Monte Carlo draw) over
the true plant, for each controller, as one closed-loop run of the offline
simulator (:func:`dem_ros.core.simulate.simulate`, i.e. the compiled
``_closed_loop`` kernel with the estimator, noise, delay and plant of the run's
validated configuration). Nothing of the plant is re-implemented here: a cell
is a set of schema overrides, applied with :func:`~dem_ros.core.params.apply_overrides`
on top of the scenario, so every value is checked against the schema (field,
bounds, cross-field rules) before any work is sent out.

Axes
----
``--axis NAME=SPEC`` (repeatable). ``NAME`` is a schema parameter
``GROUP.NAME`` (``plant_sim.m``, ``plant_sim.R``, ``plant_sim.K``,
``plant_sim.noise_scale``, ``plant_sim.command_delay``, ``estimator.R``, ...)
or a derived axis:

``hover_asymmetry`` a (m)
    uneven start: d1_0 = gap0 + a, d2_0 = gap0 - a (``plant_sim.d1_0``,
    ``plant_sim.d2_0``; the plant starts in exact equilibrium there).

``SPEC`` is ``LO:HI:N`` (N values, evenly spaced, ends included), ``LO:HI``
(Monte Carlo: uniform on [LO, HI]; integer parameters: every integer of a
grid), or ``V1,V2,...``. A value may be relative to the scenario's value of
that parameter: ``-20%:+25%:4`` on ``plant_sim.R`` is 16 ... 25 ohm.
Note that ``plant_sim.command_delay`` is the plant's true delay only; the
controller keeps ``controller.command_delay`` (a mismatch study).

Seeds
-----
Grid: every cell uses ``plant_sim.seed`` = ``--seed`` (common random numbers:
cells differ only in the plant). Monte Carlo: sample i draws its axis values
from ``default_rng([seed, i])`` and its noise from ``plant_sim.seed = seed + i``,
so ``--samples 400`` after ``--samples 200`` reuses the first 200 runs.

Results (``--out DIR``)
-----------------------
``results.csv``  one row per run (appended as runs complete). A run is
                 identified by a hash of its complete configuration, controller,
                 estimator, duration and the simulator's source
                 (:func:`core_digest`): re-running the same command skips the
                 rows already there (resume after an interruption); rows of
                 other code or settings are never reused.
``study.json``   the study's definition and the last session's throughput.
``map_<controller>.png``  robustness map: worst RMS tracking error over the
                 axes not drawn, failed cells marked, axes in their units.
``summary.md``   the robustness table (also in ``dem-ros report``).

A run *survives* when the plate never leaves (0.1 mm, 30 mm) (the simulator's
failure test); it *passes* when it survives with RMS error < ``--rms-limit``
on both outputs (default 100 um, the report's noise criterion).

Execution
---------
Runs go to Dask distributed in chunks: a ``LocalCluster`` of ``--workers N``
single-threaded worker processes on 127.0.0.1 by default, or an existing
cluster with ``--scheduler tcp://HOST:PORT`` (its workers must be able to
import ``dem_ros``). Workers load the numba kernels before the clock starts.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import os
import re
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.params import SCHEMA, ConfigError, ParamSpec, apply_overrides
from .common import CONTROLLER_TYPES, ESTIMATOR_TYPES, json_text, load_config
from .progress import Progress

__all__ = [
    "Axis",
    "StudyError",
    "StudySpec",
    "add_arguments",
    "cmd_study",
    "core_digest",
    "parse_axis",
    "plan_runs",
    "report_section",
    "robustness_rows",
    "robustness_table",
    "run_chunk",
    "run_study",
]

PRESETS: dict[str, tuple[str, ...]] = {
    # the grid of issue #8: m 10-25 kg x R -20..+25 % x K +-20 % x hover asymmetry up to +-0.5 mm
    "acceptance": (
        "plant_sim.m=10:25:4",
        "plant_sim.R=-20%,-10%,0%,+10%,+25%",
        "plant_sim.K=-20%:+20%:3",
        "hover_asymmetry=-0.5e-3:0.5e-3:3",
    ),
}

RESULT_FIELDS = (
    "failed", "fail_time_s", "rms_e1_um", "rms_e2_um", "max_e1_um", "max_e2_um",
    "rms40_e1_um", "rms40_e2_um", "peak_voltage_v", "peak_current_a",
    "m_hat_kg", "R_hat_ohm", "K_hat", "wall_time_s", "worker",
)


class StudyError(RuntimeError):
    """The study cannot run (cluster unreachable, results of another study, a worker error)."""


# ---------------------------------------------------------------------------
# axes
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Derived:
    """An axis that sets several schema parameters from one value."""

    unit: str
    description: str
    needs: tuple[tuple[str, str], ...]
    apply: Callable[[Mapping[str, Mapping[str, Any]], float], dict[str, dict[str, Any]]]
    type: type = float


def _hover_asymmetry(cfg: Mapping[str, Mapping[str, Any]], a: float) -> dict[str, dict[str, Any]]:
    g0 = cfg["plant_sim"]["gap0"]
    return {"plant_sim": {"d1_0": g0 + a, "d2_0": g0 - a}}


DERIVED: dict[str, Derived] = {
    "hover_asymmetry": Derived(
        "m", "uneven start: d1_0 = gap0 + a, d2_0 = gap0 - a",
        (("plant_sim", "d1_0"), ("plant_sim", "d2_0")), _hover_asymmetry),
}


@dataclass(frozen=True)
class Axis:
    """One axis of the study.

    Attributes:
        name: ``GROUP.NAME`` of a schema parameter or a key of :data:`DERIVED`.
        unit: SI unit of the values.
        type: the parameter's type (float, int, bool, str).
        values: grid values (already of the parameter's type); with Monte Carlo, the
            list one value is drawn from. ``None``: a Monte Carlo range.
        low, high: Monte Carlo range (inclusive), in the parameter's unit.
    """

    name: str
    unit: str
    type: type
    values: tuple[Any, ...] | None = None
    low: float | None = None
    high: float | None = None

    def draw(self, rng: np.random.Generator) -> Any:
        """One Monte Carlo value."""
        if self.values is not None:
            return self.values[int(rng.integers(len(self.values)))]
        assert self.low is not None and self.high is not None
        if self.type is int:
            return int(rng.integers(int(self.low), int(self.high) + 1))
        return float(rng.uniform(self.low, self.high))

    def overrides(self, cfg: Mapping[str, Mapping[str, Any]], value: Any) -> dict[str, dict[str, Any]]:
        if self.name in DERIVED:
            return DERIVED[self.name].apply(cfg, value)
        group, name = self.name.split(".", 1)
        return {group: {name: value}}


def _axis_target(name: str) -> tuple[ParamSpec | None, Derived | None]:
    if name in DERIVED:
        d = DERIVED[name]
        for g, n in d.needs:
            try:
                SCHEMA.spec(g, n)
            except ConfigError:
                raise ConfigError(f"axis {name}: needs {g}.{n}, "
                                  "which this build's parameter schema does not have") from None
        return None, d
    group, dot, pname = name.partition(".")
    if not dot or not pname:
        raise ConfigError(f"axis {name!r}: expected GROUP.NAME (e.g. plant_sim.m) or one of: {', '.join(DERIVED)}")
    if group not in SCHEMA.groups:
        raise ConfigError(f"axis {name}: unknown group {group!r}; known: {', '.join(SCHEMA.groups)}")
    spec = SCHEMA.spec(group, pname)
    if spec.read_only:
        raise ConfigError(f"axis {name}: a read-only parameter cannot be an axis")
    if (group, pname) == ("controller", "type") or (group, pname) == ("estimator", "type"):
        raise ConfigError(f"axis {name}: choose laws with --controllers and the estimator with --estimator")
    return spec, None


def _number(text: str, name: str, base: float | None, kind: type) -> float:
    t = text.strip()
    rel = t.endswith("%")
    if rel and (base is None or kind is not float):
        raise ConfigError(f"axis {name}: {t!r}: a relative value (%) needs a float parameter")
    if rel and base == 0.0:
        raise ConfigError(f"axis {name}: {t!r}: a relative value (%) needs a non-zero value in the scenario (it has 0)")
    try:
        v = float(t[:-1] if rel else t)
    except ValueError:
        raise ConfigError(f"axis {name}: {t!r} is not a number") from None
    return base * (1.0 + v / 100.0) if rel else v  # type: ignore[operator]


def parse_axis(text: str, base: Mapping[str, Mapping[str, Any]], monte_carlo: bool = False) -> Axis:
    """Parse ``NAME=SPEC`` (module docstring) against the scenario config ``base``."""
    if "=" not in text:
        raise ConfigError(f"axis {text!r}: expected NAME=SPEC, e.g. plant_sim.m=10:25:4 or plant_sim.R=-20%:+25%:4")
    name, spec_text = (s.strip() for s in text.split("=", 1))
    spec, derived = _axis_target(name)
    if spec is not None:
        group, pname = name.split(".", 1)
        kind, unit, base_value = spec.type, spec.unit, base[group][pname]
    else:
        assert derived is not None
        kind, unit, base_value = derived.type, derived.unit, None

    def coerce(v: Any) -> Any:
        if spec is None:
            return float(v)
        if kind is int and isinstance(v, float) and v.is_integer():
            v = int(v)
        return spec.coerce(v, f"axis {name}")

    if not spec_text:
        raise ConfigError(f"axis {name}: no values")
    if kind in (bool, str):
        words = [w.strip() for w in spec_text.split(",")]
        vals = tuple(coerce(True if w.lower() == "true" else False if w.lower() == "false" else w) for w in words)
        return Axis(name, unit, kind, values=vals)
    if ":" in spec_text:
        parts = spec_text.split(":")
        if len(parts) not in (2, 3):
            raise ConfigError(f"axis {name}: {spec_text!r}: expected LO:HI:N, LO:HI or V1,V2,...")
        lo = _number(parts[0], name, base_value, kind)
        hi = _number(parts[1], name, base_value, kind)
        if not lo <= hi:
            raise ConfigError(f"axis {name}: LO = {parts[0]} must not exceed HI = {parts[1]}")
        if monte_carlo and len(parts) == 2:
            return Axis(name, unit, kind, low=coerce(lo), high=coerce(hi))
        if len(parts) == 2:
            if kind is not int:
                raise ConfigError(f"axis {name}: a grid axis needs a count, e.g. {parts[0]}:{parts[1]}:4 "
                                  "(or use --samples)")
            vals = tuple(coerce(v) for v in range(math.ceil(lo), math.floor(hi) + 1))
        else:
            try:
                n = int(parts[2])
            except ValueError:
                raise ConfigError(f"axis {name}: count {parts[2]!r} is not an integer") from None
            if not 1 <= n <= 10000:
                raise ConfigError(f"axis {name}: count {n} must lie in [1, 10000]")
            raw = np.linspace(lo, hi, n) if n > 1 else np.array([lo])
            if kind is int:
                if not np.allclose(raw, np.round(raw)):
                    raise ConfigError(f"axis {name}: {spec_text} does not give integers for an integer parameter")
                raw = np.round(raw)
            vals = tuple(coerce(float(f"{v:.12g}")) for v in raw)
    else:
        vals = tuple(coerce(float(f"{_number(w, name, base_value, kind):.12g}")) for w in spec_text.split(","))
    if len(set(vals)) != len(vals):
        raise ConfigError(f"axis {name}: repeated values {list(vals)}")
    return Axis(name, unit, kind, values=vals)


# ---------------------------------------------------------------------------
# the plan: one job per run
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class StudySpec:
    """Everything that defines a study (the command line, validated)."""

    scenario: str
    base: Mapping[str, Mapping[str, Any]]  # scenario config with --set applied
    axes: tuple[Axis, ...]
    controllers: tuple[str, ...]
    estimator: str | None
    duration: float
    seed: int
    samples: int | None  # None: grid

    @property
    def mode(self) -> str:
        return "grid" if self.samples is None else "monte_carlo"


def core_digest() -> str:
    """SHA-1 of the simulator's source (``dem_ros/core/**/*.py``): results of other code are not reused."""
    global _CORE_DIGEST
    if _CORE_DIGEST is None:
        root = Path(__file__).resolve().parents[1] / "core"
        h = hashlib.sha1()
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
        _CORE_DIGEST = h.hexdigest()
    return _CORE_DIGEST


_CORE_DIGEST: str | None = None


def _run_id(cfg: Mapping, controller: str, estimator: str, duration: float) -> str:
    blob = json.dumps({"cfg": cfg, "controller": controller, "estimator": estimator, "duration": duration,
                       "core": core_digest()}, sort_keys=True, default=str)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def _merge(a: dict[str, dict[str, Any]], b: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    for g, v in b.items():
        a.setdefault(g, {}).update(v)
    return a


def _cells(spec: StudySpec) -> list[tuple[tuple[Any, ...], int]]:
    """(axis values, noise seed) of every cell / sample."""
    if spec.samples is None:
        import itertools

        # (a grid axis always has its values: an axis without a count is refused unless --samples)
        return [(vals, spec.seed) for vals in itertools.product(*(a.values or () for a in spec.axes))]
    out = []
    for i in range(spec.samples):
        rng = np.random.default_rng([spec.seed, i])
        out.append((tuple(a.draw(rng) for a in spec.axes), (spec.seed + i) % 2**31))
    return out


def plan_runs(spec: StudySpec) -> list[dict[str, Any]]:
    """One job per (cell, controller): validated full config, run id and axis values."""
    jobs = []
    estimator = spec.estimator or spec.base["estimator"]["type"]
    for vals, seed in _cells(spec):
        over: dict[str, dict[str, Any]] = {"plant_sim": {"seed": seed}}
        for ax, v in zip(spec.axes, vals, strict=True):
            _merge(over, ax.overrides(spec.base, v))
        label = ", ".join(f"{a.name}={v}" for a, v in zip(spec.axes, vals, strict=True))
        cfg = apply_overrides(spec.base, over, f"study cell ({label})")
        for ctl in spec.controllers:
            jobs.append({
                "run_id": _run_id(cfg, ctl, estimator, spec.duration),
                "controller": ctl, "estimator": estimator, "seed": seed, "duration": spec.duration,
                "scenario": spec.scenario, "values": dict(zip((a.name for a in spec.axes), vals, strict=True)),
                "cfg": cfg,
            })
    return jobs


def run_chunk(jobs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Worker side: simulate each job, return its result fields (see :data:`RESULT_FIELDS`)."""
    from ..core.simulate import simulate

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
    from ..core.params import default_config
    from ..core.simulate import simulate

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
_SCHED_RE = re.compile(r"tcp://[A-Za-z0-9_.\-]+:\d{1,5}|tcp://\[[0-9a-fA-F:]+\]:\d{1,5}")


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


# ---------------------------------------------------------------------------
# robustness table and maps
# ---------------------------------------------------------------------------
def _f(x: str) -> float:
    return float(x) if x not in ("", None) else float("nan")


def _g(x: float) -> str:
    return "-" if x != x else f"{x:.3g}"


def _worst_rms(r: Mapping[str, str]) -> float:
    return max(_f(r["rms_e1_um"]), _f(r["rms_e2_um"]))


def robustness_rows(rows: Iterable[Mapping[str, str]], controllers: Sequence[str],
                    rms_limit: float) -> list[dict[str, Any]]:
    """Per controller: runs, survived, passed, worst / median RMS (um), worst max |e| (um), failing cells."""
    rows = list(rows)
    out = []
    for c in controllers:
        rs = [r for r in rows if r["controller"] == c]
        if not rs:
            continue
        surv = [r for r in rs if r["failed"] == "0"]
        passed = [r for r in surv if _worst_rms(r) < rms_limit]
        rms = np.array([_worst_rms(r) for r in surv]) if surv else np.array([])
        mx = max((max(_f(r["max_e1_um"]), _f(r["max_e2_um"])) for r in surv), default=float("nan"))
        out.append({"controller": c, "runs": len(rs), "survived": len(surv), "passed": len(passed),
                    "worst_rms_um": float(np.max(rms)) if rms.size else float("nan"),
                    "median_rms_um": float(np.median(rms)) if rms.size else float("nan"),
                    "worst_max_um": mx, "failures": [r for r in rs if r["failed"] != "0"]})
    return out


def robustness_table(out: Path, rms_limit: float | None = None, run_ids: set[str] | None = None) -> str:
    """Markdown robustness table of the study in ``out`` (study.json + results.csv).

    The rows counted are ``run_ids``, by default those of the last command run in ``out``
    (``study.json``; rows of earlier settings or code stay in results.csv but are not shown).
    """
    doc = json.loads((out / "study.json").read_text())
    limit = rms_limit if rms_limit is not None else doc.get("rms_limit_um", 100.0)
    rows = list(load_results(out / "results.csv").values())
    axes = [a["name"] for a in doc["axes"]]
    if run_ids is None and "run_ids" in doc:
        run_ids = set(doc["run_ids"])
    rows = [r for r in rows if all(a in r for a in axes) and (run_ids is None or r["run_id"] in run_ids)]
    lines = [
        f"| controller | runs | survived | pass (RMS < {limit:g} um) | worst RMS [um] | median RMS [um]"
        " | worst max [um] |",
        "|---|---|---|---|---|---|---|",
    ]
    fails = []
    for s in robustness_rows(rows, doc["controllers"], limit):
        lines.append(f"| `{s['controller']}` | {s['runs']} | {s['survived']} | {s['passed']} | "
                     f"{_g(s['worst_rms_um'])} | {_g(s['median_rms_um'])} | {_g(s['worst_max_um'])} |")
        for r in s["failures"][:8]:
            cell = ", ".join(f"{a} = {r[a]}" for a in axes)
            fails.append(f"- `{s['controller']}` fails at t = {_f(r['fail_time_s']):.2f} s in cell {cell}")
        if len(s["failures"]) > 8:
            fails.append(f"- `{s['controller']}`: {len(s['failures']) - 8} more failing cells in results.csv")
    def vals(v: list[Any]) -> str:
        return ", ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in v)

    ax_text = "; ".join(
        f"{a['name']} in {{{vals(a['values'])}}} {a['unit']}" if a["values"] is not None
        else f"{a['name']} ~ U[{vals(a['range'])}] {a['unit']}" for a in doc["axes"])
    head = (f"{doc['mode'].replace('_', ' ')} over {ax_text}; scenario {doc['scenario']}, "
            f"estimator {doc['estimator']}, "
            f"{doc['duration_s']:g} s runs, seed {doc['seed']}. Survived: the plate never left (0.1 mm, 30 mm).")
    return "\n".join([head, "", *lines, *(["", *fails] if fails else [])])


def report_section(study_dir: Path) -> list[str]:
    """Markdown lines of the report's robustness section, from the study in ``study_dir``.

    ``dem-ros report --out DIR`` reads ``DIR/study`` (written by
    ``dem-ros study --out DIR/study ...``; resumable, so regenerating both is cheap).
    """
    head = ["## Robustness over plant truth (`dem-ros study`)", ""]
    if not ((study_dir / "study.json").is_file() and (study_dir / "results.csv").is_file()):
        return [*head, f"No study in `{study_dir.name}/` beside this report. Run "
                       "`dem-ros study --preset acceptance --controllers adaptive,nonlinear_decoupling "
                       f"--out <report dir>/{study_dir.name}`, "
                       "then `dem-ros report` again.", ""]
    maps = sorted(study_dir.glob("map_*.png"))
    return [*head, robustness_table(study_dir), "",
            *(f"![robustness map, {m.stem[4:]}]({study_dir.name}/{m.name})\n" for m in maps)]


_DISPLAY = {"m": (1e3, "mm")}


def _label(name: str, unit: str) -> tuple[float, str]:
    k, u = _DISPLAY.get(unit, (1.0, unit))
    return k, f"{name} [{u}]" if u else name


def draw_maps(spec: StudySpec, out: Path, rms_limit: float, map_axes: Sequence[str] | None = None) -> list[Path]:
    """One robustness map per controller (PNG); see the module docstring."""
    import matplotlib

    from .plots import save

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    rows = load_results(out / "results.csv")
    wanted = {j["run_id"] for j in plan_runs(spec)}
    rows = {k: r for k, r in rows.items() if k in wanted}
    axes = list(spec.axes)
    if map_axes:
        pick = [next(a for a in axes if a.name == n) for n in map_axes]
    else:
        multi = [a for a in axes if a.values is None or len(a.values) > 1]
        pick = (multi or axes)[:2]
    files = []
    for ctl in spec.controllers:
        rs = [r for r in rows.values() if r["controller"] == ctl]
        if not rs:
            continue
        fig, ax = plt.subplots(figsize=(7.5, 5.5))
        kx, lx = _label(pick[0].name, pick[0].unit)
        n_fail = sum(r["failed"] != "0" for r in rs)
        rest = [a.name for a in axes if a not in pick]
        title = f"{ctl}: {len(rs)} runs, {n_fail} failed; pass = survived and RMS < {rms_limit:g} um"
        scatter = spec.samples is not None or any(a.values is None for a in pick)
        if scatter:
            x = np.array([_f(r[pick[0].name]) for r in rs]) * kx
            y = (np.array([_f(r[pick[1].name]) for r in rs]) * _label(pick[1].name, pick[1].unit)[0]
                 if len(pick) > 1 else np.array([_worst_rms(r) for r in rs]))
            ok = np.array([r["failed"] == "0" for r in rs])
            c = np.array([_worst_rms(r) for r in rs])
            if ok.any():
                sc = ax.scatter(x[ok], y[ok], c=np.clip(c[ok], 1e-3, None), norm=LogNorm(), cmap="viridis", s=18)
                fig.colorbar(sc, ax=ax, label="RMS error, worst output [um]")
            ax.scatter(x[~ok], y[~ok], marker="x", color="red", s=40, label="failed")
            ax.set_ylabel(_label(pick[1].name, pick[1].unit)[1] if len(pick) > 1 else "RMS error [um]")
            if (~ok).any():
                ax.legend(loc="best")
        else:
            xs = list(pick[0].values or ())
            ys = list(pick[1].values or ()) if len(pick) > 1 else [None]
            grid = np.full((len(ys), len(xs)), np.nan)
            nf = np.zeros((len(ys), len(xs)), int)
            nt = np.zeros((len(ys), len(xs)), int)
            xs_s = [str(v) for v in xs]
            ys_s = [str(v) for v in ys]
            for r in rs:
                ix = xs_s.index(r[pick[0].name])
                iy = ys_s.index(r[pick[1].name]) if len(pick) > 1 else 0
                nt[iy, ix] += 1
                if r["failed"] != "0":
                    nf[iy, ix] += 1
                else:
                    grid[iy, ix] = np.fmax(grid[iy, ix], _worst_rms(r))
            finite = grid[np.isfinite(grid)]
            vmin = max(float(finite.min()), 1e-3) if finite.size else 1e-3
            vmax = max(float(finite.max()), vmin * 10) if finite.size else 1.0
            im = ax.imshow(np.where(np.isfinite(grid), np.clip(grid, vmin, None), np.nan), origin="lower",
                           aspect="auto", cmap="viridis", norm=LogNorm(vmin=vmin, vmax=vmax))
            fig.colorbar(im, ax=ax,
                         label="RMS error, worst output and cell [um]" if rest else "RMS error, worst output [um]")
            for iy in range(len(ys)):
                for ix in range(len(xs)):
                    if nf[iy, ix]:
                        ax.add_patch(plt.Rectangle((ix - 0.5, iy - 0.5), 1, 1, color="red", alpha=0.85))
                        ax.text(ix, iy, f"FAIL\n{nf[iy, ix]}/{nt[iy, ix]}", ha="center", va="center", fontsize=7,
                                color="white")
                    elif nt[iy, ix] and len(xs) * len(ys) <= 400:
                        v = grid[iy, ix]
                        mark = "" if v < rms_limit else "\n> limit"
                        ax.text(ix, iy, f"{v:.3g}{mark}", ha="center", va="center", fontsize=7,
                                color="white" if v < math.sqrt(vmin * vmax) else "black")
            ax.set_xticks(range(len(xs)), [f"{v * kx:.4g}" if pick[0].type is not str else v for v in xs])
            if len(pick) > 1:
                ky, ly = _label(pick[1].name, pick[1].unit)
                ax.set_yticks(range(len(ys)), [f"{v * ky:.4g}" if pick[1].type is not str else v
                                               for v in pick[1].values or ()])
                ax.set_ylabel(ly)
            else:
                ax.set_yticks([])
        ax.set_xlabel(lx)
        if rest:
            title += f"\n{'one point per run; not drawn' if scatter else 'worst case over'}: {', '.join(rest)}"
        ax.set_title(title, fontsize=9)
        files.append(save(fig, out / f"map_{ctl}.png"))
    return files


# ---------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    """The ``dem-ros study`` options (values are checked in :func:`cmd_study`, one-line errors)."""
    p.add_argument("--axis", action="append", default=[], metavar="NAME=SPEC",
                   help="axis over plant truth: GROUP.NAME or hover_asymmetry, = LO:HI:N | LO:HI | V1,V2,...; "
                        "values may be relative: -20%%:+25%%:4 (repeatable)")
    presets = "; ".join(f"{k}: {' '.join(v)}" for k, v in PRESETS.items()).replace("%", "%%")
    p.add_argument("--preset", default=None, help=f"predefined axes ({presets})")
    p.add_argument("--controllers", default="adaptive", help="comma-separated control laws (default adaptive)")
    p.add_argument("--estimator", default=None, help="kf or none (default: config, kf)")
    p.add_argument("--scenario", default="S1", help="base scenario (default S1)")
    p.add_argument("--params", default=None, help="ROS 2 params file (the scenario and --set apply on top)")
    p.add_argument("--set", action="append", metavar="GROUP.NAME=VALUE", help="fixed override for every run")
    p.add_argument("--duration", default=None, help="seconds per run (default: the scenario's, 100)")
    p.add_argument("--samples", default=None, help="Monte Carlo: this many samples (default: the full grid)")
    p.add_argument("--seed", default=None, help="seed of noise and sampling (default: plant_sim.seed)")
    p.add_argument("--out", default="study", help="results directory (default ./study); re-running resumes")
    p.add_argument("--workers", default=None, help="local cluster: worker processes (default: cores)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="use this Dask scheduler instead of a local cluster")
    p.add_argument("--chunk", default=None, help="runs per Dask task (default: about 8 tasks per worker, at most 16)")
    p.add_argument("--rms-limit", default="100", help="pass criterion: RMS error < this (um, default 100)")
    p.add_argument("--map", default=None, metavar="X,Y",
                   help="axes drawn in the maps (default: the first two that vary)")
    p.add_argument("--timeout", default="30", help="seconds to reach the scheduler and its workers (default 30)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _num(text: str | None, what: str, kind: type, lo: float, hi: float | None = None) -> Any:
    try:
        v = kind(text)
    except (TypeError, ValueError):
        v = None
    if v is None or (isinstance(v, float) and not math.isfinite(v)) or v < lo or (hi is not None and v > hi):
        rng = f"[{lo:g}, {hi:g}]" if hi is not None else f">= {lo:g}"
        raise ConfigError(f"{what}: got {text!r}, expected {'an integer' if kind is int else 'a number'} {rng}")
    return v


def spec_from_args(args: argparse.Namespace) -> StudySpec:
    """Validate the command line into a :class:`StudySpec` (ConfigError with one line on bad input)."""
    base, sc = load_config(args.scenario, args.params, args.set or ())
    samples = None if args.samples is None else _num(args.samples, "--samples", int, 1, 10**7)
    if args.preset is not None and args.preset not in PRESETS:
        raise ConfigError(f"--preset: unknown {args.preset!r}; known: {', '.join(PRESETS)}")
    axes_text = list(PRESETS[args.preset]) if args.preset else []
    axes_text += args.axis
    if not axes_text:
        raise ConfigError("give at least one --axis NAME=SPEC or a --preset (e.g. --preset acceptance)")
    axes = tuple(parse_axis(t, base, samples is not None) for t in axes_text)
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise ConfigError(f"--axis: an axis is given twice ({', '.join(n for n in names if names.count(n) > 1)})")
    if samples is None:
        bad = [a.name for a in axes if a.values is None]
        assert not bad
    ctls = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
    if not ctls:
        raise ConfigError("--controllers: empty")
    for c in ctls:
        if c not in CONTROLLER_TYPES:
            raise ConfigError(f"--controllers: unknown {c!r}; known: {', '.join(CONTROLLER_TYPES)}")
    if args.estimator is not None and args.estimator not in ESTIMATOR_TYPES:
        raise ConfigError(f"--estimator: got {args.estimator!r}, expected one of {', '.join(ESTIMATOR_TYPES)}")
    duration = sc.duration if args.duration is None else _num(args.duration, "--duration", float, 1e-3, 1e6)
    seed = base["plant_sim"]["seed"] if args.seed is None else _num(args.seed, "--seed", int, 0, 2**31 - 1)
    return StudySpec(sc.name, base, axes, ctls, args.estimator, float(duration), int(seed), samples)


def cmd_study(args: argparse.Namespace) -> int:
    spec = spec_from_args(args)
    if args.scheduler is not None:
        if args.workers is not None:
            raise ConfigError("--workers applies to the local cluster; "
                              "with --scheduler the cluster's own workers run the study")
        if not _SCHED_RE.fullmatch(args.scheduler):
            raise ConfigError(f"--scheduler: got {args.scheduler!r}, expected tcp://HOST:PORT")
    workers = _num(args.workers, "--workers", int, 1, 1024) if args.workers is not None else (os.cpu_count() or 1)
    chunk = _num(args.chunk, "--chunk", int, 1, 10**6) if args.chunk is not None else None
    limit = _num(args.rms_limit, "--rms-limit", float, 0.0)
    timeout = _num(args.timeout, "--timeout", float, 0.1, 3600)
    map_axes = [s.strip() for s in args.map.split(",")] if args.map else None
    if map_axes:
        known = [a.name for a in spec.axes]
        for n in map_axes:
            if n not in known:
                raise ConfigError(f"--map: {n!r} is not an axis of this study; axes: {', '.join(known)}")
        if len(map_axes) > 2 or len(set(map_axes)) != len(map_axes):
            raise ConfigError("--map: give one or two different axes, X,Y")
    out = Path(args.out)
    jobs = plan_runs(spec)  # validates every cell before any process starts
    n_cells = len(jobs) // len(spec.controllers)
    print(f"dem-ros study: {spec.mode.replace('_', ' ')}, {n_cells} cells x {len(spec.controllers)} controllers = "
          f"{len(jobs)} runs of {spec.duration:g} s ({spec.scenario}, seed {spec.seed}) -> {out}")
    stats = run_study(spec, out, workers=workers, scheduler=args.scheduler, chunk=chunk,
                      progress=not args.quiet, timeout=timeout)
    doc = json.loads((out / "study.json").read_text())
    doc["rms_limit_um"] = limit
    (out / "study.json").write_text(json_text(doc))
    if stats["already_done"]:
        print(f"  {stats['already_done']} runs already in {out / 'results.csv'} (skipped)")
    if stats["ran"]:
        print(f"  {stats['ran']} runs on {stats['workers']} workers in {stats['elapsed_s']:.1f} s: "
              f"{stats['runs_per_s']:.2f} runs/s of {spec.duration:g} s each "
              f"(cluster start-up and kernel load {stats['startup_s']:.1f} s; load average "
              + " ".join(f"{x:.2f}" for x in stats["load_average"]) + ")")
    files = draw_maps(spec, out, limit, map_axes)
    table = robustness_table(out, limit, {j["run_id"] for j in jobs})
    (out / "summary.md").write_text("# Robustness study\n\n" + table + "\n\n"
                                    + "\n".join(f"![{f.stem}]({f.name})" for f in files) + "\n")
    print(table)
    print(f"  results: {out / 'results.csv'}; maps: {', '.join(f.name for f in files)}; summary: {out / 'summary.md'}")
    return 0
