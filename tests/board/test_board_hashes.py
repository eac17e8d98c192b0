"""The board bit for bit: hashes of the Supervisor's outputs over the safety test grids.

A refactoring of the board must not change what it decides or applies. Every sample the board computes in
the grids of ``test_safety`` (landings from level and tilted hovers with m, R, K off; the worst commands and
the seeded random rail approaches; captures after a trip; lost, flickering and frozen sensors; landings started
during a lift-off) and in a seeded random input sequence (commands, NaNs, mode requests, bus and applied
voltages) is folded into one SHA-256 per grid: the mode, the voltages, the observer's estimate, the predicted
stopping gaps, the flags
(``implausible``, ``command_timeout``) and the snapshot (reasons, fault, counters). The table below holds the
expected digests; print the current ones with

    .venv/bin/python tests/board/test_board_hashes.py

The digests are of IEEE doubles as this platform's numba/LLVM computes them (no fastmath in the kernels).
"""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))  # the grids and their drivers live in test_safety
sys.path.insert(1, str(Path(__file__).parent.parent))  # ... which uses tests/liftoff.py (when run as a script)

import test_safety as ts

from dem_ros.board import Mode, Supervisor

T_NS = ts.T_NS


class _Recorder:
    """Folds every step of every Supervisor built while it is installed into one hash."""

    def __init__(self) -> None:
        self.h = hashlib.sha256()
        self.steps = 0

    def cls(self) -> type[Supervisor]:
        rec = self

        class Recording(Supervisor):
            def step(self, *args, **kwargs):  # type: ignore[override]
                u = super().step(*args, **kwargs)
                rec.fold(self, u)
                return u

        return Recording

    def fold(self, s: Supervisor, u: np.ndarray) -> None:
        self.steps += 1
        h = self.h
        h.update(int(s.mode).to_bytes(1, "little"))
        for a in (u, s.estimate, s.stop_gap, s.u):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        h.update(repr((s.implausible, s.command_timeout, s.min_stop_gap, sorted(s.snapshot().items()))).encode())

    def digest(self) -> str:
        return f"{self.h.hexdigest()[:16]}/{self.steps}"


def _landings() -> None:
    for g1, g2, fm, fR, fK, dm in ts.CASES:
        ts.land(g1, g2, fm, fR, fK, dm, noise=0.03, seed=7)
    for gap in (0.004, 0.008):
        for seed in (1, 2, 3):
            ts.land(gap, gap, noise=0.1, seed=seed)
    ts.land(0.006, 0.006, via="land", kick=-0.02, noise=0.03)


def _approaches() -> None:
    for variant in ts.VARIANTS.values():
        for kind in ts.COMMANDS:
            for g0 in (0.002, 0.004, 0.008):
                for v0 in (0.0, 0.05, 0.1):
                    ts.approach(g0, v0, kind, variant, seed=round(g0 * 1e4 + v0 * 1e3))
    ts.approach(0.006, 0.045, "both", cfg=ts.board_cfg(u_max=150.0), t_after=0.3)


def _random_approaches() -> None:
    rng = np.random.default_rng(20261124)
    for case in range(60):
        variant = (rng.uniform(0.75, 1.25), rng.uniform(0.0, 3.0), rng.uniform(0.75, 1.4), rng.uniform(0.75, 1.25))
        g0, tilt = rng.uniform(0.002, 0.010), rng.uniform(-0.002, 0.002)
        v0, v2 = rng.uniform(0.0, 0.1), rng.uniform(-1.0, 1.0)
        kind = str(rng.choice(ts.COMMANDS))
        ts.approach(max(g0, g0 - tilt), v0, kind, variant, tilt=tilt, v2=v2, noise=rng.uniform(0.0, 0.1), seed=case)


def _captures() -> None:
    for g0, v0, kind, variant in ts.CAPTURE:
        ts.approach(g0, v0, kind, ts.VARIANTS[variant], to_landed=True)


def _lost_sensors() -> None:
    for chan in (0, 1, 2, 3):
        ts.hover_with_lost_sensor(chan, 1, t_max=0.6)
        for variant in ts.LOSS_VARIANTS:
            ts.hover_with_lost_sensor(chan, None, variant)
    kd = ts.K_DECIDE
    for chan in (0, 1):
        def flux_then_current(k, y, i, chan=chan):
            if k >= 300:
                y[chan] = np.nan
            if k >= kd + 20:
                i[chan] = np.nan

        def flicker(k, y, i, chan=chan):
            if k >= 300:
                y[chan] = np.nan
            if k >= kd:
                if (k - kd) % 2 == 0:
                    y[1 - chan] = np.nan
                else:
                    i[chan] = np.nan

        def brief_other(k, y, i, chan=chan):
            if k >= 300:
                y[chan] = np.nan
            if kd <= k < kd + 2:
                y[1 - chan] = np.nan
            if kd + 100 <= k < kd + 100 + ts.SENSOR_BLIND_SAMPLES:
                i[chan] = np.nan

        ts.hover_with_losses(flux_then_current, ts.LOSS_VARIANTS[1], t_after_fault=0.3)
        ts.hover_with_losses(flicker, t_after_fault=0.3)
        ts.hover_with_losses(brief_other, ts.LOSS_VARIANTS[2])


