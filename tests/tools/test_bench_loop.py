"""``dem-ros bench loop``: the flags reach the graph and the JSON carries loop, holds, landing, rt.

A figure here is not a benchmark (the machine is shared): the test checks what the command
reports and that it cleans up, not how fast the loop is.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: seconds of the machine-floor probe here (the command's FLOOR_S is 10): what the test checks is that the probe
#: runs and is reported, not its figures, which 2 s of 1 kHz wake-ups give as well
FLOOR_S = 2.0
#: the command line, with the floor probe's length set first: ``dem-ros bench loop ARGS`` otherwise
CLI = ("import sys; from dem_ros.tools import bench, cli; bench.FLOOR_S = float(sys.argv[1]);"
       " sys.exit(cli.main(sys.argv[2:]))")


def _bench(tmp_path: Path, *flags: str) -> tuple[subprocess.CompletedProcess, dict | None]:
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, "-c", CLI, str(FLOOR_S), "bench", "loop", *flags, "--json", str(out)],
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=600,
                       cwd=ROOT)
    return r, (json.loads(out.read_text()) if out.exists() else None)


def _busy_pids() -> set[int]:
    pids = set()
    for d in Path("/proc").iterdir():
        try:
            if d.name.isdigit() and b"while True: pass" in (d / "cmdline").read_bytes():
                pids.add(int(d.name))
        except OSError:
            pass
    return pids


def test_bench_loop_composed_free_run_under_load_reports_what_it_ran(tmp_path):
    before = _busy_pids()
    r, res = _bench(tmp_path, "--compose", "--free-run", "--duration", "2", "--load", "1")
    assert r.returncode == 0 and res is not None, r.stdout[-3000:] + r.stderr[-3000:]
    assert res["composed"] and res["free_run"] and res["load_processes"] == 1
    loop = res["loop"]
    assert loop["cycles"] == 2000 and not loop["lockstep"], loop
    assert {"deadline_misses", "latency_us", "cpu_percent"} <= set(loop)
    assert {"holds", "landing", "rt", "timer_floor", "peer", "rms_error_um", "offline_rms_error_um"} <= set(res)
    assert set(res["rt"]) == {"container"} and res["rt"]["container"]["requested"]
    if res["peer"].get("skipped"):
        assert "rclpy" in res["peer"]["skipped"]
    else:  # the same graph on rclpy, side by side with dds
        assert res["peer"]["transport"] == "rclpy" and res["peer"]["loop"]["cycles"] == 2000, res["peer"]
        assert set(res["peer"]["rt"]) == {"container"}
        assert "side by side" in r.stdout and "rclpy/dds" in r.stdout and "[rclpy] latency" in r.stdout, r.stdout
    assert "machine floor" in r.stdout and "busy processes beside it" in r.stdout
    assert f"sleep loop with the same real-time settings, {FLOOR_S:g} s before the run" in r.stdout
    assert _busy_pids() <= before, "the --load processes outlived the benchmark"


def test_bench_loop_refuses_a_negative_load(tmp_path):
    r, _ = _bench(tmp_path, "--load", "-1", "--duration", "1")
    assert r.returncode == 2 and "--load -1" in r.stderr and "Traceback" not in r.stderr, r.stderr
