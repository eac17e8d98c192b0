"""``dem-ros faults`` itself: one row's run (launch the graph with the injector, judge the bag), the command's
arguments, the table and the JSON."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ... import contract
from ..common import UsageError, write_json
from .catalogue import CATALOGUE, RIG_CATALOGUE
from .inject import INJECTOR_NODE, Injector, _kill_hook, _n_times
from .judge import (
    _counted,
    _judge,
    _judge_hw,
    _lost,
    _outage_s,
    _plant_end,
    _rig_statuses,
    _routine_warn,
    rosout_heard,
    run_events,
)
from .spec import FaultSpec

if TYPE_CHECKING:
    from ..launcher import LaunchOptions

__all__ = ["HW_SETS", "Row", "add_arguments", "cmd_faults", "run_row"]

@dataclass
class Row:
    """One measured row (see the module docstring)."""

    fault: str
    processes: str
    outcome: str
    min_gap_mm: float | None
    max_error_um: float | None
    reported: str
    data_lost: str
    passed: bool
    detail: str = ""
    diagnostics: list[str] = field(default_factory=list)
    counted: str = ""  # hardware rows: the driver's, board's (or estimator's) counters of the fault
    counts: dict[str, float] = field(default_factory=dict)  # the same, by "driver corrupt", "emulator corrupt" ...
    descent_mm_s: float | None = None  # hardware rows: the plate's fastest true descent while the board landed it
    verdict: str = ""  # the run's own verdict (dem_ros.tools.verdict): a landing the row allows is a failed run


def _launch_args(scenario: str, duration: float, compose: bool, free_run: bool, bag_dir: Path, domain_id: int,
                 sets: list[str], hardware: str | None = None, apart: Sequence[str] = ()) -> LaunchOptions:
    from ..launcher import LaunchOptions

    return LaunchOptions(scenario=scenario, duration=duration, bag_dir=str(bag_dir), domain_id=domain_id,
                         transport="dds", compose=compose, free_run=free_run, hardware=hardware, set=list(sets),
                         apart=list(apart))


def _apart(spec: FaultSpec) -> tuple[str, ...]:
    """The rig rows' killed node runs in a process of its own beside the container (``--apart``), the rest
    composed: the rig does not hold with a process per node on a 2-core host (docs/manual/faults.md)."""
    return (spec.kill,) if spec.hardware and spec.kill is not None else ()


def _how(spec: FaultSpec, compose: bool) -> str:
    """The row's processes as the table and the progress lines say them."""
    apart = _apart(spec)
    return f"composed, {', '.join(apart)} apart" if apart else "composed" if compose else "per process"


def run_row(spec: FaultSpec, *, compose: bool, scenario: str, duration: float, at: float, free_run: bool,
            workdir: Path, domain_id: int, sets: list[str]) -> Row:
    """Launch the graph, inject ``spec`` at ``at`` s, judge the bag (a disk row: on a small tmpfs)."""
    how = _how(spec, compose)
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    workdir.mkdir(parents=True, exist_ok=True)
    if spec.hardware:
        return _run_hw_row(spec, how, compose=compose, scenario=scenario, duration=duration, at=at, workdir=workdir,
                           domain_id=domain_id, sets=sets)
    disk = workdir / "disk" if spec.disk_kib else None
    if disk is not None:
        disk.mkdir(exist_ok=True)
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={spec.disk_kib}k", "tmpfs", str(disk)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            return Row(spec.name, how, "not run", None, None, "", "", False,
                       f"cannot mount a {spec.disk_kib} KiB tmpfs (needs root): {r.stderr.strip()}")
    try:
        return _run_row(spec, how, compose=compose, scenario=scenario, duration=duration, at=at, free_run=free_run,
                        workdir=workdir, disk=disk, domain_id=domain_id, sets=sets)
    finally:
        if disk is not None:
            subprocess.run(["umount", "-l", str(disk)], check=False)


def _launch_injected(args: LaunchOptions, spec: FaultSpec, inj: Injector,
                     logs_dir: Path | None = None) -> dict[str, Any] | str:
    """``dem-ros launch`` with the injector running and the row's kill hook: the launch facts (with the run's
    verdict), or why the run did not start or was cut short (the injector is closed either way)."""
    from ...bag import BagError
    from ..launcher import GraphError, launch

    hook = _kill_hook(spec, inj) if spec.kill else None
    try:
        metrics, info = launch(args, quiet=True, supervise=hook, logs_dir=logs_dir)
        if info.get("cut_short"):
            return f"run cut short: {info['cut_short']}"
        return info | {"verdict": metrics.verdict, "verdict_reasons": metrics.verdict_reasons}
    except GraphError as exc:
        return f"run cut short: {exc}"
    except BagError as exc:  # the run ended, but its summary could not read the bag: judge it here
        return {"recorder": None, "summary_error": str(exc)}
    finally:
        inj.close()


