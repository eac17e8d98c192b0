r"""Hover initialisation: start the adaptive law from a window of pre-roll samples.

Before t = 0 the plate rests in an equilibrium (level or tilted) held by the
voltages u_j. The controller collects ``n`` samples of what it sees there
(estimated state z_k = [d1, d1', d2, d2', i1, i2], applied voltage u_k) and
filters them: the window mean (the minimum-variance estimate of a constant in
white noise) gives d_j, i_j, u_j; the scatter of the per-sample equations gives
how well each equation is known.

**The hover equations** of the law's model (docs/manual/model.md and controllers.md, hover initialisation) at rest
(d' = d'' = i' = 0), in phi = (mu, R, K, rho), mu = 1/m, coil resistances
R_1,2 = R +- rho, with delta_j of Eq. 6 and q_j = i_j^2 / delta_j^2::

    c_j = (R +- rho) i_j - u_j                                    = 0   (coil j, j = 1, 2)
    f_1 = -(mu + c_A) K q_1 - (mu - c_A) K q_2 + (mu + c_C) N_1 + (mu - c_C) N_2 + g = 0
    f_2 = -(mu - c_A) K q_1 - (mu + c_A) K q_2 + (mu - c_C) N_1 + (mu + c_C) N_2 + g = 0

(c_A = L l / I, c_C = L^2 / I; c_j = 0 is W3^T theta = 0 and f_j = 0 is
W2^T theta + g = 0 of the old single-sample initialisation). What they determine:

* the coil equations fix R and rho (each coil its own resistance);
* f_1 + f_2 = 2 mu (N_1 + N_2 - K (q_1 + q_2)) + 2 g = 0 (heave) fixes one
  combination of (mu, K): K (q_1 + q_2) = N_1 + N_2 + m g. Mass and force
  coefficient are *not* separately determined at rest;
* f_1 - f_2 = -2 c_A K (q_1 - q_2) + 2 c_C (N_1 - N_2) (pitch) does not
  involve mu or R, and at every equilibrium of the model its K-derivative
  -2 c_A (q_1 - q_2) = -2 c_A (L/l)(N_1 - N_2)/K vanishes with N_1 = N_2 (level
  or tilted, the forces are equal: :func:`dem_ros.core.model.hover_forces`):
  it determines nothing. A measured q_1 != q_2 is noise or a mismatch the law
  cannot represent (a gap-sensor offset, an off-centre load); solving it (the
  old single-sample ``pinv(rcond=1e-10)`` kept that direction) drives K to
  zero and m to its bound. It is reported (``HoverFit.pitch``), never solved.

**The solve.** Gauss-Newton on r(v) = [c_1, c_2, f_1 + f_2] in the scaled
estimation coordinates v = phi / phi_0 of the law, whitened by the standard
error of each equation's window mean (std of the per-sample values / sqrt(n),
floored at 1e-9 of the equation's size so an exact, noiseless window stays
finite) and expressed in units of the prior standard deviation (P0^{1/2}):

    J~ = S^-1 (dr/dv) P0^{1/2} = U diag(s) V^T          (SVD)
    dv = -P0^{1/2} V_k diag(1/s_k) U_k^T S^-1 r          (only s_k >= s_det)

A direction is *determined* when the window pins it to better than 1/s_det of
its prior standard deviation (s_det = 10); the others keep their prior value
(at rest: R, rho and the heave combination of (mu, K) are determined, so 3 of 4;
fewer when, e.g., the currents are zero).
The step is the minimum-P0^{-1}-norm one (as docs/manual/controllers.md A2 iv), bounded to the
law's box after every iteration. P stays P0: the law keeps adapting from there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..model import gap_weights

__all__ = [
    "LIFTOFF_CATCH_S",
    "LIFTOFF_CLEARANCE",
    "LIFTOFF_MIN_S",
    "LIFTOFF_SPEED",
    "LIFT_DETECT",
    "PREMAG_FRACTION",
    "RAMP_MAX",
    "RAMP_RATE",
    "RESTING_FRACTION",
    "HoverFit",
    "departure_acceleration",
    "hover_residuals",
    "lift_fraction",
    "liftoff_duration",
    "liftoff_reference",
    "liftoff_target",
    "premagnetise",
    "solve_hover",
    "window_means",
]

S_DET = 10.0  # a direction is solved when the window knows it 10x better than the prior
FLOOR = 1e-9  # relative floor of an equation's standard error (exact windows)


@dataclass(frozen=True)
class HoverFit:
    """Result of :func:`solve_hover`.

    Attributes:
        phi (4,): (1/m, R, K, rho) after the solve (1/kg, ohm, N m^2/A^2, ohm).
        determined: number of directions of phi the window determined (3 at any rest of the model).
        singular_values (3,): s of the whitened, prior-scaled Jacobian (last iteration).
        residual (3,): [c1, c2 (V), f1 + f2 (m/s^2)] at the window means after the solve.
        pitch: f1 - f2 (m/s^2) at the window means (not solved; non-zero: sensor offset or off-centre load).
        samples: window length n.
    """

    phi: np.ndarray
    determined: int
    singular_values: np.ndarray
    residual: np.ndarray
    pitch: float
    samples: int


def window_means(Z: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means of a window: Z (n, 6) -> (6,), U (n, 2) -> (2,); a single sample (6,), (2,) is a window of one."""
    Z = np.atleast_2d(np.asarray(Z, float))
    U = np.atleast_2d(np.asarray(U, float))
    return Z.mean(axis=0), U.mean(axis=0)


