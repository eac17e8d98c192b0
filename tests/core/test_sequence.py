"""The law's start, lift-off and restart (:class:`ControlSequence`) on its own: no node, no clock.

The node's behaviour around it (the hover window held on the wire, lift-off on the rig's board tick by tick) is
tests/graph/test_controller_node.py's and tests/graph/test_restart.py's; here each rule of the sequence, from
samples made with the nominal model.
"""

import numpy as np
import pytest

from dem_ros.core.controllers.hover import LIFT_DETECT, lift_fraction
from dem_ros.core.controllers.sequence import (
    ECHO_SAMPLES,
    HOLD,
    LAW,
    OFF_SAMPLES,
    PREMAGNETISE,
    RESTING_S,
    ControlSequence,
)
from dem_ros.core.model import hover_current
from dem_ros.core.params import SCHEMA

T = 1_000_000  # ns


def _cfg(**over) -> dict:
    cfg = SCHEMA.defaults("controller")
    cfg.update(over)
    return cfg


def _hover(cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """An estimate at the nominal symmetric hover and the voltage that holds it."""
    gap = 0.008
    i = hover_current({**cfg, "m": cfg["m_nominal"], "K": cfg["K_nominal"]}, gap)
    z = np.array([gap, 0.0, gap, 0.0, i, i])
    return z, np.full(2, 10.0 * i)


def _resting(cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    z, _ = _hover(cfg)
    z = z.copy()
    z[[0, 2]] = 0.0112  # on the support
    z[4:6] = 0.0
    return z, np.zeros(2)


def test_the_hover_window_holds_the_applied_voltage_then_the_law_starts_from_it():
    cfg = _cfg(hover_window=0.01)
    seq = ControlSequence(cfg)
    z, u = _hover(cfg)
    assert seq.window_n == 10
    kinds = [seq.step(k * T, z, u, None, preroll=True).kind for k in range(12)]
    assert kinds[:9] == [HOLD] * 9 and kinds[9:] == [LAW] * 3
    assert seq.started and seq.counts["starts"] == 1 and seq.law.hover_fit.samples == 10


def test_fit_window_is_the_offline_start_and_refuses_a_resting_window():
    cfg = _cfg()
    z, u = _hover(cfg)
    seq = ControlSequence(cfg)
    assert seq.fit_window(np.repeat(z[None], 5, axis=0), np.repeat(u[None], 5, axis=0))
    assert seq.started and seq.law.hover_fit.samples == 5
    zr, ur = _resting(cfg)
    rest = ControlSequence(cfg)
    assert not rest.fit_window(np.repeat(zr[None], 5, axis=0), np.repeat(ur[None], 5, axis=0))
    assert not rest.started and rest.counts["starts"] == 0


def test_a_resting_plate_is_premagnetised_until_the_board_echoes_then_lifts_off_when_it_leaves_the_support():
    cfg = _cfg()
    seq = ControlSequence(cfg)
    z, u = _resting(cfg)
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0], dtype=float)
    step = seq.step(0, z, u, ref, preroll=False)
    assert step.kind == PREMAGNETISE and seq.landed and not seq.started
    u_cmd = step.u.copy()
    for k in range(1, 3 * ECHO_SAMPLES):  # the board applies the command; the currents follow
        z[4:6] = u_cmd / 10.0
        step = seq.step(k * T, z, u_cmd, ref, preroll=False)
        assert step.kind == PREMAGNETISE and not seq.started  # still on the support: no lift-off
        assert np.all(step.u >= u_cmd - 1e-12)  # the force only rises (the ramp after the echo)
        u_cmd = step.u.copy()
    assert lift_fraction(z, cfg) > 0.25
    z[[0, 2]] -= 2 * LIFT_DETECT  # off the support, rising
    z[[1, 3]] = -5e-3
    step = seq.step(3 * ECHO_SAMPLES * T, z, u_cmd, ref, preroll=False)
    assert step.kind == LAW and step.u is not None and np.all(np.isfinite(step.u))
    assert seq.started and seq.liftoff is not None and seq.counts["liftoffs"] == 1 and not seq.landed


def test_a_board_that_applies_0_v_stops_the_running_law_and_it_starts_afresh():
    cfg = _cfg()
    seq = ControlSequence(cfg)
    z, u = _hover(cfg)
    assert seq.step(0, z, u, None, preroll=False).kind == LAW  # mid-run: this sample alone
    law = seq.law
    for _ in range(OFF_SAMPLES - 1):
        seq.applied([0.0, 0.0])
    seq.step(T, z, u, None, preroll=False)
    assert seq.counts["landed_stops"] == 0 and seq.law is law  # one sample short
    seq.applied([0.0, 0.0])
    seq.step(2 * T, z, u, None, preroll=False)
    assert seq.counts["landed_stops"] == 1 and seq.law is not law and seq.counts["starts"] == 2


def test_a_plate_resting_under_the_running_law_stops_it_after_resting_s():
    cfg = _cfg()
    seq = ControlSequence(cfg)
    z, u = _hover(cfg)
    seq.step(0, z, u, None, preroll=False)
    zr, _ = _resting(cfg)
    zr[4:6] = z[4:6] * 0.3  # some current left: the law still steps, the magnets carry < 1/4
    n = round(RESTING_S * 1e9 / T)
    for k in range(1, n + 1):
        seq.step(k * T, zr, u, None, preroll=False)
    assert seq.counts["landed_stops"] == 0
    seq.step((n + 1) * T, zr, u, None, preroll=False)
    assert seq.counts["landed_stops"] == 1 and not seq.started  # stopped; the next sample premagnetises
    assert seq.step((n + 2) * T, zr, u, None, preroll=False).kind == PREMAGNETISE and seq.landed


@pytest.mark.parametrize("other", ["decentralized_pid", "adaptive_enhanced"])
def test_a_new_type_swaps_the_law_and_restarts_it_from_the_next_sample(other):
    cfg = _cfg()
    seq = ControlSequence(cfg)
    z, u = _hover(cfg)
    seq.step(0, z, u, None, preroll=False)
    seq.configure({**cfg, "type": other})
    assert not seq.started and seq.law.name != cfg["type"]
    assert seq.step(T, z, u, None, preroll=False).kind == LAW and seq.started and seq.counts["starts"] == 2
