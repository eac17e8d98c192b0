"""The DEM plant as a sample-by-sample simulator (used by the ``plant_sim`` node).

Same physics, sensors and seeded disturbances as the offline simulator (both
take them from :func:`dem_ros.core.scenarios.disturbances` and
:func:`dem_ros.core.model.initial_state`), so a graph run and an offline run of
the same scenario see identical disturbances.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

from .model import IP, IQ, SM, apply_schedule, initial_state, plant_vector, rk4
from .scenarios import NOISE_UNIT, disturbances, perturbation_samples, plant_schedule, sensor_model

__all__ = ["DemPlant"]


class DemPlant:
    """x_k -> x_{k+1} under a held voltage; measurement z_k = G x_k + b + noise_k.

    Attributes:
        x (6,): true state [d1, d1', d2, d2', i1, i2] (m, m/s, A).
        u0 (2,): pre-start hover voltage (V): the plant starts in exact equilibrium at (d1_0, d2_0).
        k: sample index; t = k dt (s).
        mass: true mass now (kg).
        coil_voltage (2,): the voltage the coils got over the last period, u + the scenario's input
            perturbation (V): what a board that measures its coils' voltage reads (u0 before the first).
    """

    def __init__(self, pc: Mapping[str, Any], duration: float = 0.0):
        self.pc = dict(pc)
        self.dt = pc["dt"]
        self.p = plant_vector(pc)
        self.x, self.u0 = initial_state(pc)
        self.coil_voltage = self.u0.copy()
        self.G, self.b = sensor_model(pc)
        self.k = 0
        self.rng = np.random.default_rng(pc["seed"])
        self.n = round(duration / self.dt) if duration > 0 else 0
        if self.n:
            self._dist = disturbances(pc, self.n)
        self._row0 = plant_schedule(pc, np.zeros(1))[0]
        self.mass = float(self._row0[SM])
        self.fault: str | None = None

    def _noise_k(self) -> np.ndarray:
        if self.n and self.k < self.n:
            row: np.ndarray = self._dist.noise[self.k]
            return row
        if self.pc["noise_scale"] == 0:
            return np.zeros(6)
        z: np.ndarray = self.rng.uniform(-1.0, 1.0, 6) * self.pc["noise_scale"] * NOISE_UNIT
        if not self.pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        return z

    def _pert_k(self) -> np.ndarray:
        row: np.ndarray = (self._dist.pert[self.k] if self.n and self.k < self.n
                           else perturbation_samples(self.pc, np.array([self.k * self.dt]), self.rng)[0])
        return row

    def _schedule_k(self) -> np.ndarray:
        row: np.ndarray = (self._dist.schedule[self.k] if self.n and self.k < self.n
                           else plant_schedule(self.pc, np.array([self.k * self.dt]))[0])
        return row

    def sense(self) -> np.ndarray:
        """The sensors' view of the true state, without noise: G x + b."""
        z: np.ndarray = self.G * self.x + self.b
        return z

    def measurement(self) -> np.ndarray:
        """z_k = G x_k + b + noise_k (velocities included; the node drops them if not measured)."""
        z: np.ndarray = self.sense() + self._noise_k()
        return z

    def measurement_preroll(self) -> np.ndarray:
        """Measurement before t = 0: noise from a separate stream, so the run's sequences stay the offline ones."""
        if self.pc["noise_scale"] == 0:
            return self.sense()
        z: np.ndarray = self.sense() + self.rng.uniform(-1.0, 1.0, 6) * self.pc["noise_scale"] * NOISE_UNIT
        if not self.pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        return z

    def hold(self, u: np.ndarray) -> None:
        """Pre-roll: integrate one period under ``u`` with the truth of t = 0 and no perturbation; k stays 0."""
        self._step(u, _NO_PERT, self._row0)

    def advance(self, u: np.ndarray) -> None:
        """Hold ``u`` (+ perturbation) over [t_k, t_k+1) and integrate; then k += 1."""
        row = self._schedule_k()
        self.mass = float(row[SM])
        self._step(u, self._pert_k(), row)
        self.k += 1

    def _step(self, u: np.ndarray, pert: np.ndarray, row: np.ndarray) -> None:
        pc = self.pc
        self.coil_voltage = np.asarray(u, float) + pert
        code = _advance(self.x, np.asarray(u, float), pert, self.p, row, pc["L"], pc["l"], self.dt, pc["substeps"],
                        pc["gap_min"], pc["gap_max"])
        if code:
            x = self.x
            self.fault = ("state is not finite" if code == NOT_FINITE
                          else f"rail contact (gap {min(x[0], x[2]) * 1e3:.3f} mm)" if code == RAIL_CONTACT
                          else f"plate dropped (gap {max(x[0], x[2]) * 1e3:.3f} mm)")


_NO_PERT = np.zeros(2)
#: fault codes of :func:`_advance`
NOT_FINITE, RAIL_CONTACT, DROPPED = 1, 2, 3


@njit(cache=True)
def _advance(x: np.ndarray, u: np.ndarray, pert: np.ndarray, p: np.ndarray, row: np.ndarray, L: float, l: float,
             T: float, n: int, gap_min: float, gap_max: float) -> int:
    """One plant sample in one compiled call (the 1 kHz loop's cost is in Python calls).

    Sets the truth of ``p`` from schedule ``row``, integrates ``x`` (6,) in place over ``T``
    [s] with ``n`` RK4 sub-steps under u + pert (2,) [V] held, then checks it: 0 fine,
    NOT_FINITE, RAIL_CONTACT (a gap or an edge gap d1, d2 <= gap_min [m]) or DROPPED (a gap
    > gap_max [m]).
    """
    apply_schedule(p, row, L, l)
    ua = np.empty(2)
    ua[0] = u[0] + pert[0]
    ua[1] = u[1] + pert[1]
    rk4(x, ua, p, T, n)
    for i in range(6):
        if not np.isfinite(x[i]):
            return 1
    d1 = p[IP] * x[0] + p[IQ] * x[2]
    d2 = p[IQ] * x[0] + p[IP] * x[2]
    if min(x[0], x[2], d1, d2) <= gap_min:
        return 2
    if max(x[0], x[2]) > gap_max:
        return 3
    return 0
