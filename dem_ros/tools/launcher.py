"""``dem-ros launch``: the node graph without ROS tooling, each node its own process.

Writes the run's full configuration as a ROS 2 params file, starts recorder,
reference, estimator, controller and plant_sim (last, so it starts its clock
once the others have matched), shows the plant's status line live, stops every
process cleanly at the end or on Ctrl-C / SIGTERM (recorder last, so the bag
is complete), and prints a summary read back from the bag: tracking metrics
(e = true gap - y_m, matched by stamp), loop statistics and CPU per node.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..core.metrics import error_metrics
from ..core.params import SCHEMA

__all__ = ["bench_loop", "bench_record", "cmd_launch", "cmd_node", "cmd_param", "graph_summary", "run_graph"]

NODES = ("recorder", "reference", "estimator", "controller", "plant_sim")


class GraphError(RuntimeError):
    """The graph could not be started or run; the message says which node and where its log is."""


def _yaml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, float):
        t = repr(v)
        return t if ("." in t.split("e")[0] or "inf" in t or "nan" in t) else t.replace("e", ".0e", 1)
    return str(v)


def write_params_file(cfg: dict, path: Path) -> Path:
    lines = ["# full configuration of one dem-ros launch run (ROS 2 params file)"]
    for group in SCHEMA.groups:
        lines += [f"{group}:", "  ros__parameters:"]
        lines += [f"    {k}: {_yaml(v)}" for k, v in cfg[group].items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _wait_ready(logs: dict, procs: dict, timeout: float) -> None:
    """Block until every log says 'ready' (kernels loaded, subscriptions made)."""
    end = time.monotonic() + timeout
    pending = dict(logs)
    while pending and time.monotonic() < end:
        for n, path in list(pending.items()):
            if procs[n].poll() is not None:
                raise GraphError(f"node {n} exited during start-up (code {procs[n].returncode}); see {path}")
            try:
                if "ready" in path.read_text(errors="replace"):
                    del pending[n]
            except OSError:
                pass
        time.sleep(0.05)
    if pending:
        raise GraphError(f"nodes not ready after {timeout:.0f} s: {', '.join(pending)}")


def _cpu_seconds(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _node_cmd(name: str, transport: str, params: Path, extra: list[str]) -> list[str]:
    return [sys.executable, "-m", "dem_ros.tools.node_main", name, "--transport", transport, *extra,
            "--ros-args", "--params-file", str(params)]


def run_graph(cfg: dict, *, duration: float, transport: str, bag: Path | None, meta: dict,
              domain_id: int | None = None, status: bool = True, workdir: Path | None = None,
              compose: bool = False) -> dict:
    """Start the graph, wait for the plant to finish ``duration`` s, stop everything; return raw facts.

    ``compose``: all nodes in one ``container`` process (intra-process topics)
    instead of one process per node.
    """
    workdir = workdir or Path(tempfile.mkdtemp(prefix="dem_ros_launch_"))
    workdir.mkdir(parents=True, exist_ok=True)
    cfg = {g: dict(v) for g, v in cfg.items()}
    cfg["plant_sim"]["duration"] = float(duration)
    params = write_params_file(cfg, workdir / "params.yaml")
    env = dict(os.environ)
    if domain_id is None:
        domain_id = int(env.get("ROS_DOMAIN_ID", random.randint(1, 100)))
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env["PYTHONUNBUFFERED"] = "1"
    meta_file = workdir / "run_info.json"
    meta_file.write_text(json.dumps(meta))
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    started = {}
    cpu: dict[str, float] = {}
    interrupted = False
    cpu_start: dict[str, float] | None = None  # CPU seconds of each process when t = 0 was reached

    def on_signal(signum, frame):
        nonlocal interrupted
        interrupted = True

    old = {}
    if threading.current_thread() is threading.main_thread():  # Ctrl-C / SIGTERM stop the graph cleanly
        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    lead = "container" if compose else "plant_sim"  # its exit ends the run; its stdout has the status lines
    names = ["container"] if compose else [n for n in NODES if n != "recorder" or bag is not None]
    t0 = time.monotonic()
    try:
        for name in names:
            bag_args = ["--bag", str(bag), "--meta", str(meta_file)] if bag is not None else []
            extra = bag_args if name in ("recorder", "container") else []
            logs[name] = workdir / f"{name}.log"
            out = subprocess.PIPE if name == lead else open(logs[name], "wb")
            procs[name] = subprocess.Popen(_node_cmd(name, transport, params, extra), env=env, stdout=out,
                                           stderr=subprocess.STDOUT, start_new_session=True,
                                           text=(name == lead))
            started[name] = time.monotonic()
            if name == "controller":  # every other node is up: wait for their "ready"
                _wait_ready({n: logs[n] for n in procs if n != "plant_sim"}, procs, timeout=120.0)
        plant = procs[lead]
        plant_log = open(logs[lead], "w")
        limit = time.monotonic() + 60.0 + 10.0 * (duration + cfg["plant_sim"]["preroll"])  # lockstep may run below real time
        os.set_blocking(plant.stdout.fileno(), False)
        buf = ""
        while plant.poll() is None and not interrupted and time.monotonic() < limit:
            for name, p in procs.items():
                if name != lead and p.poll() is not None:
                    raise GraphError(f"node {name} exited early with code {p.returncode}; see {logs[name]}")
            time.sleep(0.1)
            try:
                chunk = plant.stdout.read()
            except (BlockingIOError, TypeError):
                chunk = None
            if chunk:
                plant_log.write(chunk)
                plant_log.flush()  # users (and tests) follow the run in the log
                buf += chunk
                lines = buf.split("\n")
                buf = lines[-1]
                for line in lines[:-1]:
                    if line.startswith("t =") and cpu_start is None:  # the run (t >= 0) has begun
                        cpu_start = {n: _cpu_seconds(p.pid) for n, p in procs.items()}
                        started = {n: time.monotonic() for n in procs}
                    if status and line.startswith("t ="):
                        print("\r  " + line.strip(), end="", file=sys.stderr, flush=True)
        if status:
            print(file=sys.stderr)
        rest = plant.stdout.read() if plant.poll() is not None else None
        if rest:
            plant_log.write(rest)
        plant_log.close()
    finally:
        wall = time.monotonic() - t0
        for name, p in procs.items():
            cpu[name] = _cpu_seconds(p.pid)
        # stop: plant (if still running) and controllers first, recorder last
        for name in ("container", "plant_sim", "controller", "estimator", "reference", "recorder"):
            p = procs.get(name)
            if p is None or p.poll() is not None:
                continue
            if name == "recorder":
                time.sleep(0.3)  # last samples in flight
            p.send_signal(signal.SIGINT)
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for s, h in old.items():
            signal.signal(s, h)
    elapsed = {n: (time.monotonic() - started[n]) for n in procs}
    base = cpu_start or {}
    cpu = {n: c - base.get(n, 0.0) for n, c in cpu.items()}
    cpu_pct = {n: round(100.0 * cpu[n] / max(elapsed[n], 1e-9), 1) for n in procs if cpu[n] == cpu[n]}
    recorder_counts = None
    rec_log = logs.get("container" if compose else "recorder")
    if bag is not None and rec_log is not None and rec_log.exists():
        for line in rec_log.read_text(errors="replace").splitlines():
            if line.startswith("RECORDER "):
                recorder_counts = json.loads(line[len("RECORDER "):])
    return {"interrupted": interrupted, "wall_s": wall, "cpu_percent": cpu_pct, "returncodes": {n: p.returncode for n, p in procs.items()},
            "logs": {n: str(p) for n, p in logs.items()}, "recorder": recorder_counts, "domain_id": domain_id, "workdir": str(workdir)}


def graph_summary(bag: Path) -> dict:
    """Tracking metrics and loop statistics of a recorded graph run (from the bag alone)."""
    from ..bag import BagReader

    r = BagReader(bag)
    loop = None
    for topic, _, msg in r.messages(["/diagnostics"]):
        for st in msg.status:
            if st.name == "plant_sim: loop":
                loop = {kv.key: kv.value for kv in st.values}
                loop["message"] = st.message
    epoch = int(loop["epoch_ns"]) if loop and "epoch_ns" in loop else None
    truth = r.joint_state_arrays("/dem/plant/truth")
    ref = r.joint_state_arrays("/dem/reference")
    ts, i_t, i_r = np.intersect1d(truth["stamp_ns"], ref["stamp_ns"], return_indices=True)
    if epoch is not None:  # the experiment, not the pre-roll
        keep = ts >= epoch
        ts, i_t, i_r = ts[keep], i_t[keep], i_r[keep]
    out: dict[str, Any] = {}
    if ts.size:
        t = (ts - ts[0]) * 1e-9
        e = truth["position"][i_t, :2] - ref["position"][i_r, :2]
        out.update(error_metrics(t, e))
        out["samples"] = int(ts.size)
    out["plant_diagnostics"] = loop
    est = r.joint_state_arrays("/dem/controller/state") if "/dem/controller/state" in r.topics else None
    if est is not None and est["position"].shape[0]:
        last = est["position"][-1]
        names = list(est["name"]) if est.get("name") is not None else []
        vals = dict(zip(names, last)) if names else {}
        if all(np.isfinite([vals.get("m_hat", np.nan), vals.get("R_hat", np.nan), vals.get("K_hat", np.nan)])):
            out["final_estimates"] = {"m_kg": float(vals["m_hat"]), "R_ohm": float(vals["R_hat"]), "K": float(vals["K_hat"])}
        else:
            out["final_estimates"] = None
    out["topics"] = {n: i.count for n, i in r.topics.items()}
    return out


def _config_from_args(args) -> tuple[dict, Any, float]:
    from .cli import _load_config

    cfg, sc = _load_config(args)
    if args.controller:
        cfg["controller"]["type"] = args.controller
    if args.estimator:
        cfg["estimator"]["type"] = args.estimator
    duration = args.duration if args.duration is not None else sc.duration
    return cfg, sc, duration


def launch(args, *, quiet: bool = False) -> dict:
    from ..core.simulate import simulate

    cfg, sc, duration = _config_from_args(args)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    bag_root = Path(args.bag_dir)
    bag_root.mkdir(parents=True, exist_ok=True)
    record = not args.no_record
    tmp = None
    if record:
        bag = bag_root / f"{stamp}_{sc.name}_{cfg['controller']['type']}"
    else:
        tmp = Path(tempfile.mkdtemp(prefix="dem_ros_bag_"))
        bag = tmp / "run"
    meta = {"scenario": sc.name, "scenario_description": sc.description, "controller": cfg["controller"]["type"],
            "estimator": cfg["estimator"]["type"], "transport": args.transport, "duration_s": duration,
            "dem_ros_version": __version__, "config": cfg, "started": datetime.now().isoformat(timespec="seconds")}
    if not quiet:
        print(f"dem-ros launch: {sc.name} ({sc.description}), controller {meta['controller']}, estimator {meta['estimator']},"
              f" {duration:g} s, transport {args.transport}", file=sys.stderr)
    compose = bool(getattr(args, "compose", False))
    meta["composed"] = compose
    facts = run_graph(cfg, duration=duration, transport=args.transport, bag=bag, meta=meta, domain_id=args.domain_id,
                      status=not quiet, workdir=(bag.parent / (bag.name + "_logs")) if record else None,
                      compose=compose)
    summary = graph_summary(bag)
    loop = summary.get("plant_diagnostics") or {}
    failed = str(loop.get("failed", "False")) == "True"
    offline = simulate(cfg, controller=cfg["controller"]["type"], estimator=cfg["estimator"]["type"], duration=duration,
                       scenario=sc.name).metrics()
    result = {
        "scenario": sc.name, "controller": meta["controller"], "estimator": meta["estimator"], "transport": args.transport,
        "composed": compose,
        "failed": failed, "fail_time_s": float(loop.get("t_sim_s", "nan")) if failed else None,
        "rms_error_um": summary.get("rms_error_um"), "max_error_um": summary.get("max_error_um"),
        "rms_error_after_40s_um": summary.get("rms_error_after_40s_um"),
        "peak_voltage_v": None, "final_estimates": summary.get("final_estimates"), "wall_time_s": facts["wall_s"],
        "offline_rms_error_um": offline["rms_error_um"],
        "loop": {
            "cycles": int(loop.get("cycles", 0)), "deadline_misses": int(loop.get("deadline_misses", 0)),
            "latency_us": {"p50": float(loop.get("latency_p50_us", "nan")), "p99": float(loop.get("latency_p99_us", "nan")),
                           "max": float(loop.get("latency_max_us", "nan"))},
            "cpu_percent": _with_plant_cpu(facts["cpu_percent"], loop, "container" if compose else "plant_sim"),
            "realtime_factor": float(loop.get("realtime_factor", "nan")),
            "lockstep": loop.get("lockstep") == "True",
        },
        "bag": str(bag) if record else None,
        "recorder": facts["recorder"],
        "interrupted": facts["interrupted"],
    }
    result["peak_voltage_v"] = _peak_voltage(bag)
    if record and bag.is_dir():  # the run-time summary travels with the bag (replay compares against it)
        (bag / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    if tmp is not None:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
    return result


def _with_plant_cpu(cpu: dict, loop: dict, process: str = "plant_sim") -> dict:
    """The plant's process exits before the launcher can read its CPU time: the plant reports it."""
    out = dict(cpu)
    try:
        out[process] = round(100.0 * float(loop["cpu_s"]) / float(loop["wall_s"]), 1)
    except (KeyError, ValueError, ZeroDivisionError):
        pass
    return out


