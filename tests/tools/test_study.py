"""dem-ros study: axes against the schema, the plan, results on real Dask clusters on loopback.

Clusters are real: a ``LocalCluster`` of worker processes (through the command), and
separate ``dask scheduler`` + ``dask worker`` processes started here. Runs are short
(0.3 s of simulated time) so that the tests measure behaviour, not speed.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dem_ros.core.params import ConfigError, apply_overrides
from dem_ros.core.scenarios import get_scenario
from dem_ros.core.simulate import simulate
from dem_ros.tools import study as st
from dem_ros.tools.study.run import _warm_worker

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
CMD = [sys.executable, "-m", "dem_ros.tools.cli", "study"]


@pytest.fixture(scope="module", autouse=True)
def kernels():
    """Compile (or load) the kernels once here: the processes started below share the cache
    (NUMBA_CACHE_DIR, set on importing dem_ros.tools), so their time limits cover loading, not a
    first compile of minutes on a busy machine."""
    _warm_worker()


@pytest.fixture(scope="module")
def base():
    return get_scenario("S1").config()


def _rows(path: Path) -> list[dict[str, str]]:
    with (path / "results.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def _run(args, timeout=240):
    return subprocess.run(CMD + args, capture_output=True, text=True, timeout=timeout, env=ENV, cwd=ROOT)


# --- axes ---------------------------------------------------------------------------------
def test_axis_grid_list_and_relative_values(base):
    assert st.parse_axis("plant_sim.m=10:25:4", base).values == (10.0, 15.0, 20.0, 25.0)
    assert st.parse_axis("plant_sim.R=-20%,0%,+25%", base).values == (16.0, 20.0, 25.0)
    k = st.parse_axis("plant_sim.K=-20%:+20%:3", base).values
    assert k == pytest.approx((0.8 * 4.374e-4, 4.374e-4, 1.2 * 4.374e-4), rel=1e-12)
    d = st.parse_axis("plant_sim.command_delay=0:2", base)
    assert d.values == (0, 1, 2) and all(type(v) is int for v in d.values)
    mc = st.parse_axis("plant_sim.m=10:25", base, monte_carlo=True)
    assert mc.values is None and (mc.low, mc.high) == (10.0, 25.0)
    assert st.parse_axis("plant_sim.m=10:25:4", base).unit == "kg"


@pytest.mark.parametrize("text, words", [
    ("plant_sim.m=0:25:3", ["plant_sim.m", "got 0.0", "[0.1, 10000] kg"]),
    ("plant_sim.mass=1,2", ["plant_sim.mass", "unknown parameter", "known:"]),
    ("plant.m=1,2", ["unknown group 'plant'"]),
    ("plant_sim.m=10:25", ["needs a count", "10:25:4"]),
    ("plant_sim.m=25:10:3", ["LO = 25 must not exceed HI = 10"]),
    ("plant_sim.m=a,b", ["'a' is not a number"]),
    ("plant_sim.m=10:20:x", ["count 'x' is not an integer"]),
    ("plant_sim.m=10,10", ["repeated values"]),
    ("plant_sim.command_delay=0:9", ["plant_sim.command_delay", "got 9", "[0, 8]"]),
    ("plant_sim.command_delay=0:1:3", ["does not give integers"]),
    ("plant_sim.dt=1e-3,2e-3", ["read-only"]),
    ("controller.type=adaptive", ["--controllers"]),
    ("plant_sim.m", ["expected NAME=SPEC"]),
    ("plant_sim.mass_delta=-10%,+10%", ["relative value", "non-zero value in the scenario"]),
    ("plant_sim.command_delay=-10%,0%", ["relative value (%) needs a float parameter"]),
])
def test_bad_axis_names_the_field_and_what_is_allowed(base, text, words):
    with pytest.raises(ConfigError) as exc:
        st.parse_axis(text, base)
    msg = str(exc.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


def _spec(base, axes, samples=None, controllers=("adaptive",), duration=0.3, seed=1):
    return st.StudySpec("S1", base, tuple(st.parse_axis(a, base, samples is not None) for a in axes),
                        tuple(controllers), None, duration, seed, samples)


def test_plan_applies_cells_through_the_schema(base):
    jobs = st.plan_runs(_spec(base, ["plant_sim.m=10:25:4", "plant_sim.R=-20%,+25%"],
                              controllers=("adaptive", "decentralized_pid")))
    assert len(jobs) == 4 * 2 * 2
    assert len({j["run_id"] for j in jobs}) == len(jobs)
    j = next(j for j in jobs
             if j["values"] == {"plant_sim.m": 25.0, "plant_sim.R": 25.0} and j["controller"] == "adaptive")
    assert j["cfg"]["plant_sim"]["m"] == 25.0 and j["cfg"]["plant_sim"]["R"] == 25.0
    assert j["cfg"]["estimator"]["R"] == 20.0  # truth only: the estimator's model is untouched
    # a cell that breaks a cross-field rule is refused before anything runs, naming the cell
    with pytest.raises(ConfigError, match=r"study cell \(plant_sim.gap0=0.04\).*gap_max"):
        st.plan_runs(_spec(base, ["plant_sim.gap0=0.008,0.04"]))


def test_monte_carlo_is_seeded_and_a_larger_sample_extends_a_smaller_one(base):
    axes = ["plant_sim.m=10:25", "plant_sim.K=-20%:+20%", "plant_sim.command_delay=0:2"]
    a = st.plan_runs(_spec(base, axes, samples=20, seed=7))
    b = st.plan_runs(_spec(base, axes, samples=50, seed=7))
    c = st.plan_runs(_spec(base, axes, samples=20, seed=8))
    assert [j["run_id"] for j in a] == [j["run_id"] for j in b[:20]]
    assert [j["values"] for j in a] != [j["values"] for j in c]
    m = np.array([j["values"]["plant_sim.m"] for j in b])
    assert m.min() >= 10.0 and m.max() <= 25.0 and m.std() > 2.0
    assert {j["values"]["plant_sim.command_delay"] for j in b} == {0, 1, 2}
    assert len({j["seed"] for j in b}) == 50  # independent noise per sample


def test_hover_asymmetry_sets_both_gaps(base):
    jobs = st.plan_runs(_spec(base, ["hover_asymmetry=-0.5e-3:0.5e-3:3"]))
    pcs = [j["cfg"]["plant_sim"] for j in jobs]
    assert [g for p in pcs for g in (p["d1_0"], p["d2_0"])] == pytest.approx(
        [0.0075, 0.0085, 0.008, 0.008, 0.0085, 0.0075])


def test_a_run_is_the_simulator_run_of_its_cell(base):
    """run_chunk adds nothing to the physics: its row is simulate() of the cell's config."""
    job = next(j for j in st.plan_runs(_spec(base, ["plant_sim.R=18,22"])) if j["values"]["plant_sim.R"] == 18.0)
    (row,) = st.run_chunk([job])
    ref = simulate(apply_overrides(base, {"plant_sim": {"R": 18.0}}), controller="adaptive", duration=0.3).metrics()
    assert [row["rms_e1_um"], row["rms_e2_um"]] == ref["rms_error_um"]
    assert [row["max_e1_um"], row["max_e2_um"]] == ref["max_error_um"]
    assert row["peak_voltage_v"] == ref["peak_voltage_v"]
    nominal = simulate(base, controller="adaptive", duration=0.3).metrics()
    # the axis reached the plant: the hover voltage R i0 is 18/20 of the nominal one
    assert ref["peak_voltage_v"] == pytest.approx(0.9 * nominal["peak_voltage_v"], rel=1e-3)


