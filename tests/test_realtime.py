"""dem_ros.realtime: what a process asks for, what it gets, and the one-line fallback.

The fallback is tested for real: a child process runs without CAP_SYS_NICE / CAP_IPC_LOCK
(dropped from its bounding set by util-linux ``setpriv``) and with RLIMIT_RTPRIO 0 and a
64 KiB RLIMIT_MEMLOCK (``prlimit``), exactly what an ordinary user gets by default.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import domains
import pytest

from dem_ros.realtime import ENV, OFF_LOOP_NICE, REPORT_PREFIX, RtConfig, RtConfigError, StallMonitor, config_from_env

ROOT = Path(__file__).resolve().parents[1]
#: as an ordinary user: no CAP_SYS_NICE / CAP_IPC_LOCK, RLIMIT_RTPRIO 0, RLIMIT_MEMLOCK 64 KiB
UNPRIVILEGED = ["prlimit", "--rtprio=0", "--memlock=65536", "setpriv", "--bounding-set=-sys_nice,-ipc_lock",
                "--inh-caps=-sys_nice,-ipc_lock"]
needs_setpriv = pytest.mark.skipif(
    os.geteuid() != 0 or not (shutil.which("setpriv") and shutil.which("prlimit")),
    reason="dropping CAP_SYS_NICE for a child needs root and util-linux setpriv/prlimit")

#: a child that enters the loop as the nodes do, then runs 300 periods of a 1 kHz deadline loop
LOOP_CHILD = textwrap.dedent("""
    import gc, json, os, threading, time
    from dem_ros.realtime import enter_loop
    g = enter_loop()
    due = time.monotonic_ns()
    for _ in range(300):
        due += 1_000_000
        time.sleep(max(0, due - time.monotonic_ns()) * 1e-9)
    tid = threading.get_native_id()
    policy = int(open(f"/proc/self/task/{tid}/stat").read().rsplit(")", 1)[1].split()[38])
    print("CHILD " + json.dumps({"policy": policy, "gc_enabled": gc.isenabled(), "frozen": gc.get_freeze_count()}))
