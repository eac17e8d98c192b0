"""The DEM plant as a sample-by-sample simulator (used by the ``plant_sim`` node).

Same physics, sensors and seeded disturbances as the offline simulator (both
take them from :func:`dem_ros.core.scenarios.disturbances` and
:func:`dem_ros.core.model.initial_state`), so a graph run and an offline run of
the same scenario see identical disturbances.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

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
    """

    def __init__(self, pc: Mapping, duration: float = 0.0):
        self.pc = dict(pc)
        self.dt = pc["dt"]
        self.p = plant_vector(pc)
        self.x, self.u0 = initial_state(pc)
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
            return self._dist.noise[self.k]
        if self.pc["noise_scale"] == 0:
            return np.zeros(6)
        z = self.rng.uniform(-1.0, 1.0, 6) * self.pc["noise_scale"] * NOISE_UNIT
        if not self.pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        return z

    def _pert_k(self) -> np.ndarray:
        if self.n and self.k < self.n:
            return self._dist.pert[self.k]
        return perturbation_samples(self.pc, np.array([self.k * self.dt]), self.rng)[0]

    def _schedule_k(self) -> np.ndarray:
        if self.n and self.k < self.n:
            return self._dist.schedule[self.k]
        return plant_schedule(self.pc, np.array([self.k * self.dt]))[0]

    def sense(self) -> np.ndarray:
        """The sensors' view of the true state, without noise: G x + b."""
        return self.G * self.x + self.b

    def measurement(self) -> np.ndarray:
        """z_k = G x_k + b + noise_k (velocities included; the node drops them if not measured)."""
        return self.sense() + self._noise_k()

    def measurement_preroll(self) -> np.ndarray:
        """Measurement before t = 0: noise from a separate stream, so the run's sequences stay the offline ones."""
        if self.pc["noise_scale"] == 0:
            return self.sense()
        z = self.sense() + self.rng.uniform(-1.0, 1.0, 6) * self.pc["noise_scale"] * NOISE_UNIT
        if not self.pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        return z

    def hold(self, u: np.ndarray) -> None:
        """Pre-roll: integrate one period under ``u`` with the truth of t = 0 and no perturbation; k stays 0."""
        apply_schedule(self.p, self._row0, self.pc["L"], self.pc["l"])
        rk4(self.x, np.asarray(u, float), self.p, self.dt, self.pc["substeps"])
        self._check()

    def advance(self, u: np.ndarray) -> None:
        """Hold ``u`` (+ perturbation) over [t_k, t_k+1) and integrate; then k += 1."""
        row = self._schedule_k()
        self.mass = float(row[SM])
        apply_schedule(self.p, row, self.pc["L"], self.pc["l"])
        ua = np.asarray(u, float) + self._pert_k()
        rk4(self.x, ua, self.p, self.dt, self.pc["substeps"])
        self.k += 1
        self._check()

    def _check(self) -> None:
        d1 = self.p[IP] * self.x[0] + self.p[IQ] * self.x[2]
        d2 = self.p[IQ] * self.x[0] + self.p[IP] * self.x[2]
        if not np.all(np.isfinite(self.x)):
            self.fault = "state is not finite"
        elif min(self.x[0], self.x[2], d1, d2) <= self.pc["gap_min"]:
            self.fault = f"rail contact (gap {min(self.x[0], self.x[2]) * 1e3:.3f} mm)"
        elif max(self.x[0], self.x[2]) > self.pc["gap_max"]:
            self.fault = f"plate dropped (gap {max(self.x[0], self.x[2]) * 1e3:.3f} mm)"
