r"""Exact (zero-order-hold) discretisation of the all-pole filters used here.

Both the reference model M(s) = b0/(s^3 + a2 s^2 + a1 s + a0) (Eq. 46) and the
error filter F(s) = 1/(s^3 + k1 s^2 + k2 s + k3) (Eq. 28) are third-order
all-pole systems. We realise ``b/(s^n + c_{n-1} s^{n-1} + ... + c_0)`` in
phase-variable form with state z = [y, y', ..., y^{(n-1)}]:

    z' = A z + B r,   A = companion(c),  B = [0, ..., 0, b]^T
    y^{(n)} = -c . z + b r

and discretise exactly under a zero-order hold:
``Ad = expm(A T)``, ``Bd = int_0^T expm(A s) ds B`` (one ``expm`` of the
augmented matrix [[A, B], [0, 0]] T).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit
from scipy.linalg import expm

__all__ = ["AllPoleFilter", "companion", "filter_step", "zoh"]


def companion(coeffs: np.ndarray, gain: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (A, B) of ``gain / (s^n + c[n-1] s^{n-1} + ... + c[0])``.

    ``coeffs`` are ``[c0, c1, ..., c_{n-1}]`` (constant term first).
    """
    c = np.asarray(coeffs, dtype=float)
    n = c.size
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -c
    B = np.zeros(n)
    B[-1] = gain
    return A, B


def zoh(A: np.ndarray, B: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation: (Ad, Bd) with z[k+1] = Ad z[k] + Bd r[k]."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n] = B
    E = expm(M * T)
    return E[:n, :n].copy(), E[:n, n].copy()


class AllPoleFilter:
    """A bank of identical all-pole filters, discretised once.

    Attributes:
        A, B: continuous phase-variable realisation.
        Ad, Bd: ZOH-discretised matrices for period ``T``.
        c, gain: denominator coefficients (constant first) and numerator gain.
    """

    def __init__(self, coeffs: np.ndarray | Sequence[float], gain: float, T: float) -> None:
        self.c = np.asarray(coeffs, dtype=float)
        self.gain = float(gain)
        self.T = float(T)
        self.A, self.B = companion(self.c, self.gain)
        self.Ad, self.Bd = zoh(self.A, self.B, self.T)

    @property
    def dc_gain(self) -> float:
        return self.gain / float(self.c[0])


@njit(cache=True)
def filter_step(Z: np.ndarray, Ad: np.ndarray, Bd: np.ndarray, w: np.ndarray) -> None:
    """Advance a bank of filters in place: Z[:, c] <- Ad Z[:, c] + Bd w[c] (Z: n x channels)."""
    n = Z.shape[0]
    nc = Z.shape[1]
    tmp = np.empty(n)
    for c in range(nc):
        for i in range(n):
            s = Bd[i] * w[c]
            for j in range(n):
                s += Ad[i, j] * Z[j, c]
            tmp[i] = s
        for i in range(n):
            Z[i, c] = tmp[i]
