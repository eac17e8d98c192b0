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

from dataclasses import dataclass

import numpy as np

__all__ = ["HoverFit", "hover_residuals", "solve_hover", "window_means"]

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


def hover_residuals(phi: np.ndarray, Z: np.ndarray, U: np.ndarray, geo: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(r, J): the hover equations per row of Z (n, 6), U (n, 2) -> r (n, 4) = [c1, c2, f1, f2]; J = dr/dphi (n, 4, 4).

    ``geo``: P, Q, cA, cC, N1, N2, g, floor (gap floor of the law, m).
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
) -> HoverFit:
    """Solve the hover equations of the module docstring from the window (Z (n, 6), U (n, 2)).

    ``phi0`` (4,): prior (1/m, R, K, rho); ``scale`` (4,): phi = scale * v; ``P0`` (4, 4): prior covariance
    of v; ``lo``, ``hi`` (4,): the law's bounds on phi.
    """
    Z = np.atleast_2d(np.asarray(Z, float))
    U = np.atleast_2d(np.asarray(U, float))
    n = Z.shape[0]
    zm, um = window_means(Z, U)
    sq = np.sqrt(np.clip(np.diag(P0), 0.0, None))
    v = np.asarray(phi0, float) / scale
    s = np.zeros(len(v))

    k = 0
    for _ in range(iterations):
        phi = scale * v
        rk, _ = hover_residuals(phi, Z, U, geo)
        r, J = hover_residuals(phi, zm[None], um[None], geo)
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
    r, _ = hover_residuals(phi, zm[None], um[None], geo)
    return HoverFit(phi=phi, determined=k, singular_values=s, residual=_solved(r[0]), pitch=float(r[0, 2] - r[0, 3]),
                    samples=n)


def _solved(a: np.ndarray) -> np.ndarray:
    """The equations that are solved: [c1, c2, f1 + f2] from rows [c1, c2, f1, f2] (first axis)."""
    return np.concatenate([a[:2], a[2:3] + a[3:4]])
