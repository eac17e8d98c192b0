"""Summaries a control engineer reads at a glance: no nan, waits are waits, standard JSON, the laws used."""

import json
import math

import numpy as np
import pytest

from dem_ros.core.scenarios import get_scenario
from dem_ros.core.simulate import simulate
from dem_ros.tools.common import json_safe, json_text, write_json
from dem_ros.tools.runmetrics import LoopStats, RunMetrics, tracking_text
from dem_ros.tools.verdict import RunFacts, judge


def _strict_loads(text: str):
    """json.loads that rejects NaN / Infinity (what strict parsers do)."""
    def reject(name: str):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=reject)


@pytest.fixture(scope="module")
def short_run() -> RunMetrics:
    """A 1 s offline run: shorter than 40 s, so 'RMS error after 40 s' does not apply."""
    cfg = get_scenario("S1").config()
    return RunMetrics.from_sim(simulate(cfg, controller="adaptive", estimator="none", duration=1.0, scenario="S1"))


def test_metrics_that_do_not_apply_are_omitted_not_nan(short_run):
    assert all(math.isnan(v) for v in short_run.rms_error_after_40s_um)  # the fact: no samples after 40 s
    short_run.loop = LoopStats(cycles=0, deadline_misses=0,
                               latency_us={"p50": math.nan, "p99": math.nan, "max": math.nan})
    text = short_run.format()
    assert "nan" not in text.lower()
    assert "after 40 s" not in text and "latency" not in text
    assert "RMS error e1 / e2 [um]" in text


def test_a_run_without_a_sample_from_t0_has_no_error_figures_not_nan():
    """A plate that landed in the pre-roll (bench loop on rclpy, free-running, under load): no sample with
    gap and reference from t = 0, so no RMS or max error; the summary and the bench line leave them out."""
    nan2 = [math.nan, math.nan]
    m = RunMetrics(scenario="S1", controller="adaptive", estimator="kf", transport="rclpy", error_source="truth",
                   samples=0, failed=True, fail_time_s=0.111, rms_error_um=nan2, max_error_um=nan2,
                   rms_error_after_40s_um=nan2, peak_voltage_v=math.nan,
                   loop=LoopStats(cycles=111, deadline_misses=40, latency_us={"p50": 900.0, "p99": 5e3, "max": 9e3},
                                  landing=True, landing_reason="command lost"))
    m.set_verdict(judge(RunFacts(planned_samples=3000, samples=0, reached_t0=False, landing=(-0.889, "command lost"))))
    text = m.format()
    assert "nan" not in text.lower(), text
    assert "RMS error" not in text and "max error" not in text and "peak |u|" not in text
    assert "landing: yes (command lost)" in text
    assert text.splitlines()[0].split(None, 2)[:2] == ["verdict", "failed:"] and "never reached t = 0" in text
    assert tracking_text(nan2, [1.0, 2.0]) is None
    assert tracking_text([1.234, 5.0], nan2) == "1.23 / 5.00"
    assert tracking_text([1.234, 5.0], [1.0, 2.0]) == "1.23 / 5.00 (offline, same timing: 1.00 / 2.00)"
    assert tracking_text([1.0, 2.0], None) == "1.00 / 2.00"


def test_lockstep_waits_are_reported_as_waits_not_misses():
    lock = LoopStats(cycles=30000, deadline_misses=30000, latency_us={"p50": 600.0, "p99": 1200.0, "max": 9000.0},
                     realtime_factor=0.9, lockstep=True)
    text = lock.summary()
    assert "miss" not in text
    assert "plant waited for the command in 30000 (100.0 %)" in text and "(lockstep)" in text
    free = LoopStats(cycles=1000, deadline_misses=3, latency_us={"p50": 120.0, "p99": 480.0, "max": 900.0})
    assert "deadline misses 3 (0.300 %)" in free.summary()
    # a count above the cycles (Ctrl-C between two status messages) is never over 100 %
    over = LoopStats(cycles=300, deadline_misses=301, latency_us={"p50": 1.0, "p99": 1.0, "max": 1.0}, lockstep=True)
    assert "(100.0 %)" in over.summary()


def test_the_summary_names_every_law_that_ran(short_run):
    short_run.controllers_used = ["adaptive", "nonlinear_decoupling"]
    assert "S1 / adaptive -> nonlinear_decoupling / none" in short_run.format()
    short_run.controllers_used = None
    assert "S1 / adaptive / none" in short_run.format()


def test_json_is_standard_null_not_nan(short_run, tmp_path):
    path = write_json(tmp_path / "m.json", short_run.to_dict())
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    d = _strict_loads(text)
    assert d["rms_error_after_40s_um"] == [None, None]
    assert d["rms_error_um"] == pytest.approx(short_run.rms_error_um, rel=1e-12)  # finite figures unchanged


def test_json_safe_converts_numpy_and_non_finite_values():
    obj = {"a": np.float64("nan"), "b": [np.int64(3), float("inf"), -float("inf"), 1.5], "c": (np.float32(2.0),),
           "d": "nan", 4: None}
    assert json_safe(obj) == {"a": None, "b": [3, None, None, 1.5], "c": [2.0], "d": "nan", "4": None}
    assert _strict_loads(json_text(obj))["b"] == [3, None, None, 1.5]