def _peak_voltage(bag: Path) -> float | None:
    from ..bag import BagReader

    try:
        a = BagReader(bag).joint_state_arrays("/dem/command")
        return float(np.nanmax(np.abs(a["effort"]))) if a["effort"].size else None
    except Exception:
        return None


def print_summary(res: dict) -> None:
    from .cli import _fmt_pair

    L = res["loop"]
    how = "one process (composed)" if res.get("composed") else "a process per node"
    print(f"  scenario / controller / estimator   {res['scenario']} / {res['controller']} / {res['estimator']} ({res['transport']}, {how})")
    print(f"  failed                              {'yes, at t = %.3f s' % res['fail_time_s'] if res['failed'] else 'no'}")
    if res["rms_error_um"]:
        print(f"  RMS error e1 / e2 [um]              {_fmt_pair(res['rms_error_um'])}   (offline, same timing: {_fmt_pair(res['offline_rms_error_um'])})")
        print(f"  max error e1 / e2 [um]              {_fmt_pair(res['max_error_um'])}")
        print(f"  RMS error after 40 s [um]           {_fmt_pair(res['rms_error_after_40s_um'])}")
    if res.get("final_estimates"):
        fe = res["final_estimates"]
        print(f"  final m_hat / R_hat / K_hat         {fe['m_kg']:.3f} kg / {fe['R_ohm']:.4f} ohm / {fe['K']:.4e}")
    print(f"  loop: cycles {L['cycles']}, deadline misses {L['deadline_misses']}"
          f" ({100.0 * L['deadline_misses'] / max(L['cycles'], 1):.3f} %), latency p50 {L['latency_us']['p50']:.0f} us,"
          f" p99 {L['latency_us']['p99']:.0f} us, max {L['latency_us']['max']:.0f} us;"
          f" x{L.get('realtime_factor', float('nan')):.2f} real time{' (lockstep)' if L.get('lockstep') else ''}")
    print("  CPU [% of one core]                 " + ", ".join(f"{k} {v:.1f}" for k, v in L["cpu_percent"].items())
          + f"; total {sum(L['cpu_percent'].values()):.1f}")
    if res.get("recorder"):
        rc = res["recorder"]
        dropped = sum(v["dropped"] for v in rc.values())
        written = sum(v["written"] for v in rc.values())
        print(f"  recorded                            {written} messages, {dropped} dropped")
    if res.get("bag"):
        print(f"  bag                                 {res['bag']}")