def _run_row(spec: FaultSpec, how: str, *, compose: bool, scenario: str, duration: float, at: float, free_run: bool,
             workdir: Path, disk: Path | None, domain_id: int, sets: list[str]) -> Row:
    args = _launch_args(scenario, duration, compose, free_run, disk or workdir, domain_id, sets)
    inj = Injector(_n_times(spec.n, spec.act) if spec.act is not None else None, at)
    logdir = workdir / "logs" if disk is not None else None
    info = _launch_injected(args, spec, inj, logdir)
    if isinstance(info, str):
        return Row(spec.name, how, "failed", None, None, "", "", False, info)
    root = disk or workdir
    bags = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.endswith("_logs"))
    bag = Path(info["bag"]) if info.get("bag") else bags[-1]
    from ..launcher import _config_from_args

    cfg, _, _ = _config_from_args(args)
    j = _judge(bag, 0.0 if disk is not None else at, cfg)  # a disk fills when it fills: every report counts
    logdir = logdir or bag.parent / (bag.name + "_logs")
    info["events"] = run_events(info, logdir)
    end = _plant_end(info)
    if disk is not None and j["outcome"] == "levitating" and not end.startswith("finished"):
        # the bag stops where the disk filled: the plant's own last word says how the run ended
        j["outcome"] = "landed safely" if end.startswith("landed") else "failed"
        j["detail"] = f"the plant: {end or 'no last word from it'}"
    # the nodes' log records from 1 s before the fault (as the statuses): the bag's, and those heard live it lacks
    logged, log_said = rosout_heard(j["rosout"], inj.rosout, j["fault_ns"] - 10**9, exclude=(INJECTOR_NODE,))
    exits = info.get("exits") or []  # node processes the launcher saw die (reported on its stderr at once)
    # heard live but not in the bag (a full disk stops the recording before the recorder's own ERROR)
    live = [d for d in inj.live_levels((0.0 if disk is not None else at) - 1.0) if d not in j["diagnostics"]]
    j["diagnostics"] += [f"{d} (live)" for d in live]
    reported = ", ".join(j["diagnostics"]) or "no diagnostics"
    reported += "; rosout: " + log_said
    if exits:
        reported += "; launch: " + ", ".join(f"{e['node']} exited ({e['code']})" for e in exits)
    rec = info.get("recorder") or {}
    lost = _lost(info, j["problems"])
    if spec.kill == "recorder" and not rec:
        lost.append("recorder counters lost with the process")
    for e in exits:  # the launcher saw a node die: the recorder's death costs the rest of the recording
        if e["node"] == "recorder" and "recorded_s" in j:
            lost.insert(0, f"recording lost from t = {j['recorded_s']:.3f} s (recorder killed)")
    data_lost = "; ".join(lost) or "none"
    # the plant's loop status is at WARN whenever it waited for a command or held (lockstep on a loaded
    # machine: most runs), and so is a topic's status whose rate fell 10 % short over its window; they count as
    # a report of the fault only at ERROR (a landing, a failure; a topic silent for a whole window)
    told = [d for d in j["diagnostics"] if not _routine_warn(d)]
    ok = j["outcome"] in spec.allowed and (bool(told) or bool(logged))
    sent = [f"{v} {k}" for k, v in inj.counts.items()]
    if spec.kill and spec.restart_after is not None:  # what the outage was, against the board's hold
        down = _outage_s(info, spec.kill, inj.killed_ns)
        hold = (f"lockstep_timeout {cfg['plant_sim']['lockstep_timeout']:g} s" if cfg["plant_sim"]["lockstep"]
                else f"hold_timeout {cfg['plant_sim']['hold_timeout'] * 1e3:g} ms")
        sent.append(f"down {down:.1f} s (SIGKILL to the restarted node's 'ready'; {hold})" if down is not None
                    else f"the restarted node was not ready again before the run ended ({hold})")
    detail = "; ".join([*inj.events, *sent, j.get("detail", "")]).strip("; ")
    return Row(spec.name, how, j["outcome"], j["min_gap_mm"], j.get("max_error_um"), reported, data_lost, ok, detail,
               j["diagnostics"], verdict=_verdict_text(info))


HW_SETS = ("controller.command_delay=2",)  # docs/results.md's hardware runs: a loaded host keeps the loop in time


