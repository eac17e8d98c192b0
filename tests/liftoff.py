"""A lift-off for the board's tests: the true plant lifted off the rig's support by the inverse dynamics of the
true plant (what a converged controller commands), so that a landing can start from a lift-off's state: its gap,
its rate and the currents of its acceleration (tests/board/test_safety.py, tests/firmware/test_differential.py)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from dem_ros.core.model import gap_weights

SUPPORT = 0.0112  # m, the rig group's support_gap default
REST_FRACTION = 0.7  # the magnets carry this share of the load when the lift-off starts (the plate rests)


class LiftOff:
    """Commands that lift the true plant (level: both load points alike) off its support at ``SUPPORT``.

    For ``t_rest`` [s] the magnets' force rises from ``REST_FRACTION`` of the load to just below it (the plate
    rests, the board's observer sees it resting); then the plate follows a quintic from rest on the support to
    gap ``g`` [m], rate ``v`` [m/s] (negative: rising) and acceleration ``a`` [m/s^2] (positive: a rise being
    slowed, as at the top of a lift-off; negative: a rise speeding up) at the end of ``t_path`` [s]: per magnet
    the force of the path's acceleration plus a PD on the true state, its current delta sqrt(F/K) and the
    voltage R i + half the flux step to it in one sample (the true m, R, K of ``pc``: the plant_sim group).

    ``command(k, x)``: the voltages (2,) [V] for sample k from the true state x (6,); ``n``: the samples of the
    rest and the path (the state at sample ``n`` is the lift-off state); ``x0()``: the plate on its support.
    """

    KP, KD = 40.0**2, 2 * 40.0  # the PD on the path [1/s^2, 1/s]

    def __init__(self, pc: Mapping[str, Any], g: float, v: float, a: float, t_rest: float = 0.2, t_path: float = 0.3):
        self.m, self.R, self.K, self.N, self.grav = pc["m"], pc["R"], pc["K"], pc["N1"], pc["g"]
        self.dt, self.u_max = pc["dt"], pc["u_max"]
        self.P, self.Q = gap_weights(pc["L"], pc["l"])
        self.load = 0.5 * self.m * self.grav + self.N  # per magnet [N]
        self.n_rest = round(t_rest / self.dt)
        self.n = self.n_rest + round(t_path / self.dt)
        self.t_path = t_path
        M = np.array([[t_path**3, t_path**4, t_path**5], [3 * t_path**2, 4 * t_path**3, 5 * t_path**4],
                      [6 * t_path, 12 * t_path**2, 20 * t_path**3]])
        self.c = np.linalg.solve(M, np.array([g - SUPPORT, v, a]))

    def x0(self) -> np.ndarray:
        i = SUPPORT * math.sqrt(REST_FRACTION * self.load / self.K)
        return np.array([SUPPORT, 0.0, SUPPORT, 0.0, i, i])

    def path(self, t: float) -> tuple[float, float, float]:
        """(gap [m], rate [m/s], acceleration [m/s^2]) of the path at t [s] after it starts."""
        t = min(max(t, 0.0), self.t_path)
        c3, c4, c5 = self.c
        return (SUPPORT + c3 * t**3 + c4 * t**4 + c5 * t**5, 3 * c3 * t**2 + 4 * c4 * t**3 + 5 * c5 * t**4,
                6 * c3 * t + 12 * c4 * t**2 + 20 * c5 * t**3)

    def command(self, k: int, x: np.ndarray) -> np.ndarray:
        de = (self.P * x[0] + self.Q * x[2], self.Q * x[0] + self.P * x[2])
        u = np.empty(2)
        for j in (0, 1):
            if k < self.n_rest:
                F = self.load * (REST_FRACTION + (0.99 - REST_FRACTION) * k / self.n_rest)
            else:
                y, yd, ydd = self.path((k - self.n_rest + 1) * self.dt)
                acc = ydd + self.KD * (yd - x[2 * j + 1]) + self.KP * (y - x[2 * j])
                F = max(0.5 * self.m * (self.grav - acc) + self.N, 0.0)
            i_des = de[j] * math.sqrt(F / self.K)
            u[j] = self.R * x[4 + j] + 2.0 * self.K / de[j] * (i_des - x[4 + j]) / self.dt * 0.5
        return np.clip(u, -self.u_max, self.u_max)
