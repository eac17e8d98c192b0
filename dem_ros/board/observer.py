"""The landing observer (docs/manual/board.md, "The landing law" 1): per load point gap, rate and the acceleration
the nominal model misses, from the measured gaps and currents; runs in every mode."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .config import _A, _B, _C, _D, _DMIN, _EMAX, _G, _K, _N1, _N2, _P, _Q, _T

__all__ = ["observer_gains"]


def observer_gains(T: float, w: float, w_bias: float) -> np.ndarray:
    """Lo (3,) of the current-estimator form: the eigenvalues of (I - Lo C) A are exp(-w T) (double)
    and exp(-w_bias T) (the missed-acceleration estimate, slower: it is a second derivative of noise).

    A = [[1, T, T^2/2], [0, 1, T], [0, 0, 1]], C = [1, 0, 0]. Ackermann on the pair
    (A, C A): Lo = phi(A) [CA; CA^2; CA^3]^-1 e3, phi(z) = (z - exp(-w T))^2 (z - exp(-w_bias T)).
    """
    A = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    C = np.array([[1.0, 0.0, 0.0]])
    lam = math.exp(-w * T)
    lam_b = math.exp(-w_bias * T)
    eye = np.eye(3)
    phi = (A - lam * eye) @ (A - lam * eye) @ (A - lam_b * eye)
    O = np.vstack([C @ A, C @ A @ A, C @ A @ A @ A])
    return (phi @ np.linalg.solve(O, np.array([0.0, 0.0, 1.0]))).ravel()



@njit(cache=True)
def _model_accel(p: np.ndarray, de1: float, de2: float, i1: float, i2: float, a: np.ndarray) -> None:
    """a = n - M F at gaps delta and currents i (nominal model)."""
    F1 = p[_K] * i1 * i1 / (de1 * de1)
    F2 = p[_K] * i2 * i2 / (de2 * de2)
    a[0] = p[_C] * p[_N1] + p[_D] * p[_N2] + p[_G] - p[_A] * F1 - p[_B] * F2
    a[1] = p[_D] * p[_N1] + p[_C] * p[_N2] + p[_G] - p[_B] * F1 - p[_A] * F2


@njit(cache=True)
def _deltas(p: np.ndarray, y1: float, y2: float) -> tuple[float, float]:
    de1 = max(p[_P] * y1 + p[_Q] * y2, p[_DMIN])
    de2 = max(p[_Q] * y1 + p[_P] * y2, p[_DMIN])
    return de1, de2


@njit(cache=True)
def _observe(p: np.ndarray, Lo: np.ndarray, s: np.ndarray, a: np.ndarray, y0: float, y1: float, i0: float,
             i1: float, gated: np.ndarray, blind: np.ndarray, wild: np.ndarray) -> None:
    """One observer step. s (3, 2): [p, v, b] per load point; a (2,): model acceleration of the last step (updated);
    gated (2,): per load point, 1 when the last sample was set aside as wild (updated), wild (2,) that sample [m];
    blind (2,): 1 where
    there is no gap sample (non-finite or missing): prediction only, like a wild sample."""
    T = p[_T]
    for j in range(2):
        acc = a[j] + s[2, j]
        pp = s[0, j] + T * s[1, j] + 0.5 * T * T * acc
        vp = s[1, j] + T * acc
        # no sample: the prediction alone (the wild-sample gate keeps its state)
        e = 0.0 if blind[j] != 0.0 else (y0 if j == 0 else y1) - pp
        if blind[j] != 0.0:
            pass
        elif abs(e) > p[_EMAX] and gated[j] == 0.0:
            gated[j] = 1.0  # one wild sample is set aside (prediction only); a second in a row is real
            wild[j] = pp + e
            e = 0.0
        elif abs(e) > p[_EMAX]:
            # two in a row: a real step (the plate hit its support, or moved faster than the model knows):
            # restart gap and rate from the two samples; the missed acceleration is kept
            gated[j] = 0.0
            y = pp + e
            s[0, j] = y
            s[1, j] = (y - wild[j]) / T
            continue
        else:
            gated[j] = 0.0
        s[0, j] = pp + Lo[0] * e
        s[1, j] = vp + Lo[1] * e
        s[2, j] = s[2, j] + Lo[2] * e
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    _model_accel(p, de1, de2, i0, i1, a)