def _run_hw_row(spec: FaultSpec, how: str, *, compose: bool, scenario: str, duration: float, at: float,
                workdir: Path, domain_id: int, sets: list[str]) -> Row:
    """``dem-ros launch --hardware rig``: the rig fault (board time: ``at`` + the driver's pre-roll after the
    release, i.e. t = ``at`` of the experiment within a sample), an injection or a kill at t = ``at``; judged
    from the bag (statuses and /rosout records), what the injector heard live and the emulator's own figures
    (its run-state statuses and summary, as the launcher kept them)."""
    from ..launcher import _config_from_args

    apart = _apart(spec)
    compose = compose or bool(apart)
    args = _launch_args(scenario, duration, compose, False, workdir, domain_id, [*HW_SETS, *sets], hardware="rig",
                        apart=apart)
    cfg, _, _ = _config_from_args(args)
    if spec.rig_fault:
        args.fault = [spec.rig_fault.format(t=f"{at + cfg['hw_driver']['preroll']:g}")]
    inj = Injector(_n_times(spec.n, spec.act) if spec.act is not None else None, at, extra=(contract.HW_ESTOP,))
    info = _launch_injected(args, spec, inj)
    if isinstance(info, str):
        return Row(spec.name, how, "failed", None, None, "", "", False, info)
    bags = sorted(p for p in workdir.iterdir() if p.is_dir() and not p.name.endswith("_logs"))
    if not info.get("bag") and not bags:
        return Row(spec.name, how, "failed", None, None, "", "", False, "no bag was recorded")
    bag = Path(info["bag"]) if info.get("bag") else bags[-1]
    logdir = bag.parent / (bag.name + "_logs")
    rig = info.get("rig")  # the emulator's summary, as the launcher read it
    statuses = _rig_statuses(run_events(info, logdir))
    j = _judge_hw(bag, at, cfg, spec, rig, statuses)
    logged, log_said = rosout_heard(j["rosout"], inj.rosout, j["fault_ns"], exclude=(INJECTOR_NODE,))
    said = [*j["messages"], *((f"{r.name} rosout", r.msg) for r in logged)]
    heard = [who for who, text in said if any(k.lower() in text.lower() for k in spec.reports)]
    exits = info.get("exits") or []
    reported = ", ".join(j["diagnostics"]) or "no diagnostics"
    reported += "; rosout: " + log_said
    if exits:
        reported += "; launch: " + ", ".join(f"{e['node']} exited ({e['code']})" for e in exits)
    reported += f"; '{spec.reports[0]}' " + (f"in {', '.join(sorted(set(heard)))}" if heard else "NOT reported")
    sources = {"driver": j.get("loop", {}), "board": {**(rig or {}), **((rig or {}).get("supervisor") or {})},
               "estimator": j["statuses"].get(contract.ESTIMATOR_STATUS, {})}
    counted_ok, counted, counts = _counted(spec, sources)
    hits = [f"{f['kind']} acted on {f['hits']} samples" for f in (rig or {}).get("faults", [])]
    if hits:
        counted += "; emulator: " + ", ".join(hits)
    for f in (rig or {}).get("faults", []):
        counts[f"emulator {f['kind']}"] = float(f["hits"])
    lost = _lost(info, j["problems"])
    early = j.get("early", "")
    ok = j["outcome"] in spec.allowed and bool(heard) and counted_ok and not early
    sent = [f"{v} {k}" for k, v in inj.counts.items()]
    if spec.act is not None:
        sent.insert(0, f"{inj.injected} sent from t = {at:g} s")
    detail = "; ".join(x for x in [early, *inj.events, *sent, j.get("detail", "")] if x)
    return Row(spec.name, how, j["outcome"], j["min_gap_mm"], j.get("max_error_um"), reported,
               "; ".join(lost) or "none", ok, detail, j["diagnostics"], counted, counts,
               (rig or {}).get("land_speed_max_mm_s"), _verdict_text(info))


def _verdict_text(info: dict[str, Any]) -> str:
    """The run's verdict in a row: ``failed: landed before the planned end ...`` ("" when launch gave none)."""
    v = info.get("verdict", "")
    reasons = info.get("verdict_reasons") or []
    return v + (f": {'; '.join(reasons)}" if reasons and v else "")


