"""``dem-ros bench``: speed measured by commands, not by timed tests.

``bench loop``: the node graph (``dem-ros launch`` on S1, no bag) with the plant's
loop statistics, CPU per node, the hypervisor's steal and this machine's timer floor.
``bench record``: the recorder's writer at the graph's load (:mod:`dem_ros.bag.bench`), and
why the package keeps hand-written codecs (:func:`codec_comparison`): per message, our
JointState CDR encoder/decoder against cyclonedds' generic IDL codec and rosbags'
typestore, and our MCAP writer/reader against the ``mcap`` package's.

``bench sim``: the 100 s S1 scenario at 1 kHz control with 0.1 ms RK4 sub-steps:
single-run wall time (and CPU time) and x real time, the controller's per-call step time as
the nodes call it (p50, p99), both again for the law of 42edb28 (the adaptive law with the
session-3 terms off, :data:`TERMS_OFF`: the figures to compare across #8 and #9), batch throughput, and the same closed
loop run by scipy's ``solve_ivp`` (what a Python user would otherwise write: the plant
as a numpy right-hand side, integrated sample by sample under the same ZOH
controller) with the speed ratio and the largest trajectory difference.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..realtime import ENV, REPORT_PREFIX, STALLS_PREFIX
from .common import UsageError
from .launcher import GraphError, LaunchOptions, launch
from .runmetrics import tracking_text

__all__ = ["bench_loop", "bench_record", "bench_sim", "machine", "run"]


def machine() -> dict:
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}


def cpu_times() -> dict[str, int] | None:
    """Machine-wide CPU ticks from /proc/stat (busy, idle, steal); None where unavailable."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    steal = v[7] if len(v) > 7 else 0
    idle = v[3] + (v[4] if len(v) > 4 else 0)
    return {"busy": sum(v[:8]) - idle - steal, "idle": idle, "steal": steal}


def steal_percent(before: dict | None, after: dict | None) -> float | None:
    """Share of CPU time the hypervisor took from this VM between two :func:`cpu_times` (%)."""
    if not before or not after:
        return None
    d = {k: after[k] - before[k] for k in before}
    total = sum(d.values())
    return round(100.0 * d["steal"] / total, 2) if total > 0 else None


FLOOR_WARMUP_ROUNDS = 200  # unmeasured 1 kHz rounds before the floor is measured (0.2 s)


