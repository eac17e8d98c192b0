r"""State estimator: extended Kalman filter on the DEM plant model.

State (10,): ``s = [d1, d1', d2, d2', i1, i2, beta1, beta2, w1, w2]``
(m, m/s, A, m/s^2, V): the plant state of :mod:`dem_ros.core.model` plus

* an acceleration bias per gap, beta_j, that absorbs what the nominal model
  gets wrong in the mechanics (an unknown added mass, load changes);
* a voltage bias per coil, w_j, that absorbs what it gets wrong in the coil
  circuit: the filter does not assume a known R. With the true R_j,
  u_j - R_j i_j = u_j + w_j - R i_j for w_j = (R - R_j) i_j, so a resistance
  error (tolerance, one coil hotter than the other, heating during the run)
  and any voltage offset of the driver are one slowly varying voltage per
  coil, observable through the measured current (one sample of w moves i_j
  by delta_j w T / 2K, about 9 mA per volt at 8 mm, against 1 mA sensor noise).

Why not take R_hat from the adaptive law (``/dem/controller/state``)? That
closes a second loop estimator -> law -> estimator whose gain nobody designed
(the law's R_hat is identified through the estimator's own currents), delays
R_hat by a sample in the graph, and the law's single R cannot describe two
coils. The bias states need no other node and are per coil. Measured effect
(``adaptive``, S1, 100 s, delay 1): true R = 18 ohm, 28 um RMS with the old
8-state filter, see README for the figures with this one.

Model (continuous, nominal m, R, K of the ``estimator`` group)::

    s' = f(s, u) + G n,   f = [plant dynamics under u + w, d_j'' += beta_j ; beta' = 0 ; w' = 0]
    n  = per-sample (held) disturbances: acceleration sigma_accel, voltage sigma_voltage,
         bias changes sigma_bias T and sigma_voltage_bias T; Q = G diag(sigma^2) G^T T^2

Discrete step (period T)::

    predict   s <- RK4(f, s, u_{k-1}, T)
              F  = I + A T + (A T)^2 / 2,     A = df/ds (central differences)
              Pk = F P F^T + Q
    update    y  = z - H s                    (innovation)
              S  = H P H^T + Rm
              Kg = P H^T S^-1
              s <- s + Kg y ;  P <- (I - Kg H) P (I - Kg H)^T + Kg Rm Kg^T   (Joseph form)

``H`` picks the gaps and currents, and the gap rates when the sensors deliver
them. Innovation, gain and covariance are kept for inspection.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

from .model import IK, IP, IQ, dynamics, plant_vector
from .params import SCHEMA

__all__ = ["Estimator", "KalmanEstimator", "PassThrough", "make_estimator"]

NS = 10


@njit(cache=True)
def _f(s: np.ndarray, u: np.ndarray, p: np.ndarray, ds: np.ndarray) -> None:
    dx = np.empty(6)
    ue = np.empty(2)
    ue[0] = u[0] + s[8]
    ue[1] = u[1] + s[9]
    dynamics(s[:6], ue, p, dx)
    ds[:6] = dx
    ds[1] += s[6]
    ds[3] += s[7]
    for j in range(6, NS):
        ds[j] = 0.0


@njit(cache=True)
def _rk4(s: np.ndarray, u: np.ndarray, p: np.ndarray, T: float) -> None:
    k1 = np.empty(NS)
    k2 = np.empty(NS)
    k3 = np.empty(NS)
    k4 = np.empty(NS)
    _f(s, u, p, k1)
    _f(s + 0.5 * T * k1, u, p, k2)
    _f(s + 0.5 * T * k2, u, p, k3)
    _f(s + T * k3, u, p, k4)
    s += T / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@njit(cache=True)
def jacobian(s: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """A = df/ds by central differences, step scaled to each state."""
    A = np.empty((NS, NS))
    fp = np.empty(NS)
    fm = np.empty(NS)
    for j in range(NS):
        h = 1e-6 * max(abs(s[j]), 1e-3)
        sp = s.copy()
        sm = s.copy()
        sp[j] += h
        sm[j] -= h
        _f(sp, u, p, fp)
        _f(sm, u, p, fm)
        for i in range(NS):
            A[i, j] = (fp[i] - fm[i]) / (2.0 * h)
    return A


@njit(cache=True)
def ekf_step(s: np.ndarray, P: np.ndarray, z: np.ndarray, mask: np.ndarray, u_prev: np.ndarray, p: np.ndarray,
             T: float, qc: np.ndarray, rm: np.ndarray, out: np.ndarray) -> None:
    """One predict + update. ``z`` (6,) measured [d1, d1', d2, d2', i1, i2]; ``mask`` (6,) 1 = measured.

    ``qc`` = (sigma_accel^2, sigma_voltage^2, sigma_bias^2, sigma_voltage_bias^2), ``rm`` (6,) measurement variances.
    Writes the estimate [d1, d1', d2, d2', i1, i2] into ``out``.
    """
    A = jacobian(s, u_prev, p)
    _rk4(s, u_prev, p, T)
    AT = A * T
    F = np.eye(NS) + AT + 0.5 * (AT @ AT)
    # process noise: acceleration on d', voltage through delta/(2K) on i', random walk on beta
    # per-sample (zero-order-hold) disturbances of standard deviation sigma: a held
    # acceleration a changes the rate by a T, a held voltage v the current by (delta/2K) v T,
    # and the bias walks by sigma_bias T per sample
    Q = np.zeros((NS, NS))
    T2 = T * T
    Q[1, 1] = qc[0] * T2
    Q[3, 3] = qc[0] * T2
    de1 = p[IP] * s[0] + p[IQ] * s[2]
    de2 = p[IQ] * s[0] + p[IP] * s[2]
    Q[4, 4] = qc[1] * (de1 / (2.0 * p[IK])) ** 2 * T2
    Q[5, 5] = qc[1] * (de2 / (2.0 * p[IK])) ** 2 * T2
    Q[6, 6] = qc[2] * T2
    Q[7, 7] = qc[2] * T2
    Q[8, 8] = qc[3] * T2
    Q[9, 9] = qc[3] * T2
    P[:, :] = F @ P @ F.T + Q
    nm = 0
    for i in range(6):
        if mask[i] > 0.0 and np.isfinite(z[i]):
            nm += 1
    if nm > 0:
        H = np.zeros((nm, NS))
        y = np.empty(nm)
        Rm = np.zeros((nm, nm))
        r = 0
        for i in range(6):
            if mask[i] > 0.0 and np.isfinite(z[i]):
                H[r, i] = 1.0
                y[r] = z[i] - s[i]
                Rm[r, r] = rm[i]
                r += 1
        S = H @ P @ H.T + Rm
        Kg = np.linalg.solve(S, H @ P).T
        s += Kg @ y
        IKH = np.eye(NS) - Kg @ H
        P[:, :] = IKH @ P @ IKH.T + Kg @ Rm @ Kg.T
    for i in range(6):
        out[i] = s[i]


class KalmanEstimator:
    """EKF of the module docstring; ``step(z, u_prev) -> x_hat`` (6,)."""

    name = "kf"

    def __init__(self, cfg: Mapping[str, Any], measure_velocity: bool = True):
        self.cfg = SCHEMA.validate_group("estimator", dict(cfg))
        c = self.cfg
        self.p = plant_vector(c)
        self.T = float(c["dt"])
        self.qc = np.array([c["sigma_accel"] ** 2, c["sigma_voltage"] ** 2, c["sigma_bias"] ** 2,
                            c["sigma_voltage_bias"] ** 2])
        self.rm = np.array([c["sigma_gap"], c["sigma_rate"], c["sigma_gap"], c["sigma_rate"],
                            c["sigma_current"], c["sigma_current"]]) ** 2
        self.mask = np.array([1.0, float(measure_velocity), 1.0, float(measure_velocity), 1.0, 1.0])
        self.s = np.zeros(NS)
        self.P = np.eye(NS)
        self.out = np.zeros(6)
        self.started = False

    def reset(self, z0: np.ndarray) -> None:
        """Start at the first measurement (velocities 0 when not measured, no bias)."""
        z0 = np.asarray(z0, float)
        self.s[:6] = np.where(self.mask > 0, z0, 0.0)
        self.s[6:] = 0.0
        w0 = self.cfg["voltage_bias_prior"] ** 2
        self.P = np.diag(np.concatenate([self.rm, [1.0, 1.0, w0, w0]]))
        self.P[1, 1] = self.P[3, 3] = max(self.rm[1], 1e-6)
        self.out[:] = self.s[:6]
        self.started = True

    def step(self, z: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """Estimate for this sample from measurement ``z`` and the voltage applied since the last one."""
        if not self.started:
            self.reset(z)
            return self.out
        ekf_step(self.s, self.P, np.asarray(z, float), self.mask, np.asarray(u_prev, float),
                 self.p, self.T, self.qc, self.rm, self.out)
        return self.out

    def kernel_args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
        return (self.s, self.P, self.mask, self.p, self.T, self.qc, self.rm)


class PassThrough:
    """No estimator: the controller gets the raw measurement (velocities 0 if not measured)."""

    name = "none"

    def __init__(self, measure_velocity: bool = True):
        self.mask = np.array([1.0, float(measure_velocity), 1.0, float(measure_velocity), 1.0, 1.0])
        self.out = np.zeros(6)

    def reset(self, z0: np.ndarray) -> None:
        self.out[:] = np.where(self.mask > 0, z0, 0.0)

    def step(self, z: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        self.out[:] = np.where(self.mask > 0, z, 0.0)
        return self.out


#: what :func:`make_estimator` makes: ``reset(z0)``, ``step(z, u_prev) -> x_hat`` (6,)
Estimator = KalmanEstimator | PassThrough


def make_estimator(cfg: Mapping[str, Any], kind: str | None = None, measure_velocity: bool = True) -> Estimator:
    kind = kind or cfg["type"]
    if kind == "kf":
        return KalmanEstimator(cfg, measure_velocity)
    if kind == "none":
        return PassThrough(measure_velocity)
    from .params import ConfigError

    raise ConfigError(f"estimator.type: got {kind!r}, expected one of 'kf', 'none'")
