"""The ``dem-ros study`` command: its options, their checks, then spec, run and report in turn."""

from __future__ import annotations

import argparse
import json
import os
import re
from pathlib import Path

from ...core.params import ConfigError
from ..common import json_text
from .report import draw_maps, robustness_table
from .run import run_study
from .spec import PRESETS, _num, plan_runs, spec_from_args

__all__ = ["add_arguments", "cmd_study"]

_SCHED_RE = re.compile(r"tcp://[A-Za-z0-9_.\-]+:\d{1,5}|tcp://\[[0-9a-fA-F:]+\]:\d{1,5}")


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