def cmd_launch(args) -> int:
    res = launch(args)
    print_summary(res)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
        print(f"  summary written to {args.json}")
    return 130 if res["interrupted"] else (1 if res["failed"] else 0)


def cmd_node(args) -> int:
    from .node_main import run

    return run(args.name, args.ros_args, args.transport)


def cmd_param(args) -> int:
    from ..transport import param_get, param_set

    if args.action == "get":
        print(param_get(args.node, args.name, domain_id=args.domain_id, timeout_s=args.timeout))
        return 0
    if args.value is None:
        from .cli import UsageError

        raise UsageError("param set needs a VALUE")
    ok, reason = param_set(args.node, args.name, args.value, domain_id=args.domain_id, timeout_s=args.timeout)
    if ok:
        print("Set parameter successful")
        return 0
    print(f"Setting parameter failed: {reason}", file=sys.stderr)
    return 1


class _Args:
    def __init__(self, **kw):
        self.__dict__.update(kw)


def bench_loop(args) -> dict:
    duration = args.duration or 60.0
    compose = bool(getattr(args, "compose", False))
    a = _Args(scenario="S1", params=None, set=None, controller=None, estimator=None, duration=duration,
              transport=args.transport, bag_dir=tempfile.mkdtemp(prefix="dem_ros_bench_"), no_record=True,
              domain_id=None, json=None, compose=compose)
    from .bench import cpu_times, machine, steal_percent, timer_floor

    floor = timer_floor(5.0)
    before = cpu_times()
    res = launch(a, quiet=False)
    steal = steal_percent(before, cpu_times())

    m = machine()
    L = res["loop"]
    how = "all nodes in one process (--compose)" if compose else "one process per node"
    print(f"dem-ros bench loop on {m['cpu']} ({m['cores']} cores), transport {args.transport}, {how}, {duration:g} s of S1")
    print(f"  cycles {L['cycles']}, deadline misses {L['deadline_misses']} ({100.0 * L['deadline_misses'] / max(L['cycles'], 1):.3f} %)")
    print(f"  latency sensor stamp -> command at plant: p50 {L['latency_us']['p50']:.0f} us, p99 {L['latency_us']['p99']:.0f} us, max {L['latency_us']['max']:.0f} us")
    print("  CPU [% of one core]: " + ", ".join(f"{k} {v:.1f}" for k, v in L["cpu_percent"].items())
          + f"; all nodes {sum(L['cpu_percent'].values()):.1f}")
    if steal is not None:  # a VM whose host is busy loses whole milliseconds: say so next to the figures
        print(f"  CPU stolen by the hypervisor during the run: {steal:.1f} % of this VM's time")
    print(f"  machine floor (a bare 1 kHz sleep loop, 5 s before the run): late p50 {floor['p50_us']:.0f} us,"
          f" p99 {floor['p99_us']:.0f} us, p99.9 {floor['p99_9_us']:.0f} us, max {floor['max_us']:.0f} us;"
          f" {floor['over_1ms_percent']:.3f} % of wake-ups > 1 ms late")
    return {"loop": L, "machine": m, "transport": args.transport, "composed": compose, "duration_s": duration,
            "hypervisor_steal_percent": steal, "timer_floor": floor}


def bench_record(args) -> dict:
    from ..bag.bench import bench_record as br
    from .bench import machine

    seconds = args.duration or 10.0
    r = br(seconds)
    print(f"dem-ros bench record on {machine()['cpu']}: {seconds:g} s at the graph's load")
    for k, v in r.items():
        print(f"  {k}: {v}")
    r["machine"] = machine()
    return r