def timer_floor(seconds: float = 5.0, period_s: float = 1e-3, command_delay: int = 1) -> dict[str, Any]:
    """How late this machine wakes a bare 1 kHz loop sleeping to absolute deadlines (us), and
    the deadline misses that alone would cause.

    No middleware, no work: the floor under any node's deadline misses. On a VM
    whose host is busy this alone can exceed a millisecond.

    ``misses_percent`` applies the free-running plant's rule (:mod:`dem_ros.nodes.plant_sim`)
    to these wake-ups, with a chain that takes no time at all: a wake-up publishes every sample
    due within half a period; sample k needs the command of sample k-1-d (d =
    ``command_delay``), which is computed after the wake-up that published that sample, so k
    misses when both were published by the same (late) wake-up. A graph cannot miss less than
    this on the same machine. ``stalls``: the bare loop's own stalls (> 5 ms) by cause
    (:class:`dem_ros.realtime.StallMonitor`): what the machine does to a thread doing nothing.
    """
    from ..realtime import StallMonitor

    period = int(period_s * 1e9)
    n = max(1, int(seconds / period_s))
    wake = np.empty(n, dtype=np.int64)
    monitor = StallMonitor(5.0, write=lambda _line: None)
    # warm-up, not measured (as the graph's pre-roll is not): the first pass through this code and the
    # monitor's /proc reads fault their pages in. On a loaded host the probe was once blocked for seconds
    # there and, as a loop that catches up, counted every later wake-up late (a floor far above the graph's)
    due = time.monotonic_ns() + period
    for _ in range(FLOOR_WARMUP_ROUNDS):
        wait = due - time.monotonic_ns()
        if wait > 0:
            time.sleep(wait * 1e-9)
        monitor.round(due, time.monotonic_ns())
        due += period
    monitor = StallMonitor(5.0, write=lambda _line: None)
    t0 = due = time.monotonic_ns() + period
    for i in range(n):
        wait = due - time.monotonic_ns()
        if wait > 0:
            time.sleep(wait * 1e-9)
        wake[i] = time.monotonic_ns()
        monitor.round(due, wake[i])
        due += period
    dues = t0 + period * np.arange(n, dtype=np.int64)
    late = (wake - dues) / 1e3
    p50, p99, p999 = np.percentile(late, [50, 99, 99.9])
    # the wake-up that publishes each sample: the first one at or after (due - half a period)
    group = np.searchsorted(wake, dues - period // 2, side="left")
    src = np.arange(n) - 1 - command_delay
    ok = (src >= 0) & (group < n)
    misses = int(np.sum(group[ok] == group[src[ok]]))
    s = monitor.summary()
    return {"p50_us": round(float(p50), 1), "p99_us": round(float(p99), 1), "p99_9_us": round(float(p999), 1),
            "max_us": round(float(late.max()), 1), "over_1ms_percent": round(100.0 * float(np.mean(late > 1000)), 3),
            "misses_percent": round(100.0 * misses / max(int(ok.sum()), 1), 3), "command_delay": command_delay,
            "stalls": {"n": s["stalls"], "by_cause": s["by_cause"], "steal_ms": s["steal_ms"]}}


def _peer(cfg, duration: float, ref_arrays):
    """The same loop with scipy.integrate.solve_ivp (RK45, tight tolerances) per 1 ms interval."""
    from scipy.integrate import solve_ivp

    from ..core.controllers import make_controller
    from ..core.model import derived, hover_state

    pc = cfg["plant_sim"]
    P, Q, A, B, C, D = derived(pc["L"], pc["l"], pc["m"], pc["I"])
    K, R, N1, N2, g = pc["K"], pc["R"], pc["N1"], pc["N2"], pc["g"]

    def f(t, x, u):
        d1 = P * x[0] + Q * x[2]
        d2 = Q * x[0] + P * x[2]
        F1 = K * x[4] ** 2 / d1**2
        F2 = K * x[5] ** 2 / d2**2
        return np.array([
            x[1], -A * F1 - B * F2 + C * N1 + D * N2 + g,
            x[3], -B * F1 - A * F2 + D * N1 + C * N2 + g,
            d1 / (2 * K) * (u[0] - R * x[4]) + x[4] * (P * x[1] + Q * x[3]) / d1,
            d2 / (2 * K) * (u[1] - R * x[5]) + x[5] * (Q * x[1] + P * x[3]) / d2,
        ])

    _, ref = ref_arrays
    dt = pc["dt"]
    n = round(duration / dt)
    x, u0 = hover_state(pc, pc["gap0"])
    ctrl = make_controller(cfg["controller"], "adaptive")
    ctrl.reset(x.copy(), u0)
    X = np.zeros((n, 6))
    d = pc["command_delay"]
    held = [u0.copy() for _ in range(d)]  # the same command delay as ours: u_k is held over [t_k+d, t_k+d+1)
    t0 = time.perf_counter()
    for k in range(n):
        X[k] = x
        held.append(ctrl.step(x.copy(), ref[k]).copy())
        u = held.pop(0)
        sol = solve_ivp(f, (0.0, dt), x, args=(u,), method="RK45", rtol=1e-10, atol=1e-13)
        x = sol.y[:, -1]
    return X, time.perf_counter() - t0


#: the session-3 terms of the adaptive law off: the law of 42edb28, the commit before #9 (bench sim's second row)
TERMS_OFF = {"ki": 0.0, "coil_weight": 0.0, "q_R": 0.0, "q_rho": 0.0}


def bench_sim(batch: int = 64, peer_duration: float = 5.0, bar: Any = None) -> dict:
    """The simulator's speed; ``bar``: a :class:`.progress.Progress` told each phase (minutes on a busy machine)."""
    say = bar.stage if bar is not None else (lambda _what: None)
    from ..core.controllers import make_controller
    from ..core.model import hover_state
    from ..core.scenarios import get_scenario
    from ..core.simulate import prepare, simulate, simulate_batch

    cfg = get_scenario("S1").config()
    # the law of 42edb28 (before #8's terms), for comparisons across that change (#9: the same law configuration)
    old = {g: dict(v) for g, v in cfg.items()}
    old["controller"].update(TERMS_OFF)

    def single_and_step(c: dict, label: str) -> dict:
        walls, cpus = [], []
        say(f"S1, 100 s, 3 runs (the best counts){label}")
        for _ in range(3):
            c0 = time.thread_time()
            res = simulate(c, controller="adaptive", estimator="none", duration=100.0)
            cpus.append(time.thread_time() - c0)
            walls.append(res.wall_time)
        r: dict[str, Any] = {"single_run_wall_s": min(walls), "single_run_cpu_s": min(cpus),
                             "realtime_factor": 100.0 / min(walls)}
        # controller step as the nodes call it (Python -> compiled kernel)
        say(f"controller step from Python, 20 000 calls{label}")
        pc = c["plant_sim"]
        x0, u0 = hover_state(pc, pc["gap0"])
        _, ref = prepare(c, 20.0)[1:3]
        ctrl = make_controller(c["controller"], "adaptive")
        ctrl.reset(x0.copy(), u0)
        xs = res.x[:20000]
        times = np.empty(len(xs))
        for k in range(len(xs)):
            t = time.perf_counter_ns()
            ctrl.step(xs[k], ref[k])
            times[k] = time.perf_counter_ns() - t
        r["controller_step_us"] = {"p50": float(np.percentile(times, 50) / 1e3),
                                   "p99": float(np.percentile(times, 99) / 1e3)}
        return r

    simulate(cfg, controller="adaptive", estimator="none", duration=1.0)  # compile / load the cache
    out = {"machine": machine(), "scenario": "S1", "duration_s": 100.0, "control_rate_hz": 1000,
           "plant_substep_s": 1e-4}
    out.update(single_and_step(cfg, ""))
    out["terms_off"] = {"controller": TERMS_OFF, **single_and_step(old, ", the law of 42edb28")}

    offsets = np.linspace(0.0, 3.0, batch)
    say(f"batch of {batch} plants x 100 s")
    simulate_batch(cfg, offsets[:2], controller="adaptive", duration=1.0)  # compile
    t_batch = time.perf_counter()
    simulate_batch(cfg, offsets, controller="adaptive", duration=100.0)
    bw = time.perf_counter() - t_batch
    out["batch"] = {"plants": batch, "wall_s": bw}
    out["batch_runs_per_s"] = batch / bw

    say(f"the scipy solve_ivp peer, {peer_duration:g} s")
    ours = simulate(cfg, controller="adaptive", estimator="none", duration=peer_duration)
    Xp, pw = _peer(cfg, peer_duration, prepare(cfg, peer_duration)[1:3])
    diff = np.max(np.abs(Xp[:, [0, 2]] - ours.x[:, [0, 2]])) * 1e6
    rt_peer = peer_duration / pw
    out["peer"] = {
        "name": "scipy.integrate.solve_ivp (RK45, rtol 1e-10, atol 1e-13) per 1 ms ZOH interval",
        "simulated_s": peer_duration,
        "realtime_factor": rt_peer,
        "speedup": out["realtime_factor"] / rt_peer,
        "max_abs_diff_um": float(diff),
    }
    return out


def _print_sim(r: dict) -> None:
    m = r["machine"]
    print(f"dem-ros bench sim on {m['cpu']} ({m['cores']} cores), Python {m['python']}")
    print(f"  S1, 100 s, 1 kHz control, 0.1 ms RK4: {r['single_run_wall_s']:.3f} s wall"
          f" ({r['single_run_cpu_s']:.3f} s CPU) = {r['realtime_factor']:.0f}x real time")
    c = r["controller_step_us"]
    print(f"  controller step (adaptive, per call from Python): p50 {c['p50']:.2f} us, p99 {c['p99']:.1f} us")
    o = r["terms_off"]
    c = o["controller_step_us"]
    print(f"  the law of 42edb28 ({', '.join(f'{k} = {v:g}' for k, v in o['controller'].items())}):"
          f" {o['single_run_wall_s']:.3f} s wall ({o['single_run_cpu_s']:.3f} s CPU), step p50 {c['p50']:.2f} us,"
          f" p99 {c['p99']:.1f} us")
    print(f"  batch: {r['batch']['plants']} plants x 100 s in {r['batch']['wall_s']:.1f} s"
          f" = {r['batch_runs_per_s']:.2f} runs/s")
    p = r["peer"]
    print(f"  peer {p['name']}: {p['realtime_factor']:.2f}x real time over {p['simulated_s']:g} s;"
          f" ours is {p['speedup']:.0f}x faster; max |gap difference| {p['max_abs_diff_um']:.2e} um")


#: seconds of the machine-floor probe run before the graph
FLOOR_S = 10.0
#: a neighbour's load: one busy Python process at normal priority
_BUSY = "while True: pass"


def _busy(n: int) -> list[subprocess.Popen]:
    """``n`` processes that spin at normal priority until killed (``bench loop --load N``)."""
    return [subprocess.Popen([sys.executable, "-c", _BUSY], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True) for _ in range(max(0, n))]


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.kill()
    for p in procs:
        p.wait()


def _floor_child(seconds: float, env: dict[str, str]) -> dict[str, Any]:
    """:func:`timer_floor` in a child process with the nodes' real-time settings (``env``)."""
    code = ("import json; from dem_ros.realtime import enter_loop; enter_loop(report=False);"
            f" from dem_ros.tools.bench import timer_floor; print('FLOOR ' + json.dumps(timer_floor({seconds!r})))")
    limit = 300 + 2 * seconds  # a normal-priority child on a loaded machine can take minutes to import numpy
    try:
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired:
        raise GraphError(f"the timer-floor probe did not finish within {limit:g} s: this machine is too loaded"
                         " to measure (try --rt)") from None
    for line in r.stdout.splitlines():
        if line.startswith("FLOOR "):
            return json.loads(line[6:])
    raise GraphError(f"the timer-floor probe failed: {(r.stderr or r.stdout).strip()[-500:]}")


def _log_reports(logs: Path, prefix: str) -> dict[str, Any]:
    """Each node process's ``PREFIX {json}`` line (``REALTIME``: what it was granted; ``STALLS``:
    its loop's stalls), by process name."""
    out: dict[str, Any] = {}
    for log in sorted(logs.glob("*.log")):
        for line in log.read_text(errors="replace").splitlines():
            if line.startswith(prefix):
                with contextlib.suppress(ValueError):
                    out[log.stem] = json.loads(line[len(prefix):])
    return out


def _plant_status(bag: Path) -> dict[str, str]:
    """The key/values of the plant's last loop status in ``bag`` (holds, landing, ... when reported)."""
    from .. import contract
    from ..bag import BagReader

    last: dict[str, str] = {}
    for _, _, msg in BagReader(bag).messages([contract.DIAGNOSTICS.name]):
        for st in msg.status:
            if st.name == contract.LOOP_STATUS:
                last = {kv.key: kv.value for kv in st.values}
    return last


def _rclpy_missing() -> str | None:
    """Why the rclpy transport cannot be the peer here (None: it can)."""
    try:
        import rclpy  # noqa: F401
    except Exception as exc:  # ImportError, or a broken ROS environment
        return f"rclpy does not import ({type(exc).__name__}: {exc})"
    return None


def _one_loop(transport: str, compose: bool, free_run: bool, duration: float) -> dict[str, Any]:
    """One graph run (S1, recorded to a temporary bag): loop figures, RMS, holds, landing, rt."""
    tmp = Path(tempfile.mkdtemp(prefix="dem_ros_bench_"))
    try:
        a = LaunchOptions(scenario="S1", set=["plant_sim.lockstep=false"] if free_run else [], duration=duration,
                          transport=transport, bag_dir=str(tmp), compose=compose)
        metrics, info = launch(a, quiet=False)
        bag = Path(info["bag"])
        status = _plant_status(bag)
        logs = bag.parent / (bag.name + "_logs")
        rt = _log_reports(logs, REPORT_PREFIX)
        stalls = _log_reports(logs, STALLS_PREFIX)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if metrics.loop is None:
        raise GraphError("the plant reported no loop statistics (see the launch logs)")
    holds = status.get("holds")
    return {"verdict": metrics.verdict, "verdict_reasons": metrics.verdict_reasons,
            "loop": metrics.to_dict()["loop"], "failed": metrics.failed, "fail_time_s": metrics.fail_time_s,
            "rms_error_um": metrics.rms_error_um, "offline_rms_error_um": info["offline_rms_error_um"],
            "holds": int(holds) if holds is not None else None,
            "landing": status.get("landing") == "True" if "landing" in status else None,
            "landing_reason": status.get("landing_reason") or None, "rt": rt, "stalls": stalls}


def _print_loop(r: dict[str, Any], label: str) -> None:
    L = r["loop"]
    lat = L["latency_us"]
    cyc = max(L["cycles"], 1)
    failed = f"yes, at t = {r['fail_time_s']:.3f} s" if r["failed"] else "no"
    print(f"  [{label}] verdict {r['verdict']}"
          + (f": {'; '.join(r['verdict_reasons'])}" if r["verdict_reasons"] else ""))
    print(f"  [{label}] cycles {L['cycles']}, deadline misses {L['deadline_misses']}"
          f" ({100.0 * L['deadline_misses'] / cyc:.3f} %), holds {r['holds'] if r['holds'] is not None else 'n/a'},"
          " landing "
          f"{'n/a' if r['landing'] is None else ('YES: ' + str(r['landing_reason'])) if r['landing'] else 'no'},"
          f" failed {failed}")
    if all(isinstance(lat.get(k), (int, float)) and np.isfinite(lat[k])
           for k in ("p50", "p99", "max")):  # none: no command came
        print(f"  [{label}] latency sensor stamp -> command at plant: p50 {lat['p50']:.0f} us, p99 {lat['p99']:.0f} us,"
              f" max {lat['max']:.0f} us")
    print(f"  [{label}] CPU [% of one core]: " + ", ".join(f"{k} {v:.1f}" for k, v in L["cpu_percent"].items())
          + f"; all nodes {sum(L['cpu_percent'].values()):.1f}")
    rms = tracking_text(r["rms_error_um"], r["offline_rms_error_um"])
    if rms is not None:  # a plate that landed before t = 0 has none (runmetrics leaves it out, never nan)
        print(f"  [{label}] RMS error e1 / e2 [um]: {rms}")
    for proc, g in r["rt"].items():
        got = (f"SCHED_FIFO {g['fifo_priority']} ({', '.join(g['fifo_threads'])})" if g["fifo_priority"]
               else "normal scheduling")
        extra = ", memory locked" if g["memory_locked"] else ""
        miss = f"; refused: {', '.join(g['missing'])}" if g["missing"] else ""
        print(f"  [{label}] real time {proc}: "
              f"{got if g['requested'] else 'off (--no-rt)'}{extra if g['requested'] else ''}{miss}")
    for proc, st in r.get("stalls", {}).items():
        print(f"  [{label}] loop stalls {proc}: {_stall_text(st)}")


def _stall_text(st: dict[str, Any]) -> str:
    """``n stalls > T ms: cause n (total ms, longest ms), ...; longest ...`` from a stall summary."""
    causes = ", ".join(f"{c} {v['n']} ({v['total_ms']:.0f} ms, longest {v['max_ms']:.1f})"
                       for c, v in st["by_cause"].items() if v["n"])
    text = f"{st.get('stalls', st.get('n'))} > {st.get('threshold_ms', 5):g} ms" + (f": {causes}" if causes else "")
    return text + f"; steal across them {st['steal_ms']:.0f} ms"


def _print_side_by_side(dds: dict[str, Any], rclpy: dict[str, Any]) -> None:
    """The two transports' runs in columns, with rclpy / dds."""
    def row(label: str, a: float, b: float, fmt: str) -> None:
        ratio = f"{b / a:.2f}x" if np.isfinite(a) and np.isfinite(b) and a > 0 else "-"
        print(f"    {label:<26}{format(a, fmt):>10}{format(b, fmt):>10}{ratio:>12}")

    def num(x: Any) -> float:
        return float(x) if isinstance(x, (int, float)) else float("nan")

    print(f"    {'side by side':<26}{'dds':>10}{'rclpy':>10}{'rclpy/dds':>12}")
    la, lb = dds["loop"]["latency_us"], rclpy["loop"]["latency_us"]
    for k in ("p50", "p99", "max"):
        row(f"latency {k} [us]", num(la.get(k)), num(lb.get(k)), ".0f")
    for r in (dds, rclpy):
        r["_miss"] = 100.0 * r["loop"]["deadline_misses"] / max(r["loop"]["cycles"], 1)
        r["_cpu"] = sum(r["loop"]["cpu_percent"].values())
    row("deadline misses [%]", dds.pop("_miss"), rclpy.pop("_miss"), ".3f")
    row("CPU, all nodes [% core]", dds.pop("_cpu"), rclpy.pop("_cpu"), ".1f")
    land = {k: ("n/a" if r["landing"] is None else "YES" if r["landing"] else "no")
            for k, r in (("d", dds), ("r", rclpy))}
    print(f"    {'landing':<26}{land['d']:>10}{land['r']:>10}")


def bench_loop(args: argparse.Namespace) -> dict[str, Any]:
    """``bench loop [--compose] [--free-run] [--load N] [--rt/--no-rt]``: the graph's loop, measured.

    ``--load N`` runs N busy processes for the whole benchmark (floor and run), as a neighbour
    would; the machine floor (a bare 1 kHz sleep loop with the nodes' real-time settings) is
    measured under that load just before the run. The same graph then also runs on the other
    transport (rclpy after dds, dds after rclpy; rclpy where it imports: the ``ros`` extra), and
    both are printed side by side with the ratio rclpy / dds.
    """
    duration = args.duration or 60.0
    compose, free_run, load, rt = bool(args.compose), bool(args.free_run), int(args.load or 0), bool(args.rt)
    if load < 0:
        raise UsageError(f"--load {load}: give a number of busy processes >= 0")
    saved = os.environ.get(ENV["enabled"])
    os.environ[ENV["enabled"]] = "1" if rt else "0"  # the node processes inherit it
    busy = _busy(load)
    try:
        floor = _floor_child(FLOOR_S, dict(os.environ))
        before = cpu_times()
        up_before = os.getloadavg()
        transport = args.transport if args.transport != "auto" else ("dds" if _rclpy_missing() else "rclpy")
        ours = _one_loop(transport, compose, free_run, duration)
        steal = steal_percent(before, cpu_times())
        up_after = os.getloadavg()
        other = "rclpy" if transport == "dds" else "dds"
        why = _rclpy_missing() if other == "rclpy" else None
        peer: dict[str, Any] = ({"transport": other, "skipped": why} if why
                                else {"transport": other, **_one_loop(other, compose, free_run, duration)})
    finally:
        _stop(busy)
        if saved is None:
            os.environ.pop(ENV["enabled"], None)
        else:
            os.environ[ENV["enabled"]] = saved

    m = machine()
    how = "all nodes in one process (--compose)" if compose else "one process per node"
    timing = "free-running (plant_sim.lockstep=false)" if free_run else "lockstep"
    print(f"dem-ros bench loop on {m['cpu']} ({m['cores']} cores), transport {args.transport}, {how}, {timing},"
          f" {duration:g} s of S1, real time {'on' if rt else 'off'}, {load} busy processes beside it")
    print(f"  load average (1 min) {up_before[0]:.2f} before, {up_after[0]:.2f} after the run")
    _print_loop(ours, transport)
    if peer.get("skipped"):
        print(f"  [{other}] peer skipped: {peer['skipped']}")
    else:
        _print_loop(peer, other)
        by = {transport: ours, other: peer}
        _print_side_by_side(by["dds"], by["rclpy"])
    if steal is not None:  # a VM whose host is busy loses whole milliseconds: say so next to the figures
        print(f"  CPU stolen by the hypervisor during the run: {steal:.1f} % of this VM's time")
    print(f"  machine floor (a bare 1 kHz sleep loop with the same real-time settings, {FLOOR_S:g} s before the run):"
          f" late p50 {floor['p50_us']:.0f} us, p99 {floor['p99_us']:.0f} us, p99.9 {floor['p99_9_us']:.0f} us,"
          f" max {floor['max_us']:.0f} us; {floor['over_1ms_percent']:.3f} % of wake-ups > 1 ms late;"
          f" deadline misses it alone would cause (command_delay {floor['command_delay']}):"
          f" {floor['misses_percent']:.3f} %")
    print(f"  machine floor stalls: {_stall_text(floor['stalls'])}")
    return {**ours, "machine": m, "transport": transport, "composed": compose, "free_run": free_run,
            "duration_s": duration, "load_processes": load,
            "load_average": {"before": up_before[0], "after": up_after[0]},
            "hypervisor_steal_percent": steal, "timer_floor": floor, "peer": peer}


def _per_call_us(fn: Any, n: int) -> float:
    """Best of 3 rounds of ``n`` calls of ``fn()``: us per call."""
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def codec_comparison(n_cdr: int = 20_000, n_bag: int = 100_000) -> dict[str, Any]:
    """Our codecs against the libraries they replace, on the graph's messages (us per message).

    CDR: a measurement JointState (2 names, 2 gaps, 2 rates, 2 currents) encoded and decoded by
    :mod:`dem_ros.transport.dds.fastcdr`, by cyclonedds' IDL serializer (what DdsNode would
    otherwise call) and by rosbags' typestore. MCAP: ``n_bag`` such messages over 7 topics written
    with zstd chunks by :class:`dem_ros.bag.BagWriter` and by ``mcap.writer.Writer``, then read back
    raw by :class:`dem_ros.bag.BagReader` and by ``mcap.reader``. A library that is not installed
    is reported as missing.
    """
    from ..bag import BagReader, BagWriter
    from ..contract import QOS_STREAM
    from ..nodes.common import joint_state
    from ..transport.dds import fastcdr, msgs
    from ..typestore import typestore

    out: dict[str, Any] = {"cdr_messages": n_cdr, "mcap_messages": n_bag}
    msg = joint_state(msgs.JointState, 1_700_000_000_123_456_789, (0.008, 0.0081), (1e-4, -2e-4), (4.0, 4.1))
    enc = fastcdr.encode_joint_state
    dec = fastcdr.decoder(msgs.JointState)
    data = enc(msg)
    assert bytes(msg.serialize()) == data and dec(data) == msg  # the same bytes and message as the library's
    cdr: dict[str, dict[str, float]] = {
        "dem_ros fastcdr": {"encode_us": _per_call_us(lambda: enc(msg), n_cdr),
                            "decode_us": _per_call_us(lambda: dec(data), n_cdr)},
        "cyclonedds IdlStruct": {"encode_us": _per_call_us(msg.serialize, n_cdr),
                                 "decode_us": _per_call_us(lambda: msgs.JointState.deserialize(data), n_cdr)},
    }
    ts = typestore()  # rosbags (a dependency)
    rmsg = ts.deserialize_cdr(data, "sensor_msgs/msg/JointState")
    cdr["rosbags typestore"] = {
        "encode_us": _per_call_us(lambda: ts.serialize_cdr(rmsg, "sensor_msgs/msg/JointState"), n_cdr),
        "decode_us": _per_call_us(lambda: ts.deserialize_cdr(data, "sensor_msgs/msg/JointState"), n_cdr)}
    out["cdr"] = cdr

    names = [f"/bench/js_{i}" for i in range(7)]
    mcap_figures: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="dem_ros_codec_") as tmp:
        ours = Path(tmp) / "ours"
        t0 = time.perf_counter()
        w = BagWriter(ours, compression="zstd")
        for name in names:
            w.add_topic(name, "sensor_msgs/msg/JointState", QOS_STREAM)
        for k in range(n_bag):
            w.write(names[k % 7], 1_000_000 * k, data)
        w.close()
        write_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = BagReader(ours)
        n_read = sum(1 for _ in r.raw_messages())
        r.close()
        read_s = time.perf_counter() - t0
        assert n_read == n_bag
        mcap_figures["dem_ros bag"] = {"write_us": 1e6 * write_s / n_bag, "read_us": 1e6 * read_s / n_bag}
        try:
            from mcap.reader import make_reader
            from mcap.writer import CompressionType, Writer

            theirs = Path(tmp) / "mcap.mcap"
            t0 = time.perf_counter()
            with open(theirs, "wb") as f:
                mw = Writer(f, compression=CompressionType.ZSTD)
                mw.start(profile="ros2", library="mcap-python")
                schema = mw.register_schema("sensor_msgs/msg/JointState", "ros2msg", b"")
                chans = [mw.register_channel(name, "cdr", schema) for name in names]
                for k in range(n_bag):
                    t = 1_000_000 * k
                    mw.add_message(chans[k % 7], log_time=t, data=data, publish_time=t)
                mw.finish()
            write_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            with open(theirs, "rb") as f:
                n_read = sum(1 for _ in make_reader(f).iter_messages())
            read_s = time.perf_counter() - t0
            assert n_read == n_bag
            mcap_figures["mcap package"] = {"write_us": 1e6 * write_s / n_bag, "read_us": 1e6 * read_s / n_bag}
        except ImportError:
            mcap_figures["mcap package"] = {"missing": True}
    out["mcap"] = mcap_figures
    return out