""")


def _run_child(code: str, env_extra: dict[str, str] | None = None, prefix: list[str] | None = None,
               timeout: float = 120.0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for v in ENV.values():
        env.pop(v, None)
    env.update(env_extra or {})
    return subprocess.run([*(prefix or []), sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def _line(out: str, prefix: str) -> dict:
    lines = [ln for ln in out.splitlines() if ln.startswith(prefix)]
    assert len(lines) == 1, out
    return json.loads(lines[0][len(prefix):])


def test_config_from_env_defaults_and_values():
    assert config_from_env({}) == RtConfig(enabled=True, priority=50, lock_memory=True, cpus=())
    env = {ENV["enabled"]: "1", ENV["priority"]: "80", ENV["lock_memory"]: "0", ENV["cpus"]: "0"}
    assert config_from_env(env) == RtConfig(enabled=True, priority=80, lock_memory=False, cpus=(0,))
    assert config_from_env({ENV["enabled"]: "off"}).enabled is False


@pytest.mark.parametrize("name, value, says", [
    ("priority", "high", "DEM_ROS_RT_PRIORITY='high'"),
    ("priority", "-1", "1..99"),
    ("priority", "100", "1..99"),
    ("enabled", "maybe", "DEM_ROS_RT='maybe'"),
    ("cpus", "0;1", "DEM_ROS_RT_CPUS='0;1'"),
    ("cpus", "4096", "do not exist"),
])
def test_bad_settings_are_named(name, value, says):
    with pytest.raises(RtConfigError, match=None) as exc:
        config_from_env({ENV[name]: value})
    assert says in str(exc.value)


@needs_setpriv
def test_without_rt_permission_one_warning_line_and_the_loop_runs():
    r = _run_child(LOOP_CHILD, prefix=UNPRIVILEGED)
    assert r.returncode == 0, r.stderr
    warnings = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(warnings) == 1, r.stderr
    w = warnings[0]
    assert w.startswith("warning: dem_ros real time: running without")
    for what in ("SCHED_FIFO 50", "RLIMIT_RTPRIO 0", "mlockall", "RLIMIT_MEMLOCK 64 KiB", "limits.conf",
                 "--ulimit rtprio=99", "DEM_ROS_RT=0"):
        assert what in w, w
    g = _line(r.stdout, REPORT_PREFIX)
    assert g["requested"] and g["fifo_priority"] is None and not g["memory_locked"]
    assert g["timer_slack_ns"] == 1000  # needs no privilege
    child = _line(r.stdout, "CHILD ")
    assert child["policy"] == os.SCHED_OTHER and not child["gc_enabled"] and child["frozen"] > 1000


def test_granted_where_permitted():
    r = _run_child(LOOP_CHILD)
    assert r.returncode == 0, r.stderr
    g = _line(r.stdout, REPORT_PREFIX)
    if g["missing"]:
        pytest.skip(f"this process may not use real-time settings here: {g['missing']}")
    assert r.stderr.strip() == ""
    assert g["fifo_priority"] == 50 and g["memory_locked"] and g["timer_slack_ns"] == 1000
    assert _line(r.stdout, "CHILD ")["policy"] == os.SCHED_FIFO


def test_priority_0_is_off_the_loop_s_path_normal_scheduling_at_nice_minus_10():
    """The recorder's setting: no SCHED_FIFO (its CPU time would come out of the real-time budget), nice -10 on
    every thread the process has and starts, and the rest of the settings as for a loop process."""
    code = LOOP_CHILD + textwrap.dedent("""
        t = threading.Thread(target=lambda: None)  # a thread started after enter_loop inherits the nice value
        t.start(); t.join()
        nices = {int(tid): os.getpriority(os.PRIO_PROCESS, int(tid)) for tid in os.listdir("/proc/self/task")}
        print("NICE " + json.dumps({"nices": sorted(set(nices.values())), "started": t.native_id is not None}))
    """)
    r = _run_child(code, {ENV["priority"]: "0"})
    assert r.returncode == 0, r.stderr
    g = _line(r.stdout, REPORT_PREFIX)
    if g["missing"]:
        pytest.skip(f"this process may not use real-time settings here: {g['missing']}")
    assert g["fifo_priority"] is None and g["fifo_threads"] == [] and g["nice"] == OFF_LOOP_NICE == -10
    assert g["memory_locked"] and g["timer_slack_ns"] == 1000 and g["rt_budget_ms"] is None
    assert _line(r.stdout, "CHILD ")["policy"] == os.SCHED_OTHER
    assert _line(r.stdout, "NICE ")["nices"] == [-10]


def test_blas_computes_on_the_loop_thread_only():
    """numpy's and scipy's OpenBLAS get one thread: a FIFO loop thread must never spin for its normal-priority
    workers (at SCHED_FIFO beside two busy processes one expm took up to 111 ms that way; realtime docstring)."""
    code = textwrap.dedent("""
        import ctypes, json, os
        import numpy, scipy.linalg
        from dem_ros.realtime import enter_loop
        g = enter_loop(report=False)
        n = {}
        for lib in {l.split(None, 5)[5].strip() for l in open("/proc/self/maps") if "openblas" in l}:
            h = ctypes.CDLL(lib)
            for name in ("openblas_get_num_threads", "openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                         "scipy_openblas_get_num_threads64_"):
                if hasattr(h, name):
                    n[os.path.basename(lib)] = getattr(h, name)()
                    break
        print("CHILD " + json.dumps({"set": g.blas_single_thread, "threads": n,
                                     "env": os.environ["OPENBLAS_NUM_THREADS"]}))
    """)
    r = _run_child(code, {"OPENBLAS_NUM_THREADS": "4"})
    assert r.returncode == 0, r.stderr
    child = _line(r.stdout, "CHILD ")
    assert child["threads"] and set(child["threads"].values()) == {1}, child
    assert sorted(child["set"]) == sorted(child["threads"]) and child["env"] == "1", child


def test_rt_off_leaves_the_process_alone():
    r = _run_child(LOOP_CHILD, {ENV["enabled"]: "0"})
    assert r.returncode == 0 and r.stderr.strip() == "", r.stderr
    g = _line(r.stdout, REPORT_PREFIX)
    assert not g["requested"] and g["fifo_priority"] is None and g["missing"] == []
    child = _line(r.stdout, "CHILD ")
    assert child["policy"] == os.SCHED_OTHER and child["gc_enabled"]  # frozen, but collections as usual


#: the composed graph in this process (what ``dem-ros node container`` runs), then what the loop left
GRAPH_CHILD = textwrap.dedent("""
    import gc, json, sys, time
    from pathlib import Path
    from dem_ros.core.scenarios import get_scenario
    from dem_ros.tools.launcher import write_params_file
    from dem_ros.nodes import container
    cfg = {g: dict(v) for g, v in get_scenario("S1").config().items()}
    cfg["plant_sim"].update(duration=2.0, preroll=0.2, lockstep=True)
    params = write_params_file(cfg, Path(sys.argv[1]))
    wall, cpu = time.monotonic(), time.process_time()
    code = container.main(["--transport", "dds", "--ros-args", "--params-file", str(params)])
    wall, cpu = time.monotonic() - wall, time.process_time() - cpu
    print("CHILD " + json.dumps({"code": code, "cyclic_garbage": gc.collect(), "cpu_share": cpu / wall}))
""")


@needs_setpriv
def test_graph_without_rt_permission_warns_once_runs_and_leaves_no_cyclic_garbage(tmp_path):
    """The container as an ordinary user: one warning, the run completes; the loop made no
    reference cycles (automatic collection was off the whole run) and never spun."""
    env = {"ROS_DOMAIN_ID": str(domains.hold()),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    r = subprocess.run([*UNPRIVILEGED, sys.executable, "-c", GRAPH_CHILD, str(tmp_path / "params.yaml")],
                       env={**os.environ, "PYTHONPATH": str(ROOT), **env}, capture_output=True, text=True,
                       timeout=300, cwd=ROOT)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-3000:]
    warnings = [ln for ln in out.splitlines() if "real time" in ln and "warning" in ln]
    assert len(warnings) == 1, out[-3000:]
    assert "finished 2 s" in out, out[-3000:]
    child = _line(r.stdout, "CHILD ")
    assert child["code"] == 0
    # ~2200 loop cycles: a cycle per sample would leave thousands of objects; shutdown leaves a few
    assert child["cyclic_garbage"] < 500, child
    assert child["cpu_share"] < 0.9, child  # the loop sleeps between samples


def _stall(monitor, work) -> dict:
    """One dispatch round due now that does ``work()`` before it ends; the STALL line it reported."""
    lines: list[str] = []
    monitor._write = lines.append
    due = time.monotonic_ns()
    work()
    monitor.round(due, time.monotonic_ns())
    assert len(lines) == 1 and lines[0].startswith("STALL "), lines
    return json.loads(lines[0][6:])


def test_a_stall_is_split_into_computing_and_asleep_as_the_kernel_counted_it():
    """Robust on a loaded machine: the monitor's ``running`` is the thread's own CPU time over
    the stall (whatever share of it a busy neighbour took, which goes to ``runnable``), and a
    thread asleep is ``blocked`` for its sleep."""
    m = StallMonitor(stall_ms=5.0)
    m.round(time.monotonic_ns(), time.monotonic_ns())  # an ordinary round: no report
    assert m.stalls == 0
    cpu0 = time.thread_time_ns()
    e = _stall(m, lambda: _spin_for(0.03))
    cpu_ms = (time.thread_time_ns() - cpu0) / 1e6
    assert e["ms"] >= 30 and abs(e["running_ms"] - cpu_ms) < 5.0, (e, cpu_ms)
    assert e["running_ms"] + e["runnable_ms"] + e["blocked_ms"] >= e["ms"] - 0.1, e
    e = _stall(m, lambda: time.sleep(0.03))
    # asleep: "blocked", or "stolen" if the host took this vCPU for half of it meanwhile (a busy VM)
    assert e["cause"] in ("blocked", "stolen") and e["blocked_ms"] >= 25 and e["running_ms"] < 5, e
    s = m.summary()
    assert s["stalls"] == 2 and s["longest"]["ms"] >= 30
    assert s["sched_rt_period_us"] > 0


def _spin_for(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


#: a loop thread at SCHED_FIFO 10 on CPU 0 computes 15 ms while a FIFO 20 process spins 40 ms on the same CPU
RUNNABLE_CHILD = textwrap.dedent("""
    import json, os, subprocess, sys, time
    from dem_ros.realtime import StallMonitor
    os.sched_setaffinity(0, {0})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    hog = subprocess.Popen([sys.executable, "-c", "import os, sys, time; os.sched_setaffinity(0, {0});"
                            " os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(20)); print('ready', flush=True);"
                            " sys.stdin.read(1); end = time.monotonic() + 0.04\\nwhile time.monotonic() < end: pass"],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    assert hog.stdout.readline() == b"ready\\n"  # FIFO 20 on CPU 0, asleep on its stdin
    lines = []
    m = StallMonitor(5.0, write=lines.append)
    due = time.monotonic_ns()
    hog.stdin.write(b"x"); hog.stdin.flush()  # it wakes and takes CPU 0 for 40 ms
    end = time.thread_time() + 0.015  # 15 ms of our own CPU time, and whatever the hog takes
    while time.thread_time() < end:
        pass
    m.round(due, time.monotonic_ns())
    hog.wait()
    print("CHILD " + lines[0][6:])
""")


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO for the test's processes needs root (CAP_SYS_NICE)")
def test_a_stall_spent_preempted_by_a_higher_priority_thread_is_runnable():
    r = _run_child(RUNNABLE_CHILD)
    assert r.returncode == 0, r.stderr[-2000:]
    e = _line(r.stdout, "CHILD ")
    assert e["cause"] == "runnable" and e["runnable_ms"] >= 30 and e["running_ms"] < 25, e


#: a loop thread that spins at SCHED_FIFO instead of sleeping, then reports its scheduling
SPIN_CHILD = textwrap.dedent("""
    import json, os, time
    from dem_ros.realtime import enter_loop
    g = enter_loop(report=False)
    end = time.monotonic() + 0.6  # 600 ms without sleeping: three times the RT budget
    while time.monotonic() < end:
        pass
    print("CHILD " + json.dumps({"budget": g.rt_budget_ms, "fifo": g.fifo_priority,
                                 "policy_after": os.sched_getscheduler(0)}))
""")


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO for the test's process needs root (CAP_SYS_NICE)")
def test_a_real_time_thread_that_stops_sleeping_is_put_back_to_normal_scheduling():
    """RLIMIT_RTTIME: the SIGXCPU handler leaves real time (one error line) and the process runs on,
    instead of spinning at SCHED_FIFO into the kernel's RT throttling."""
    r = _run_child(SPIN_CHILD)
    assert r.returncode == 0, r.stderr[-2000:]
    child = _line(r.stdout, "CHILD ")
    assert child["fifo"] == 50 and child["budget"] == 200
    assert child["policy_after"] == os.SCHED_OTHER, child
    lines = [ln for ln in r.stderr.splitlines() if "ran 200 ms without sleeping" in ln]
    assert len(lines) == 1, r.stderr


def test_leave_loop_is_idempotent_and_counts_what_it_changed():
    code = textwrap.dedent("""
        import os
        from dem_ros.realtime import enter_loop, leave_loop
        g = enter_loop(report=False)
        print("CHILD", g.fifo_priority is not None and leave_loop() >= 1, leave_loop(), os.sched_getscheduler(0))
    """)
    r = _run_child(code)
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("CHILD")).split()
    assert line[1] == ("True" if os.geteuid() == 0 else "False") and line[2] == "0" and int(line[3]) == os.SCHED_OTHER


@pytest.mark.skipif(os.geteuid() != 0, reason="changing kernel threads' scheduling needs root (CAP_SYS_NICE)")
def test_tty_workers_run_at_fifo_meanwhile_and_get_their_policy_back():
    from dem_ros.realtime import TTY_WORKERS_PREFIX, tty_workers_fifo

    def workers() -> dict[int, int]:
        out = {}
        for pid in os.listdir("/proc"):
            with contextlib.suppress(OSError):
                if pid.isdigit() and Path(f"/proc/{pid}/comm").read_text().startswith(TTY_WORKERS_PREFIX):
                    out[int(pid)] = os.sched_getscheduler(int(pid))
        return out

    pre = workers()
    with tty_workers_fifo(1) as changed:
        during = workers()
    if not changed:
        pytest.skip("this kernel has no kworker/u threads right now")
    assert all(during[t] == os.SCHED_FIFO for t in changed if t in during), during
    post = workers()
    assert ({t: post[t] for t in changed if t in post and t in pre}
            == {t: pre[t] for t in changed if t in post and t in pre})


def test_the_tty_workers_wrapper_runs_the_command_and_passes_its_exit_code():
    r = subprocess.run([sys.executable, "-m", "dem_ros.realtime", "--tty-workers-fifo", "1", "--", sys.executable, "-c",
                        "raise SystemExit(7)"], env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True,
                       text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 7 and "tty workers:" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-m", "dem_ros.realtime", "--tty-workers-fifo", "1"],
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=120,
                       cwd=ROOT)
    assert r.returncode == 2 and "a command after --" in r.stderr and "Traceback" not in r.stderr