# -- the command -------------------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", action="append", default=[], metavar="NAME",
                   help="run only these rows (repeatable): " + ", ".join(f.name for f in CATALOGUE)
                   + "; with --hardware rig: " + ", ".join(f.name for f in RIG_CATALOGUE))
    p.add_argument("--hardware", choices=("rig",), default=None,
                   help="'rig': the hardware rows instead, hw_driver and the emulated board (dem-ros launch --hardware "
                        "rig, UDP on loopback, controller.command_delay=2; rig faults, an e-stop, a killed controller)")
    p.add_argument("--processes", choices=("per-process", "composed", "both"), default=None,
                   help="the graph as a process per node, composed in one process, or both (default: both; with "
                        "--hardware rig each row once, composed; a killed controller in a process of its own "
                        "beside the container)")
    p.add_argument("--scenario", default="S1")
    p.add_argument("--duration", type=float, default=4.0, help="seconds of each run (default 4)")
    p.add_argument("--at", type=float, default=1.5, help="inject at this experiment time [s] (default 1.5)")
    p.add_argument("--free-run", action="store_true", help="free-running plant (hardware-like timing)")
    p.add_argument("--set", action="append", default=[], metavar="GROUP.NAME=VALUE", help="parameter override")
    p.add_argument("--bag-dir", default=None, help="keep the runs' bags here (default: a temporary directory)")
    p.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID of the runs (default: from the pid)")
    p.add_argument("--json", default=None, help="write the rows as JSON")


def _table(rows: list[Row]) -> str:
    hw = any(r.counted for r in rows)  # hardware rows: who counted the fault
    head = ("fault", "processes", "outcome", "min gap [mm]", "max error [um]", "reported",
            *(("counted",) if hw else ()), "data lost", "pass")
    body = [(r.fault, r.processes, r.outcome + (f" ({r.detail})" if r.detail else ""),
             "-" if r.min_gap_mm is None else f"{r.min_gap_mm:.3f}",
             "-" if r.max_error_um is None else f"{r.max_error_um:.1f}", r.reported, *((r.counted,) if hw else ()),
             r.data_lost, "yes" if r.passed else "NO") for r in rows]
    w = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
    lines = ["| " + " | ".join(h.ljust(w[i]) for i, h in enumerate(head)) + " |",
             "|" + "|".join("-" * (x + 2) for x in w) + "|"]
    lines += ["| " + " | ".join(c.ljust(w[i]) for i, c in enumerate(b)) + " |" for b in body]
    return "\n".join(lines)


def _write(args: argparse.Namespace, rows: list[Row]) -> None:
    write_json(args.json, {"rows": [asdict(r) for r in rows], "scenario": args.scenario, "at_s": args.at,
                           "duration_s": args.duration, "free_run": args.free_run, "hardware": args.hardware,
                           "sets": ([*HW_SETS] if args.hardware else []) + list(args.set)})


def _plan(specs: list[FaultSpec], processes: str | None, hardware: bool) -> list[tuple[FaultSpec, bool]]:
    """(row, composed) in the order they run: every row per process, then composed (--processes both); the
    rig's default runs each row once, composed unless it kills a node (its own process)."""
    if hardware and processes is None:
        return [(f, f.composed) for f in specs]
    modes = {"per-process": (False,), "composed": (True,), "both": (False, True)}[processes or "both"]
    return [(f, compose) for compose in modes for f in specs if f.composed or not compose]


def cmd_faults(args: argparse.Namespace) -> int:
    catalogue = RIG_CATALOGUE if args.hardware else CATALOGUE
    names = {f.name for f in catalogue}
    bad = [n for n in args.only if n not in names]
    if bad:
        raise UsageError(f"--only: unknown row(s) {', '.join(bad)}; "
                         f"rows{' (--hardware rig)' if args.hardware else ''}: "
                         f"{', '.join(sorted(names))}")
    specs = [f for f in catalogue if not args.only or f.name in args.only]
    work = Path(args.bag_dir) if args.bag_dir else Path(tempfile.mkdtemp(prefix="dem_ros_faults_"))
    domain = args.domain_id if args.domain_id is not None else 1 + os.getpid() % 100
    rows: list[Row] = []
    for spec, compose in _plan(specs, args.processes, bool(args.hardware)):
        print(f"dem-ros faults: {spec.name} ({_how(spec, compose)}): {spec.description}", file=sys.stderr, flush=True)
        row = run_row(spec, compose=compose, scenario=args.scenario, duration=max(args.duration, spec.min_duration),
                      at=args.at, free_run=args.free_run,
                      workdir=work / spec.name / ("composed" if compose else "processes"), domain_id=domain,
                      sets=args.set)
        print(f"  -> {row.outcome}, min gap {row.min_gap_mm} mm, {'pass' if row.passed else 'FAIL'}",
              file=sys.stderr, flush=True)
        rows.append(row)
        if args.json:  # after every row: a long catalogue run keeps what it measured
            _write(args, rows)
    print(_table(rows))
    failed = [r.fault for r in rows if not r.passed]
    if failed:
        print(f"dem-ros faults: {len(failed)} of {len(rows)} row(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0
