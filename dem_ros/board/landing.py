"""The landing law (docs/manual/board.md, "The landing law" 2-4): reference, outer gap loop and current loop,
from the observer's estimate and the measured currents."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .config import (
    _A,
    _ACAP,
    _AREF,
    _B,
    _C,
    _D,
    _G,
    _ILIM,
    _K,
    _KC,
    _KD,
    _KI,
    _KP,
    _N1,
    _N2,
    _P,
    _Q,
    _R,
    _RSTOP,
    _T,
    _TCAP,
    _UMAX,
    _VREF,
)
from .observer import _deltas


@njit(cache=True)
def _land_law(p: np.ndarray, s: np.ndarray, ref: np.ndarray, ui: np.ndarray, i: np.ndarray, landed: bool,
              u: np.ndarray) -> None:
    """Voltages u (2,) of the landing law.

    ref (3, 2) = [r, r', r''] per load point and ui (2,) the current loop's integral [V] are advanced here.
    """
    T = p[_T]
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    dd1 = p[_P] * s[1, 0] + p[_Q] * s[1, 1]
    dd2 = p[_Q] * s[1, 0] + p[_P] * s[1, 1]
    istar1 = 0.0
    istar2 = 0.0
    if not landed:
        a1 = ref[2, 0] + p[_KD] * (ref[1, 0] - s[1, 0]) + p[_KP] * (ref[0, 0] - s[0, 0])
        a2 = ref[2, 1] + p[_KD] * (ref[1, 1] - s[1, 1]) + p[_KP] * (ref[0, 1] - s[0, 1])
        h1 = p[_C] * p[_N1] + p[_D] * p[_N2] + p[_G] - a1 + s[2, 0]  # M F* = n - a* + b
        h2 = p[_D] * p[_N1] + p[_C] * p[_N2] + p[_G] - a2 + s[2, 1]
        det = p[_A] * p[_A] - p[_B] * p[_B]
        F1 = (p[_A] * h1 - p[_B] * h2) / det
        F2 = (-p[_B] * h1 + p[_A] * h2) / det
        F1 = min(max(F1, 0.0), p[_K] * p[_ILIM] * p[_ILIM] / (de1 * de1))
        F2 = min(max(F2, 0.0), p[_K] * p[_ILIM] * p[_ILIM] / (de2 * de2))
        istar1 = de1 * math.sqrt(F1 / p[_K])
        istar2 = de2 * math.sqrt(F2 / p[_K])
        # the reference stops a rising plate (r'' = a_cap while r' < 0), descends (r'' = a_ref up to
        # r' = v_ref) and stops at r_stop
        for j in range(2):
            ref[0, j] += T * ref[1, j] + 0.5 * T * T * ref[2, j]
            ref[1, j] += T * ref[2, j]
            if ref[1, j] < 0.0:
                ref[2, j] = min(max(-ref[1, j] / p[_TCAP], p[_AREF]), p[_ACAP])
            elif ref[1, j] >= p[_VREF]:
                ref[1, j] = p[_VREF]
                ref[2, j] = 0.0
            else:
                ref[2, j] = p[_AREF]
            if ref[0, j] >= p[_RSTOP]:
                ref[0, j] = p[_RSTOP]
                ref[1, j] = 0.0
                ref[2, j] = 0.0
    else:
        ui[0] = 0.0
        ui[1] = 0.0
    kK = 2.0 * p[_K]
    e1 = istar1 - i[0]
    e2 = istar2 - i[1]
    u[0] = p[_R] * i[0] + ui[0] + kK / de1 * (p[_KC] * e1 - i[0] * dd1 / de1)
    u[1] = p[_R] * i[1] + ui[1] + kK / de2 * (p[_KC] * e2 - i[1] * dd2 / de2)
    for j in range(2):
        lim = p[_UMAX]
        if u[j] > lim:
            u[j] = lim
        elif u[j] < -lim:
            u[j] = -lim
        elif not landed:  # integrate only when not saturated (anti-windup)
            e = e1 if j == 0 else e2
            de = de1 if j == 0 else de2
            ui[j] += T * p[_KI] * kK / de * e