def hover_residuals(phi: np.ndarray, Z: np.ndarray, U: np.ndarray, geo: dict[str, float],
                    A: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(r, J): the hover equations per row of Z (n, 6), U (n, 2) -> r (n, 4) = [c1, c2, f1, f2]; J = dr/dphi (n, 4, 4).

    ``geo``: P, Q, cA, cC, N1, N2, g, floor (gap floor of the law, m). ``A`` (n, 2): the gaps' measured
    accelerations y_j'' [m/s^2] (down positive) when the plate is not at rest (f_j - y_j'' = 0); None: at rest.
    """
    mu, R, K, rho = phi
    d1 = np.maximum(Z[:, 0], geo["floor"])
    d2 = np.maximum(Z[:, 2], geo["floor"])
    de1 = geo["P"] * d1 + geo["Q"] * d2
    de2 = geo["Q"] * d1 + geo["P"] * d2
    i1, i2 = Z[:, 4], Z[:, 5]
    q1, q2 = (i1 / de1) ** 2, (i2 / de2) ** 2
    cA, cC, N1, N2, g = geo["cA"], geo["cC"], geo["N1"], geo["N2"], geo["g"]
    n = Z.shape[0]
    r = np.empty((n, 4))
    r[:, 0] = (R + rho) * i1 - U[:, 0]
    r[:, 1] = (R - rho) * i2 - U[:, 1]
    r[:, 2] = -(mu + cA) * K * q1 - (mu - cA) * K * q2 + (mu + cC) * N1 + (mu - cC) * N2 + g
    r[:, 3] = -(mu - cA) * K * q1 - (mu + cA) * K * q2 + (mu - cC) * N1 + (mu + cC) * N2 + g
    if A is not None:
        r[:, 2:] -= np.asarray(A, float).reshape(n, 2)
    J = np.zeros((n, 4, 4))
    J[:, 0, 1] = J[:, 0, 3] = i1
    J[:, 1, 1] = i2
    J[:, 1, 3] = -i2
    J[:, 2, 0] = J[:, 3, 0] = -K * (q1 + q2) + N1 + N2
    J[:, 2, 2] = -(mu + cA) * q1 - (mu - cA) * q2
    J[:, 3, 2] = -(mu - cA) * q1 - (mu + cA) * q2
    return r, J


def solve_hover(
    phi0: np.ndarray,
    scale: np.ndarray,
    P0: np.ndarray,
    Z: np.ndarray,
    U: np.ndarray,
    geo: dict[str, float],
    lo: np.ndarray,
    hi: np.ndarray,
    iterations: int = 6,
    A: np.ndarray | None = None,
) -> HoverFit:
    """Solve the hover equations of the module docstring from the window (Z (n, 6), U (n, 2)).

    ``phi0`` (4,): prior (1/m, R, K, rho); ``scale`` (4,): phi = scale * v; ``P0`` (4, 4): prior covariance
    of v; ``lo``, ``hi`` (4,): the law's bounds on phi. ``A`` (n, 2): the window's measured gap accelerations
    [m/s^2] when the plate is not at rest (a plate leaving its support: :data:`LIFT_DETECT`); None: at rest.
    """
    Z = np.atleast_2d(np.asarray(Z, float))
    U = np.atleast_2d(np.asarray(U, float))
    n = Z.shape[0]
    A = None if A is None else np.asarray(A, float).reshape(n, 2)
    am = None if A is None else A.mean(axis=0)[None]
    zm, um = window_means(Z, U)
    sq = np.sqrt(np.clip(np.diag(P0), 0.0, None))
    v = np.asarray(phi0, float) / scale
    s = np.zeros(len(v))

    k = 0
    for _ in range(iterations):
        phi = scale * v
        rk, _ = hover_residuals(phi, Z, U, geo, A)
        r, J = hover_residuals(phi, zm[None], um[None], geo, am)
        r, J = _solved(r[0]), _solved(J[0])
        rk = _solved(rk.T).T
        size = np.array([abs(um[0]), abs(um[1]), geo["g"]]) + 1e-300
        se = np.sqrt(np.var(rk, axis=0) / n) if n > 1 else np.zeros(3)
        se = np.maximum(se, FLOOR * size)
        Jt = (J * scale[None, :] * sq[None, :]) / se[:, None]
        Uu, s, Vt = np.linalg.svd(Jt, full_matrices=False)
        keep = s >= S_DET
        k = int(keep.sum())
        if k == 0:
            break
        w = -(Vt[keep].T @ ((Uu[:, keep].T @ (r / se)) / s[keep]))
        v = np.clip(scale * (v + sq * w), lo, hi) / scale
    phi = scale * v
    r, _ = hover_residuals(phi, zm[None], um[None], geo, am)
    return HoverFit(phi=phi, determined=k, singular_values=s, residual=_solved(r[0]), pitch=float(r[0, 2] - r[0, 3]),
                    samples=n)


def _solved(a: np.ndarray) -> np.ndarray:
    """The equations that are solved: [c1, c2, f1 + f2] from rows [c1, c2, f1, f2] (first axis)."""
    return np.concatenate([a[:2], a[2:3] + a[3:4]])


# ---------------------------------------------------------------------------------------------
# Lift-off: starting the law from a plate that rests on its support (added for restarts, #11/#12)
# ---------------------------------------------------------------------------------------------
#
# The hover initialisation above needs a levitating plate: with the coils off (i = 0) its
# equations say nothing about R or K, and the heave equation mu (N1 + N2) + g = 0 has no
# admissible solution, so the fit would drive the mass to its bound. Worse, the CE law itself
# is singular at i = 0 (dF_j/di_j = 2 K i_j / delta_j^2: the current cannot be steered through
# a coil that carries none), and neither the law's model nor the estimator's knows the support:
# run on a plate that rests on it, they see a plate that does not fall and adapt to that
# (measured on the emulated rig: the law wound up for 1.4 s, then drove the plate into the rail).
# A plate on its support is therefore started in four steps:
#
# 1. *recognise it*: the magnets carry less than RESTING_FRACTION of the load
#    (:func:`lift_fraction` on the nominal model): a hovering plate carries all of it;
# 2. *premagnetise* (:func:`premagnetise`): hold u_j = R i*_j with i*_j the current of
#    PREMAG_FRACTION of the hover force of magnet j at the measured gaps; the coil settles with
#    its time constant L/R = (2K/delta)/R ~ 4 ms and the plate stays on its support (half its
#    load; with K and m off by 25 % at most 0.5 * 1.25 / 0.75 = 83 % of the true one);
# 3. *raise the force* at RAMP_RATE (share of the nominal hover force per second, up to
#    RAMP_MAX) until the plate leaves its support by LIFT_DETECT: the force then just exceeds
#    the true load. The plate is not at rest there: the magnets' negative stiffness has
#    accelerated it for some 20 ms;
# 4. start the law *with* its hover fit from that sample, the heave equation equal to the
#    measured accelerations (``solve_hover(A=...)``: fitted as a rest, the model takes the net
#    force for a bias, and the law's error settles at k1 a / k3, about 1 mm above its
#    reference), and the *lift-off reference* (:func:`liftoff_reference`): a C^3 blend from
#    where the plate is, with its rates, to the reference stream, at least LIFTOFF_CLEARANCE
#    off the support (:func:`liftoff_target`). Both matter most when commands take several
#    samples to the coils (tests/graph/test_restart.py; figures: docs/results.md,
#    "Hardware in the loop").

RESTING_FRACTION = 0.25  # the magnets carry less than this share of the load: the plate rests on its support
PREMAG_FRACTION = 0.5  # premagnetise to this share of the hover force (the plate stays on its support)
RAMP_RATE = 0.2  # 1/s: the premagnetising force rises by this share of the nominal hover force per second
RAMP_MAX = 1.5  # the ramp stops at this share (the plate cannot be that much heavier than its data sheet)
LIFT_DETECT = 1e-4  # m: the plate has left its support when a gap is this much smaller than where it rested
LIFTOFF_SPEED = 5e-3  # m/s: peak speed of the lift-off blend (half the board's default landing speed)
LIFTOFF_MIN_S = 0.5  # s: the shortest lift-off blend
LIFTOFF_CLEARANCE = 1e-3  # m: the lift-off takes the plate at least this far off its support
#: s: the lift-off reference starts with the plate's own rates, which fade with this time constant (about the
#: law's error dynamics at its default gains: poles at -20, -20, -30 1/s)
LIFTOFF_CATCH_S = 0.05


def _hover_forces(cfg: Mapping[str, Any]) -> np.ndarray:
    """Hover forces F_j (2,) [N] of the nominal model: F1 + F2 = m g + N1 + N2, (F1 - F2) l = (N1 - N2) L."""
    w = cfg["m_nominal"] * cfg["g"] + cfg["N1"] + cfg["N2"]
    d = cfg["L"] / cfg["l"] * (cfg["N1"] - cfg["N2"])
    return np.maximum(0.5 * np.array([w + d, w - d]), 0.0)


def _deltas(cfg: Mapping[str, Any], z: np.ndarray) -> np.ndarray:
    """Magnet gaps delta_j (2,) [m] (Eq. 6) of the load-point gaps z[0], z[2], floored at gap_floor."""
    L, l = cfg["L"], cfg["l"]
    P, Q = gap_weights(L, l)
    d1, d2 = max(z[0], cfg["gap_floor"]), max(z[2], cfg["gap_floor"])
    return np.array([P * d1 + Q * d2, Q * d1 + P * d2])


def lift_fraction(z: np.ndarray, cfg: Mapping[str, Any]) -> float:
    """Share of the load the magnets carry: sum_j K i_j^2/delta_j^2 / (m g + N1 + N2) (nominal model).

    ``z`` = [d1, d1', d2, d2', i1, i2] (m, m/s, A); ``cfg``: the controller group (L, l, N1, N2, g,
    m_nominal, K_nominal, gap_floor). About 1 at hover; below ``RESTING_FRACTION`` the plate rests
    on its support (or falls).
    """
    # Python floats throughout (one tolist(), no numpy scalars): the controller evaluates this every sample
    d1, _, d2, _, i1, i2 = z.tolist()[:6] if isinstance(z, np.ndarray) else [float(v) for v in z[:6]]
    L, l, floor = cfg["L"], cfg["l"], cfg["gap_floor"]
    P, Q = gap_weights(L, l)
    d1, d2 = max(d1, floor), max(d2, floor)
    de1, de2 = P * d1 + Q * d2, Q * d1 + P * d2  # Eq. (6), as _deltas
    f = cfg["K_nominal"] * (i1 * i1 / (de1 * de1) + i2 * i2 / (de2 * de2))
    return float(f / (cfg["m_nominal"] * cfg["g"] + cfg["N1"] + cfg["N2"]))


def premagnetise(z: np.ndarray, cfg: Mapping[str, Any],
                 fraction: float = PREMAG_FRACTION) -> tuple[np.ndarray, np.ndarray]:
    """(i*, u) (2,), (2,) [A], [V]: the currents of ``fraction`` of the nominal hover force at the
    measured gaps, i*_j = delta_j sqrt(fraction F_j / K), and the voltages that hold them,
    u_j = R_nominal i*_j."""
    i_star = _deltas(cfg, z) * np.sqrt(fraction * _hover_forces(cfg) / cfg["K_nominal"])
    return i_star, cfg["R_nominal"] * i_star


def departure_acceleration(y_rest: np.ndarray, y: np.ndarray, v: np.ndarray, g: float) -> np.ndarray:
    """The gaps' accelerations (2,) [m/s^2] of a plate leaving its support: rising from rest at ``y_rest`` (2,) to
    ``y`` (2,) [m], now at the rates ``v`` (2,) [m/s] (gaps shrink: up is negative), at constant acceleration
    a_j = -v_j^2 / (2 (y_rest,j - y_j)).

    Exact for a constant acceleration; the departure itself accelerates (the magnets' negative stiffness: from rest,
    y_rest - y = A (cosh(lambda t) - 1)), so it gives between 1/2 and 1 of the true one: it never overstates it,
    which would leave the law's model a bias the other way (toward the support). Robust where a difference of
    estimated rates is not (under gap noise that can even take the wrong sign). A magnet that has not risen
    LIFT_DETECT / 2, or does not rise, gets 0; at most 2 g (y_rest - y) / y_rest up.
    """
    dy = np.asarray(y_rest, float) - np.asarray(y, float)
    v = np.asarray(v, float)
    a = np.zeros(2)
    rising = (dy >= LIFT_DETECT / 2) & (v < 0.0)
    # at most what the magnets' negative stiffness gives a plate that left its rest at the hover force:
    # lambda^2 dy, lambda^2 = 2 g / y (F ~ 1/y^2); a lagging estimate (rates that caught up late, the gap not yet)
    # overstates v^2 / 2 dy: the law would then let the plate fall back
    a[rising] = -np.minimum(v[rising] ** 2 / (2 * dy[rising]), 2 * g * dy[rising] / np.asarray(y_rest, float)[rising])
    return a


def liftoff_target(y0: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, bool]:
    """The reference the lift-off blends to: ``ref`` (8,), except that a magnet whose reference is not
    ``LIFTOFF_CLEARANCE`` off the support (y0 (2,), the landed gaps) is held at rest that far off it.

    A plate tracking a reference *at* its support does not leave it: the law's model, which has no
    support, sees the plate not falling and adapts to that. Returns (target (8,), True when ``ref`` itself
    is the target: the lift-off can hand over to the stream).
    """
    out = np.array(ref[:8], dtype=float)
    off = np.asarray(y0, float) - LIFTOFF_CLEARANCE  # y positive down: off the support = a smaller gap
    held = out[:2] > off
    for j in np.flatnonzero(held):
        out[j], out[2 + j], out[4 + j], out[6 + j] = off[j], 0.0, 0.0, 0.0
    return out, not bool(held.any())


def liftoff_duration(y0: np.ndarray, ref: np.ndarray) -> float:
    """Length T [s] of the blend from the landed gaps ``y0`` (2,) to the reference gaps ``ref[:2]``:
    the blend's peak speed 35/16 |dy| / T equals ``LIFTOFF_SPEED``, and T >= ``LIFTOFF_MIN_S``."""
    dy = float(np.max(np.abs(np.asarray(ref[:2], float) - np.asarray(y0, float))))
    return max(LIFTOFF_MIN_S, 35.0 / 16.0 * dy / LIFTOFF_SPEED)


def liftoff_reference(y0: np.ndarray, ref: np.ndarray, t: float, T: float, v0: np.ndarray | None = None,
                      a0: np.ndarray | None = None) -> np.ndarray:
    r"""The lift-off reference (8,) at ``t`` s after the start: from rest at ``y0`` to ``ref``.

    ``ref`` (8,) = [y1, y2, y1', y2', y1'', y2'', y1''', y2'''] (m, m/s, m/s^2, m/s^3), the
    reference stream at the same instant. With a = [y0, 0, 0, 0] (rest) and b = ``ref``, the
    blend y = (1 - s) a + s b, s(tau) = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7, tau = t/T in
    [0, 1] (s and its first three derivatives vanish at 0, the derivatives at 1: C^3 at both
    ends), has by Leibniz

        y'   = s b' + s_t (b - a)
        y''  = s b'' + 2 s_t b' + s_tt (b - a)
        y''' = s b''' + 3 s_t b'' + 3 s_tt b' + s_ttt (b - a)

    with s_t = s'/T, s_tt = s''/T^2, s_ttt = s'''/T^3. Peak |s'| = 35/16 (at tau = 1/2).

    A plate that leaves its support is already moving: ``v0``, ``a0`` (2,) (m/s, m/s^2), its gap rates and
    accelerations at t = 0. The reference then starts with them, so that the law does not begin by fighting
    (and winding its integral up against) the motion the lift-off itself started: it adds the catch term

        c(t) = (v0 t + (a0 / 2 + v0 / tau_c) t^2) exp(-t / tau_c),   tau_c = LIFTOFF_CATCH_S

    (c = 0, c' = v0, c'' = a0 at t = 0; it fades within a few tau_c), with its derivatives.
    """
    tau = min(max(t / T, 0.0), 1.0)
    s0 = tau**4 * (35 - 84 * tau + 70 * tau**2 - 20 * tau**3)
    s1 = 140 * tau**3 * (1 - tau) ** 3 / T
    s2 = 420 * tau**2 * (1 - tau) ** 2 * (1 - 2 * tau) / T**2
    s3 = 840 * tau * (1 - tau) * (5 * tau**2 - 5 * tau + 1) / T**3
    b = np.asarray(ref[:8], float)
    a = np.asarray(y0, float)
    dy = b[:2] - a
    out = np.empty(8)
    out[:2] = a + s0 * dy
    out[2:4] = s0 * b[2:4] + s1 * dy
    out[4:6] = s0 * b[4:6] + 2 * s1 * b[2:4] + s2 * dy
    out[6:8] = s0 * b[6:8] + 3 * s1 * b[4:6] + 3 * s2 * b[2:4] + s3 * dy
    if v0 is not None or a0 is not None:
        c1 = np.zeros(2) if v0 is None else np.asarray(v0, float)
        c2 = ((np.zeros(2) if a0 is None else np.asarray(a0, float)) + 2 * c1 / LIFTOFF_CATCH_S) / 2
        tc = max(t, 0.0)
        r, E = 1 / LIFTOFF_CATCH_S, math.exp(-tc / LIFTOFF_CATCH_S)
        p, p1, p2 = c1 * tc + c2 * tc * tc, c1 + 2 * c2 * tc, 2 * c2
        out[:2] += p * E
        out[2:4] += (p1 - r * p) * E
        out[4:6] += (p2 - 2 * r * p1 + r * r * p) * E
        out[6:8] += (-3 * r * p2 + 3 * r * r * p1 - r**3 * p) * E
    return out