# --- the command on a LocalCluster -----------------------------------------------------------
def test_study_on_a_local_cluster_writes_rows_maps_and_resumes(tmp_path):
    out = tmp_path / "st"
    args = ["--axis", "plant_sim.m=10:25:2", "--axis", "plant_sim.R=-20%,+25%",
            "--controllers", "adaptive,nonlinear_decoupling", "--duration", "0.3", "--workers", "2", "--out", str(out)]
    r = _run(args)
    assert r.returncode == 0, r.stderr
    rows = _rows(out)
    assert len(rows) == 8 and len({x["run_id"] for x in rows}) == 8
    assert len({x["worker"] for x in rows}) >= 1
    assert "8/8 runs" in r.stderr  # the progress bar
    assert "8 runs on 2 workers" in r.stdout
    for c in ("adaptive", "nonlinear_decoupling"):
        png = out / f"map_{c}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = (out / "summary.md").read_text()
    assert "| `adaptive` | 4 |" in summary
    doc = json.loads((out / "study.json").read_text())
    assert doc["last_session"]["workers"] == 2 and doc["last_session"]["ran"] == 8
    section = "\n".join(st.report_section(out))  # what dem-ros report shows for <report>/study
    assert "| `adaptive` | 4 |" in section and f"({out.name}/map_adaptive.png)" in section
    assert "No study in `nothing/`" in "\n".join(st.report_section(tmp_path / "nothing"))

    # same command again: nothing re-runs
    r2 = _run(args)
    assert r2.returncode == 0, r2.stderr
    assert "8 runs already in" in r2.stdout and "runs on" not in r2.stdout
    assert _rows(out) == rows

    # a run killed mid-write leaves a torn line: it is dropped and only that run is redone
    text = (out / "results.csv").read_text().splitlines(keepends=True)
    (out / "results.csv").write_text("".join(text[:-1]) + text[-1][: len(text[-1]) // 2])
    r3 = _run([*args, "--workers", "1"])
    assert r3.returncode == 0, r3.stderr
    assert "7 runs already in" in r3.stdout and "1 runs on 1 workers" in r3.stdout
    again = {x["run_id"]: x for x in _rows(out)}
    assert set(again) == {x["run_id"] for x in rows}
    lost = rows[-1]
    assert again[lost["run_id"]]["rms_e1_um"] == lost["rms_e1_um"]  # deterministic: the same number again

    # the table shows the runs of the last command in the directory (study.json), not every row
    doc = json.loads((out / "study.json").read_text())
    assert sorted(doc["run_ids"]) == sorted(again)
    doc["run_ids"] = [x["run_id"] for x in rows if x["controller"] == "adaptive"][:3]
    (out / "study.json").write_text(json.dumps(doc))
    table = st.robustness_table(out)
    assert "| `adaptive` | 3 |" in table and "nonlinear_decoupling" not in table


def test_results_of_another_study_are_not_mixed_in(tmp_path, base):
    out = tmp_path / "st"
    out.mkdir()
    (out / "results.csv").write_text("run_id,controller,estimator,seed,duration_s,plant_sim.K,"
                                     + ",".join(st.RESULT_FIELDS) + "\n")
    r = _run(["--axis", "plant_sim.m=10,12", "--duration", "0.3", "--workers", "1", "--out", str(out)])
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "holds another study (columns plant_sim.K)" in r.stderr


# --- the command against separate scheduler and worker processes ------------------------------
def _dask_cli() -> Path | None:
    p = Path(sys.executable).parent / "dask"
    return p if p.is_file() else None


@pytest.mark.skipif(_dask_cli() is None,
                    reason="the dask command line (dask scheduler / dask worker) is not installed beside python")
def test_study_against_a_separate_scheduler_and_worker(tmp_path):
    dask = str(_dask_cli())
    sched_file = tmp_path / "scheduler.json"
    procs = []
    try:
        procs.append(subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                       "--scheduler-file", str(sched_file)], env=ENV, cwd=tmp_path,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        deadline = time.monotonic() + 60
        while not sched_file.is_file() and time.monotonic() < deadline:
            assert procs[0].poll() is None, "dask scheduler exited"
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "2", "--nthreads", "1", "--no-dashboard",
                                       "--host", "127.0.0.1"], env=ENV, cwd=tmp_path,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        from distributed import Client

        with Client(address, timeout=60) as c:  # both worker processes joined: the count below is fixed
            c.wait_for_workers(2, timeout=60)
        out = tmp_path / "st"
        r = _run(["--axis", "plant_sim.m=10:25:3", "--duration", "0.3", "--scheduler", address, "--timeout", "60",
                  "--out", str(out)])
        assert r.returncode == 0, r.stderr
        rows = _rows(out)
        assert len(rows) == 3 and all(x["failed"] == "0" for x in rows)
        assert "3 runs on 2 workers" in r.stdout
        assert json.loads((out / "study.json").read_text())["last_session"]["scheduler"] == address
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)