def bench_record(args: argparse.Namespace) -> dict[str, Any]:
    from ..bag.bench import bench_record as br

    seconds = args.duration or 10.0
    r = br(seconds)
    print(f"dem-ros bench record on {machine()['cpu']}: {seconds:g} s at the graph's load")
    for k, v in r.items():
        print(f"  {k}: {v}")
    c = codec_comparison()
    print(f"  codecs, us per message (best of 3; CDR: {c['cdr_messages']} calls, MCAP: {c['mcap_messages']} messages"
          " over 7 topics, zstd):")
    for lib, f in c["cdr"].items():
        print(f"    CDR  {lib:<22} " + ("not installed" if f.get("missing") else
                                         f"encode {f['encode_us']:.2f}, decode {f['decode_us']:.2f}"))
    for lib, f in c["mcap"].items():
        print(f"    MCAP {lib:<22} " + ("not installed" if f.get("missing") else
                                         f"write {f['write_us']:.2f}, read {f['read_us']:.2f}"))
    r["codecs"] = c
    r["machine"] = machine()
    return r


def run(what: str, args: argparse.Namespace) -> dict[str, Any]:
    """Run benchmark ``what`` (sim, loop, record), print its figures, return them."""
    if what == "sim":
        from .common import warm_kernels
        from .progress import Progress

        warm_kernels("dem-ros bench sim")  # compiled (a first run) or loaded with progress, not inside the timing
        with Progress("dem-ros bench sim", None, stage="a 1 s warm-up run") as bar:
            r = bench_sim(args.batch, args.peer_duration, bar)
        _print_sim(r)
        return r
    if what == "loop":
        return bench_loop(args)
    return bench_record(args)
