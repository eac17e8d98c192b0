"""Replay's figures: one plotting path with ``dem-ros sim``'s, every signal on the experiment clock."""

from pathlib import Path

import numpy as np
import pytest

from dem_ros.tools.plots import RunSignals, plot_signals
from dem_ros.tools.replay import analyse, plot_what_if, replay_signals, what_if

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_S1"  # 8 s of S1 from the graph, after a 1 s pre-roll
DT = 1e-3  # the sample period [s]


@pytest.fixture(scope="module")
def recorded():
    m, series = analyse(SAMPLE)
    return m, series, replay_signals(series, m)


def test_every_signal_is_on_the_experiment_clock(recorded):
    m, _series, sig = recorded
    assert sig.t[0] == 0.0 and sig.t[-1] == pytest.approx((m.samples - 1) * DT)
    end = sig.t[-1] + DT
    # commands, latencies and estimates from t = 0 (the pre-roll is not drawn), up to the end of the run
    for tt in (sig.u_t, sig.latency_t, sig.est_t):
        assert tt is not None and 0.0 <= tt.min() <= DT and tt.max() <= end
    # the plant's loop status, once a second: t_sim_s, not the recorder's arrival clock (the old loop.png)
    assert sig.loop_t is not None and sig.loop_t.min() >= 0.0 and sig.loop_t.max() <= end + 1.0
    assert np.all(np.diff(sig.loop_t) >= 0) and sig.lockstep  # the sample ran in lockstep: waits, not misses


def test_the_truth_is_drawn_beside_the_estimates_and_the_force_balance_holds(recorded):
    _m, _series, sig = recorded
    tr = sig.truth
    assert tr is not None and tr["K"] == pytest.approx(4.374e-4) and tr["R"] == pytest.approx(20.0)
    assert sig.est is not None and sig.mass is not None
    m_hat, k_hat = sig.est[-1, 0], sig.est[-1, 2]
    # m_hat is far from m, yet K_hat sits on the balance K (N + m_hat g/2) / (N + m g/2) the caption explains
    assert abs(m_hat - sig.mass[-1]) > 3.0
    balance = tr["K"] * (tr["N"] + m_hat * tr["g"] / 2) / (tr["N"] + sig.mass[-1] * tr["g"] / 2)
    assert k_hat == pytest.approx(balance, rel=2e-3)


def test_replay_and_sim_draw_the_same_figures(recorded, tmp_path):
    _m, _series, sig = recorded
    files = plot_signals(sig, tmp_path / "bag")
    assert [f.name for f in files] == ["tracking.png", "error.png", "inputs.png", "estimates.png", "loop.png"]
    t = np.arange(0, 1.0, DT)
    gaps = np.full((t.size, 2), 0.008)
    offline = RunSignals(title="offline", t=t, gaps=gaps, ref=gaps, u_t=t, u=np.full((t.size, 2), 80.0))
    assert [f.name for f in plot_signals(offline, tmp_path / "sim")] == ["tracking.png", "error.png", "inputs.png"]
    for f in files:
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_what_if_is_on_the_experiment_clock_and_draws_the_difference(tmp_path):
    res = what_if(SAMPLE, sets=["k1=60"])
    t = np.array(res["t"])
    assert t[0] == pytest.approx(-1.0, abs=0.05) and t[-1] == pytest.approx(8.0, abs=0.01)  # the pre-roll is t < 0
    assert plot_what_if(res, tmp_path).name == "what_if.png"