def _stuck_sensors() -> None:
    for variant in ts.STUCK_VARIANTS:
        for chan in (0, 1):
            for v0 in (-0.01, 0.01):
                frozen: dict[int, float] = {}

                def stick(k, y, i, chan=chan, frozen=frozen):
                    if k >= 1500:
                        y[chan] = frozen.setdefault(chan, y[chan])

                def push(k, x, chan=chan, v0=v0):
                    if k == 1600:
                        x[2 * chan + 1] = v0

                ts.hover_with_losses(stick, variant, t_max=4.0, push=push)
    for variant in ts.STUCK_VARIANTS[:2]:
        for chan in (0, 1):
            both: dict[int, float] = {}

            def stick_both(k, y, i, both=both):
                if k >= 1500:
                    y[0] = both.setdefault(0, y[0])
                    y[1] = both.setdefault(1, y[1])

            def push_one(k, x, chan=chan):
                if k == 1600:
                    x[2 * chan + 1] = -0.01

            ts.hover_with_losses(stick_both, variant, t_max=3.0, push=push_one, t_after_fault=0.3)


def _liftoffs() -> None:
    for idx, (g, v, a) in enumerate(ts.LIFTOFF_STATES):
        ts.land_during_liftoff(g, v, a, ts.LIFTOFF_VARIANTS[idx % len(ts.LIFTOFF_VARIANTS)])


def _random_inputs() -> None:
    """Seeded random samples straight into the board: commands (none, finite, huge, NaN), gaps and currents
    (NaN now and then), mode requests, a measured bus and applied voltages; clear() after each landing."""
    rng = np.random.default_rng(22)
    for run in range(12):
        s = ts.Supervisor(ts.board_cfg(u_max=150.0 + 10 * run), 1e-3, mode=Mode.RUN, u0=np.array([80.0, 80.0]))
        for k in range(400):
            r = rng.random(8)
            cmd = None if r[0] < 0.2 else (np.array([np.nan, 1.0]) if r[0] < 0.23 else rng.uniform(-300, 300, 2))
            y = rng.uniform(0.002, 0.012, 2)
            i = rng.uniform(0.0, 9.0, 2)
            if r[1] < 0.05:
                y[int(r[2] * 2)] = np.nan
            if r[3] < 0.05:
                i[int(r[4] * 2)] = np.nan
            req = Mode.RUN if r[5] < 0.9 else (Mode.LAND if r[5] < 0.95 else Mode.OFF)
            bus = None if run % 2 else float(rng.uniform(50.0, 250.0))
            applied = None if run % 3 else rng.uniform(-100.0, 100.0, 2)
            s.step(k * T_NS, y, i, cmd, requested=req, bus=bus, applied=applied)
            if s.mode in (Mode.LANDED, Mode.FAULT) and r[6] < 0.1:
                s.clear()
            if s.mode in (Mode.RUN, Mode.HOLD) and r[7] < 0.005:
                s.estop("test")


GRIDS: dict[str, Callable[[], None]] = {
    "landings": _landings,
    "approaches": _approaches,
    "random_approaches": _random_approaches,
    "captures": _captures,
    "lost_sensors": _lost_sensors,
    "stuck_sensors": _stuck_sensors,
    "liftoffs": _liftoffs,
    "random_inputs": _random_inputs,
}

EXPECTED: dict[str, str] = {
    "landings": "0dd3eb67a12f1e2a/34201",
    "approaches": "6174e624485fc626/78090",
    "random_approaches": "505ccd030654f5ce/10800",
    "captures": "c534df71ae9154af/13234",
    "lost_sensors": "6179e1b04fcbfb8b/29530",
    "stuck_sensors": "b8e3383784d724dc/52181",
    "liftoffs": "5f5398db90d22056/17952",
    "random_inputs": "ae94cac21b94af0d/4800",
}


def run(grid: str) -> str:
    rec = _Recorder()
    saved = ts.Supervisor
    ts.Supervisor = rec.cls()
    try:
        GRIDS[grid]()
    finally:
        ts.Supervisor = saved
    return rec.digest()


@pytest.mark.parametrize("grid", list(GRIDS))
def test_board_outputs_are_bit_for_bit(grid):
    assert run(grid) == EXPECTED[grid]


if __name__ == "__main__":
    for g in GRIDS:
        print(f'    "{g}": "{run(g)}",', flush=True)
