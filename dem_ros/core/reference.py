r"""Reference generator: command schedule r(t) filtered by the reference model M(s).

    M(s) = b0 / (s^3 + a2 s^2 + a1 s + a0)          (Eq. 46: 0.25/((s+1)(s+0.5)^2))

per output, discretised exactly (ZOH, :mod:`dem_ros.core.lti`). The state of
each model is [y_d, y_d', y_d''] and the jerk is y_d''' = -a0 y_d - a1 y_d'
- a2 y_d'' + b0 r. The default schedule is the staggered steps of notes
section 7: r1 goes 8 -> 5 mm at t = 1 s, r2 goes 8 -> 5 mm at t = 10 s.

Output layout (shape (8,)): ``[y1, y2, y1', y2', y1'', y2'', y1''', y2''']``
(m, m/s, m/s^2, m/s^3), the same as the ``/dem/reference`` topic.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

from .lti import AllPoleFilter

__all__ = ["ReferenceModel", "command", "hover_start", "reference_trajectory"]


def command(cfg: Mapping[str, Any], t: np.ndarray | float) -> np.ndarray:
    """Command r(t) (m), shape (..., 2): staggered steps of the ``reference`` group."""
    if isinstance(t, float):  # one sample (the 1 kHz node): no array machinery
        return np.array([cfg["target_1"] if t >= cfg["step_time_1"] else cfg["initial"],
                         cfg["target_2"] if t >= cfg["step_time_2"] else cfg["initial"]])
    t = np.asarray(t, dtype=float)
    r1 = np.where(t >= cfg["step_time_1"], cfg["target_1"], cfg["initial"])
    r2 = np.where(t >= cfg["step_time_2"], cfg["target_2"], cfg["initial"])
    return np.stack([r1, r2], axis=-1)


@njit(cache=True)
def _ref_step(z: np.ndarray, Ad: np.ndarray, Bd: np.ndarray, c: np.ndarray, b0: float, r: np.ndarray,
              out: np.ndarray) -> None:
    """Write the reference for the current sample into ``out`` and advance ``z`` (3 x 2)."""
    for j in range(2):
        out[j] = z[0, j]
        out[2 + j] = z[1, j]
        out[4 + j] = z[2, j]
        out[6 + j] = -c[0] * z[0, j] - c[1] * z[1, j] - c[2] * z[2, j] + b0 * r[j]
    tmp = np.empty(3)
    for j in range(2):
        for i in range(3):
            tmp[i] = Ad[i, 0] * z[0, j] + Ad[i, 1] * z[1, j] + Ad[i, 2] * z[2, j] + Bd[i] * r[j]
        for i in range(3):
            z[i, j] = tmp[i]


@njit(cache=True)
def _ref_run(z: np.ndarray, Ad: np.ndarray, Bd: np.ndarray, c: np.ndarray, b0: float, r: np.ndarray,
             out: np.ndarray) -> None:
    for k in range(r.shape[0]):
        _ref_step(z, Ad, Bd, c, b0, r[k], out[k])


class ReferenceModel:
    """Two reference models M(s) started in steady state at ``cfg['initial']`` (or where the plate hovers)."""

    def __init__(self, cfg: Mapping[str, Any]):
        self.cfg = dict(cfg)
        self.filter = AllPoleFilter([cfg["a0"], cfg["a1"], cfg["a2"]], cfg["b0"], cfg["dt"])
        self.reset()

    def reset(self, initial: float | np.ndarray | None = None) -> None:
        """Rest at ``initial`` (m; one value or one per magnet, default ``cfg['initial']``).

        A rig starts from the hover it is in (e.g. :func:`hover_start` of the pre-roll): the model
        rests there and glides to the commands through M(s), instead of stepping from 8 mm.
        """
        y0 = self.cfg["initial"] if initial is None else initial
        self.z = np.zeros((3, 2))
        self.z[0, :] = np.asarray(y0, float) * self.filter.dc_gain
        self.r_rest = self.z[0].copy() / self.filter.dc_gain  # the command that holds this rest
        self.k = 0

    def step(self, r: np.ndarray) -> np.ndarray:
        """Reference for the current sample given the held command ``r`` (2,); advances one period."""
        out = np.empty(8)
        _ref_step(self.z, self.filter.Ad, self.filter.Bd, self.filter.c, self.filter.gain, np.asarray(r, float), out)
        self.k += 1
        return out

    def step_hold(self) -> np.ndarray:
        """The reference at rest (state unchanged): what is held before the schedule starts."""
        out = np.empty(8)
        z = self.z.copy()
        _ref_step(z, self.filter.Ad, self.filter.Bd, self.filter.c, self.filter.gain, self.r_rest, out)
        return out

    def step_at(self, t: float) -> np.ndarray:
        """Reference for time ``t`` using the configured schedule (one period per call)."""
        return self.step(command(self.cfg, t))

    def run(self, r: np.ndarray) -> np.ndarray:
        """Reference for a whole command sequence ``r`` (N, 2) -> (N, 8)."""
        r = np.ascontiguousarray(r, dtype=float)
        out = np.empty((r.shape[0], 8))
        _ref_run(self.z, self.filter.Ad, self.filter.Bd, self.filter.c, self.filter.gain, r, out)
        self.k += r.shape[0]
        return out


def reference_trajectory(cfg: Mapping[str, Any], n: int,
                         start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(r, yd): command (n, 2) and reference (n, 8) at t_k = k dt, k = 0..n-1;
    the model rests at ``start`` (2,) first."""
    t = np.arange(n) * cfg["dt"]
    r = command(cfg, t)
    model = ReferenceModel(cfg)
    if start is not None:
        model.reset(start)
    yd: np.ndarray = model.run(r)
    return r, yd


def hover_start(gaps: np.ndarray) -> np.ndarray:
    """Where the reference starts: the median of the pre-roll's measured gaps (n, 2) -> (2,) (m).

    The median: robust to outliers, and exact for a noiseless hover (a level hover at 8 mm starts the
    model at exactly 8 mm, as the schedule's ``initial``).
    """
    start: np.ndarray = np.median(np.atleast_2d(np.asarray(gaps, float)), axis=0)
    return start

