"""dem_ros.realtime: what a process asks for, what it gets, and the one-line fallback.

The fallback is tested for real: a child process runs without CAP_SYS_NICE / CAP_IPC_LOCK
(dropped from its bounding set by util-linux ``setpriv``) and with RLIMIT_RTPRIO 0 and a
64 KiB RLIMIT_MEMLOCK (``prlimit``), exactly what an ordinary user gets by default.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import domains
import pytest

from dem_ros.realtime import ENV, REPORT_PREFIX, RtConfig, RtConfigError, config_from_env

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
    ("priority", "0", "1..99"),
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