# --- bad arguments --------------------------------------------------------------------------
@pytest.mark.parametrize("args, words", [
    ([], ["at least one --axis"]),
    (["--axis", "plant_sim.m=0,10"], ["plant_sim.m", "got 0", "[0.1, 10000] kg"]),
    (["--axis", "plant_sim.m=10,12", "--workers", "0"], ["--workers", "got '0'"]),
    (["--axis", "plant_sim.m=10,12", "--controllers", "adaptive,pd"], ["unknown 'pd'"]),
    (["--axis", "plant_sim.m=10,12", "--scheduler", "localhost:8786"], ["tcp://HOST:PORT"]),
    (["--axis", "plant_sim.m=10,12", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"],
     ["--workers applies to the local cluster"]),
    (["--axis", "plant_sim.m=10,12", "--samples", "-3"], ["--samples", "got '-3'"]),
    (["--axis", "plant_sim.m=10,12", "--map", "plant_sim.R"], ["not an axis of this study"]),
    (["--axis", "plant_sim.m=10,12", "--preset", "nope"], ["unknown 'nope'"]),
    (["--axis", "plant_sim.m=10,12", "--duration", "nan"], ["--duration"]),
])
def test_bad_arguments_give_one_line_and_exit_2(tmp_path, args, words):
    r = _run([*args, "--out", str(tmp_path / "st")], timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("dem-ros study: error: "), r.stderr
    for w in words:
        assert w in r.stderr, r.stderr
    assert not (tmp_path / "st").exists()  # nothing started


def test_an_unreachable_scheduler_is_one_line_within_the_timeout(tmp_path):
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    r = _run(["--axis", "plant_sim.m=10,12", "--duration", "0.3", "--scheduler", f"tcp://127.0.0.1:{port}",
              "--timeout", "3", "--out", str(tmp_path / "st")], timeout=120)
    assert r.returncode == 2, r.stderr
    # progress lines may come first (a loaded machine takes over a second to get there); the error is one line
    errors = [ln for ln in r.stderr.splitlines() if not ln.startswith("dem-ros study: [")]
    assert len(errors) == 1 and f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port}" in errors[0], r.stderr
    assert "Traceback" not in r.stderr
    assert time.monotonic() - t0 < 60
