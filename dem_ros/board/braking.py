"""The stopping-distance trip (docs/manual/board.md, "The braking bound"): where the plate stops if the board
applies a candidate voltage for one sample and then brakes, and the brake itself."""

from __future__ import annotations

import numpy as np
from numba import njit

from .config import _AB, _BB, _K, _KB, _KBL, _NB1, _NB2, _R, _T
from .observer import _deltas


@njit(cache=True)
def _force_bound(p: np.ndarray, i: float, de: float, uc: float) -> tuple[float, float]:
    """(F+ [N], lambda+ [V s]) of one magnet after one sample of uc [V] from current i [A] at gap delta [m]:
    the largest force over K in [(1 - e) K, (1 + e) K] and the largest flux (at (1 + e) K).

    F+(K) = (K a + c)^2 / (4 K), a = 2|i|/delta, c = T|uc|, is convex in K (F+'' = c^2 / (2 K^3) >= 0): its
    maximum over an interval is at an end (the stationary point K = c/a is the minimum), so both ends."""
    a = 2.0 * abs(i) / de
    c = p[_T] * abs(uc)
    hi = p[_KB] * a + c
    lo = p[_KBL] * a + c
    return max(hi * hi / (4.0 * p[_KB]), lo * lo / (4.0 * p[_KBL])), hi


@njit(cache=True)
def _stop_gaps(p: np.ndarray, s: np.ndarray, i: np.ndarray, uc: np.ndarray, U: float, out: np.ndarray) -> None:
    """Predicted stopping gaps out (2,) [m]: candidate uc (2,) [V] for one sample, then brake at U [V].

    s (3, 2): observer state; i (2,): measured currents [A]. The bound of docs/manual/board.md.
    """
    T = p[_T]
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    F1, lam1 = _force_bound(p, i[0], de1, uc[0])
    F2, lam2 = _force_bound(p, i[1], de2, uc[1])
    for j in range(2):
        Fj, Fk = (F1, F2) if j == 0 else (F2, F1)
        lj, lk = (lam1, lam2) if j == 0 else (lam2, lam1)
        n = p[_NB1] if j == 0 else p[_NB2]
        G = p[_AB] * Fj + p[_BB] * Fk
        lam = max(lj, lk) if p[_BB] > 0.0 else lj
        tau = lam / U + T
        w = -s[1, j]
        a0 = G - n
        s0 = max(w, 0.0) * T + max(a0, 0.0) * 0.5 * T * T
        w1 = w + a0 * T + G * tau / 3.0
        D = s0 + (w1 * w1 / (2.0 * n) if w1 > 0.0 else 0.0)
        out[j] = s[0, j] - D


@njit(cache=True)
def _brake(p: np.ndarray, s: np.ndarray, i: np.ndarray, U: float, u: np.ndarray) -> None:
    """The brake u (2,) [V]: each coil's current to zero in one sample (u = R i - (2K/delta) i/T), clipped to +-U."""
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    for j in range(2):
        de = de1 if j == 0 else de2
        v = p[_R] * i[j] - 2.0 * p[_K] / de * i[j] / p[_T]
        u[j] = min(max(v, -U), U)

