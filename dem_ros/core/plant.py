"""The DEM plant as a sample-by-sample simulator (used by the ``plant_sim`` node).

Same physics and the same seeded noise / perturbation / mass sequences as the
offline simulator (:func:`dem_ros.core.simulate.prepare`), so a graph run and an
offline run of the same scenario see identical disturbances.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .model import IP, IQ, hover_state, plant_vector, rk4, set_mass
from .scenarios import NOISE_UNIT, mass_profile

__all__ = ["DemPlant"]


class DemPlant:
    """x_k -> x_{k+1} under a held voltage; measurement z_k = x_k + noise_k.

    Attributes:
        x (6,): true state [d1, d1', d2, d2', i1, i2] (m, m/s, A).
        u0 (2,): pre-start hover voltage (V).
        k: sample index; t = k dt (s).
    """

    def __init__(self, pc: Mapping, duration: float = 0.0):
        self.pc = dict(pc)
        self.dt = pc["dt"]
        self.p = plant_vector(pc)
        self.x, self.u0 = hover_state(pc, pc["gap0"])
        self.k = 0
        self.mass = pc["m"]
        self.rng = np.random.default_rng(pc["seed"])
        self.n = int(round(duration / self.dt)) if duration > 0 else 0
        if self.n:
            from .simulate import prepare

            _, _, _, self._mass, self._noise, self._pert = prepare({"plant_sim": pc, "reference": _dummy_ref(pc)}, duration)
        self.fault: str | None = None

    def _noise_k(self) -> np.ndarray:
        if self.n and self.k < self.n:
            return self._noise[self.k]
        if self.pc["noise_scale"] == 0:
            return np.zeros(6)
        z = self.rng.uniform(-1.0, 1.0, 6) * self.pc["noise_scale"] * NOISE_UNIT
        if not self.pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        return z

    def _pert_k(self) -> np.ndarray:
        if self.n and self.k < self.n:
            return self._pert[self.k]
        kind, a = self.pc["perturbation"], self.pc["perturbation_amplitude"]
        if kind == "none" or a == 0:
            return np.zeros(2)
        if kind == "uniform":
            return self.rng.uniform(-a, a, 2)
        t = self.k * self.dt
        return a * np.sin(2 * np.pi * self.pc["perturbation_frequency"] * t + np.array([0.0, np.pi / 2]))

    def measurement(self) -> np.ndarray:
        """z_k = x_k + noise_k (velocities included; the node drops them if not measured)."""
        return self.x + self._noise_k()

    def measurement_preroll(self) -> np.ndarray:
        """Measurement before t = 0: noise from a separate stream, so the run's sequences stay the offline ones."""
        if self.pc["noise_scale"] == 0:
            return self.x.copy()
        z = self.x + self.rng.uniform(-1.0, 1.0, 6) * self.pc["noise_scale"] * NOISE_UNIT
        if not self.pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        return z

    def hold(self, u: np.ndarray) -> None:
        """Pre-roll: integrate one period under ``u`` with the initial mass and no perturbation; k stays 0."""
        set_mass(self.p, self.pc["m"], self.pc["L"], self.pc["l"], self.pc["I"])
        rk4(self.x, np.asarray(u, float), self.p, self.dt, self.pc["substeps"])
        self._check()

    def advance(self, u: np.ndarray) -> None:
        """Hold ``u`` (+ perturbation) over [t_k, t_k+1) and integrate; then k += 1."""
        t = self.k * self.dt
        self.mass = float(self._mass[self.k]) if self.n and self.k < self.n else float(mass_profile(self.pc, np.array([t]))[0])
        set_mass(self.p, self.mass, self.pc["L"], self.pc["l"], self.pc["I"])
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


def _dummy_ref(pc: Mapping) -> dict:
    from .params import SCHEMA

    return {**SCHEMA.defaults("reference"), "dt": pc["dt"]}
