"""RunMetrics: one set of figures for sim, launch and replay, whatever produced the run."""

import json
import math
import subprocess
import sys

import pytest

from dem_ros.core.scenarios import get_scenario
from dem_ros.core.simulate import simulate
from dem_ros.tools.offline_bag import record_result
from dem_ros.tools.runmetrics import LoopStats, RunMetrics, load_run


@pytest.fixture(scope="module")
def offline_run():
    cfg = get_scenario("S1").config()
    return simulate(cfg, controller="adaptive", estimator="none", duration=1.0, scenario="S1")


def test_a_recorded_offline_run_reads_back_to_the_figures_of_the_run(offline_run, tmp_path):
    """The bag path (launch, replay) and the result path (sim) give the same numbers for one run."""
    direct = RunMetrics.from_sim(offline_run)
    bag = record_result(offline_run, tmp_path)
    read, series = load_run(bag)
    assert read.samples == direct.samples == 1000
    assert read.rms_error_um == pytest.approx(direct.rms_error_um, rel=1e-12)
    assert read.max_error_um == pytest.approx(direct.max_error_um, rel=1e-12)
    assert read.peak_voltage_v == pytest.approx(direct.peak_voltage_v, rel=1e-12)
    assert read.peak_current_a == pytest.approx(direct.peak_current_a, rel=1e-12)
    assert read.final_estimates == pytest.approx(direct.final_estimates, rel=1e-12)
    assert (read.failed, read.error_source, read.transport) == (False, "truth", "offline")
    assert read.loop is not None and read.loop.cycles == 1000 and read.loop.deadline_misses == 0
    assert series["e"].shape == (1000, 2)


def test_the_laws_are_read_from_the_controller_status_by_its_name_now_and_its_former_name(offline_run, tmp_path,
                                                                                          monkeypatch):
    """A bag recorded before the statuses were named "<node>: <task>" (the controller's was "controller") is still
    a dem_ros run: its laws are read from either name (here one of each, in order)."""
    from dem_ros import contract
    from dem_ros.nodes import common

    real = common.diag_array

    def with_controller_statuses(DA, DS, KV, t_ns, *args, **kw):
        arr = real(DA, DS, KV, t_ns, *args, **kw)
        arr.status = [*arr.status, *(common.diag_status(DS, KV, name, 0, "ok", {"law": law}) for name, law in
                                     (("controller", "adaptive"), (contract.CONTROLLER_STATUS, "paper")))]
        return arr

    monkeypatch.setattr(common, "diag_array", with_controller_statuses)
    read, _ = load_run(record_result(offline_run, tmp_path))
    assert read.controllers_used == ["adaptive", "paper"]


def test_the_table_and_the_json_carry_the_same_figures(offline_run):
    m = RunMetrics.from_sim(offline_run)
    m.loop = LoopStats(cycles=1000, deadline_misses=3, latency_us={"p50": 120.0, "p99": 480.0, "max": 900.0},
                       cpu_percent={"plant_sim": 40.0, "controller": 20.0})
    text = m.format(extra=[("bag", "/x")])
    rms = " / ".join(f"{v:.2f}" for v in m.rms_error_um)
    assert f"RMS error e1 / e2 [um]             {rms}" in text
    assert ("deadline misses 3 (0.300 %)" in text and "total 60.0" in text
            and text.endswith("bag                                /x"))
    d = json.loads(json.dumps(m.to_dict()))
    assert d["rms_error_um"] == m.rms_error_um and d["loop"]["latency_us"]["p99"] == 480.0
    assert d["loop"]["cpu_percent"] == {"plant_sim": 40.0, "controller": 20.0}


def test_loop_status_strings_parse_and_missing_values_are_nan():
    L = LoopStats.from_status({"cycles": "5", "deadline_misses": "1", "latency_p50_us": "10.5", "epoch_ns": "7",
                               "cpu_s": "1.0", "wall_s": "4.0", "lockstep": "True"})
    assert (L.cycles, L.deadline_misses, L.epoch_ns, L.plant_cpu_percent, L.lockstep) == (5, 1, 7, 25.0, True)
    assert L.latency_us["p50"] == 10.5 and math.isnan(L.latency_us["max"]) and math.isnan(L.realtime_factor)


def test_sim_help_states_the_configured_command_delay():
    from dem_ros.core.params import SCHEMA

    r = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "sim", "--help"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    d = SCHEMA.spec("plant_sim", "command_delay").default
    assert d == 1 and f"command_delay = {d}" in " ".join(r.stdout.split())
