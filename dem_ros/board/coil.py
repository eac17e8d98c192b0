"""The board's coil model and flux gaps (docs/manual/board.md, "Lost sensor samples"): a coil's current from the
voltage applied when its sensor gives nothing, and a load point's gap from its coil's flux when its gap sensor
was given up."""

from __future__ import annotations

import math

import numpy as np

from .config import _K, _P, _Q, _R, FLUX_GAP_MIN_CURRENT, R_LEARN_TIME

__all__ = ["CoilModel"]


class CoilModel:
    """Per coil j: the flux linkage lambda_j = 2K i_j / delta_j [V s] of Eq. 5's coil, u_j = R_j i_j + d lambda_j/dt.

    Args:
        p: the board's kernel parameter vector (``config.kernel_vector``).
        dt: sample period T [s].

    Attributes:
        u_prev (2,): the voltages applied over the last period [V] (measured when the board measures them).
        r_est (2,): each coil's resistance, learned while its current is measured [ohm].
        i_est (2,): the coil model's current for the next sample [A].
        flux_gap (2,): gap sensor j given up: its gap comes from coil j's flux (``flux_gaps``).
        lam_flux (2,): that coil's flux linkage, integrated from its voltage and current [V s].
        i_flux (2,): its current at the last sample [A].
    """

    def __init__(self, p: np.ndarray, dt: float):
        self._p = p
        self.dt = dt
        self.i_est = np.zeros(2)
        self.lam = np.zeros(2)  # the coil model's flux linkage 2K i/delta [V s]
        self.r_est = np.full(2, p[_R])
        self.lam_pred = np.zeros(2)
        self.u_prev = np.zeros(2)
        self.flux_gap = [False, False]
        self.lam_flux = np.zeros(2)
        self.i_flux = np.zeros(2)

    def start_flux(self, n: int, lam: float, i: float) -> None:
        """Gap sensor n given up: its gap from coil n's flux from now on, starting at ``lam`` [V s], current i [A]."""
        self.flux_gap[n] = True
        self.lam_flux[n] = lam
        self.i_flux[n] = i

    def flux_gaps(self, y0: float, y1: float, i0: float, i1: float, landed: bool,
                  rest: np.ndarray) -> tuple[float, float]:
        """The gap of a load point whose sensor was given up, from its coil's flux: lambda_j += T (u_j - R_j
        (i_j,prev + i_j)/2) (the voltage applied over the last period, trapezoid current), delta_j = 2K i_j /
        lambda_j, y_j = (delta_j - Q y_k) / P with the other load point's measured gap y_k. NaN (no sample) where
        it cannot be formed; ``landed``: on the support, its current removed: ``rest`` (2,), the gaps the landing
        ended at [m]."""
        y = [y0, y1]
        i = (i0, i1)
        P, Q, K2 = self._p[_P], self._p[_Q], 2.0 * self._p[_K]
        for j in (0, 1):
            if not self.flux_gap[j]:
                continue
            if not math.isfinite(i[j]):  # no flux without the current: the sensor's own reading, if it is back
                continue
            self.lam_flux[j] += self.dt * (float(self.u_prev[j]) - self.r_est[j] * 0.5 * (self.i_flux[j] + i[j]))
            self.i_flux[j] = i[j]
            yk = y[1 - j]
            if math.isfinite(y[j]):  # the sensor is back: its gap, and the flux re-anchored on it
                de = P * y[j] + Q * yk if math.isfinite(yk) else math.nan
                if math.isfinite(de) and de > 0.0:
                    self.lam_flux[j] = K2 * i[j] / de
            elif math.isfinite(yk) and abs(i[j]) > FLUX_GAP_MIN_CURRENT and self.lam_flux[j] > 0.0:
                y[j] = (K2 * i[j] / self.lam_flux[j] - Q * yk) / P
            elif landed:
                y[j] = float(rest[j])
        return y[0], y[1]

    def predict(self, u: np.ndarray, ok0: bool, ok1: bool, i_last: tuple[float, float],
                de: tuple[float, float]) -> None:
        """Predict the currents of the next sample from the voltages u (2,) [V] just applied:
        lambda+ = lambda + T (u - R_j i), i+ = lambda+ delta / (2K) (u = R i + d lambda/dt, Eq. 5), with
        delta (2,) [m] from the observer and i_last (2,) this sample's currents [A] (ok: measured). R_j is
        learned per coil while its current is measured (low-pass, R_LEARN_TIME) from the same equation, so a
        heated or cold coil does not bias the model; K cancels in lambda -> i."""
        K2 = 2.0 * self._p[_K]
        for j, ok in ((0, ok0), (1, ok1)):
            ij = i_last[j]
            lam = K2 * ij / de[j]
            if ok and abs(ij) > 0.2 and self.lam[j] != 0.0 and not self.flux_gap[j]:  # R_j from the last voltage
                r = (float(self.u_prev[j]) - (lam - self.lam[j]) / self.dt) / ij
                r = min(max(r, 0.5 * self._p[_R]), 2.0 * self._p[_R])
                self.r_est[j] += self.dt / R_LEARN_TIME * (r - self.r_est[j])
            if not ok:
                lam = self.lam_pred[j]
            self.lam[j] = lam
            self.lam_pred[j] = lam + self.dt * (float(u[j]) - self.r_est[j] * ij)
            self.i_est[j] = self.lam_pred[j] * de[j] / K2
        self.u_prev[:] = u
