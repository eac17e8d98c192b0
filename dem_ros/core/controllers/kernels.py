r"""Compiled control laws (numba). One step = one sample of the 1 kHz loop.

Certainty-equivalence (CE) family, paper Eqs. 17-36 corrected (docs/manual/controllers.md).
Every member shares the control law and the augmented error; they differ in
how theta_hat is adapted (``mode``):

    MODE_FIXED     nonlinear decoupling with fixed theta (De-Sheng et al. 2006)
    MODE_PAPER     "A0": Eq. 36 as printed (continuous normalised LS, +P')
    MODE_PAPER_FIX "A1": 8 free theta, per-sample RLS, scaled, cone projection
    MODE_ADAPTIVE  "A2": phi = (1/m, R, K, rho), Gauss-Newton RLS on e_c and the coil equations,
                   random walks, bounds, integral action
    MODE_ENHANCED  "A2e": A2 + corrected leakage and dead zone of Eq. 48

Per sample k (docs/manual/controllers.md, "common loop")::

    xi, zeta  <- outputs of F(s) from the previous updates
    e         = y - y_d
    e_c       = xi^T theta_hat - zeta - e            (= xi^T (theta_hat - theta))
    theta_hat <- update(e_c)
    v_e       = y_d''' - k1((L_f^2 h)_e - y_d'') - k2(y' - y_d') - k3 e     (Eq. 21, erratum 7)
    u         = M_hat^{-1} (v_e - (L_f^3 h)_e)                                (Eq. 22)
    u_a       = the voltage applied over this sample: u_{k-delay}, clipped to +-min(voltage_limit, u_max)
    W_p       = W3(x, u_a) + k1 W2(x)
    F(s) bank <- advance with W_p (2 NTH channels) and v_e + k1 W2^T theta_hat (2 channels)

The law clips its command at +-min(``voltage_limit``, ``u_max``): ``u_max`` is the board's coil-driver limit
(the ``SAFETY_SPECS`` value of ``plant_sim`` / ``hw_driver``, which ``simulate`` and the launcher give the
controller group), so the u_a the law feeds its augmented error and its integrator is the voltage the board
applies, also when the board clips (a measured bus below ``u_max`` is still unknown to the law).

The last input equals W_p^T theta_hat when u_a is the law's own unclipped output
(W3(u)^T theta_hat = v_e). In general the error equation is

    e^(3) + k1 e^(2) + k2 e^(1) + k3 e = W_p(u_a)^T (theta - theta_hat) + [W3(u_a)^T theta_hat - v_e]

and the bracket is known, so filtering v_e + k1 W2^T theta_hat keeps
e_c = xi^T (theta_hat - theta) exact under a command delay and under clipping.

**Drifting coils: why A2 adds two things** (S5: R1 +20 %, R2 +10 % over 100 s).
At rest the e_c rows cannot tell a resistance error from a mass error: a
voltage error dV_j = (R_j_hat - R_j) i_j makes a constant jerk error
-(A b_j) dV_j, a mass error a constant acceleration error, and F(s) turns
both into constant e_c vectors (the hover equations of :mod:`.hover`: R and
the heave combination of (mu, K) only). With the random walk on 1/m, the
mass estimate absorbed the drift of R (m_hat 8.6 -> 10.4 kg, R_hat *falling*
while R rose) and the plate was lost at 13.7 s. And without integral action a
constant parameter error leaves e = W_p^T theta~ / k3: 6.5 mm per volt of coil
error (A b_j / k3 at the 8 mm hover), so 10 um asks R to 0.4 mOhm while it
drifts by 40 mOhm/s. Hence (A2, A2e):

1. *Coil equations as regression rows.* Each coil obeys u_j = R_j i_j +
   2K d(i_j/delta_j)/dt, linear in (R_j = R +- rho, K). Filtered by
   lp = a/(z - (1 - a)) (a = 1 - exp(-bw T), ``coil_bandwidth``; the derivative
   enters as lp of (b_{k+1} - b_k)/T over the period u_{a,k} was held, so no
   current is differentiated), the residual

       r_j = kappa_j (R_j_hat lp(i_j) + 2 K_hat lp(b_j') - lp(u_j)),  kappa_j = (mu_hat + c_A) |b_j| / k3

   Per coil j, over the period [t_{k-1}, t_k) (:func:`_coil_rows`, ``coil`` state)::

       lp(u_j)  += a (u_{a,j} - lp(u_j))                  u_a: the voltage applied over that period
       lp(i_j)  += a (0.5 (i_{j,k-1} + i_{j,k}) - lp(i_j))   the trapezoid: the mean current of the period
       lp(b_j') += a ((b_{j,k} - b_{j,k-1}) / T - lp(b_j'))  b_j = i_j / delta_j [A/m]

   and they start (the first sample after a reset: no previous i, b) at lp(u_j) = u_{a,j}, lp(i_j) = i_{j,0},
   lp(b_j') = 0, with no coil rows in that sample.

   joins e_c in the least squares with weight ``coil_weight`` x kappa_j, the
   tracking error (m) a coil misfit of 1 V would cause; its rows in (R, rho)
   (K_hat taken as known there). R and rho are then pinned where they are observable (in the
   current), not in the tracking error, and the random walks q_R, q_rho let
   them follow heating. The slow bw (10 rad/s) averages out fast voltages the
   law does not know (a 50 Hz disturbance: S4b), whose correlation with lp(i)
   would bias R_hat.
2. *Integral action.* The command uses v_e - ki sigma_hat with
   sigma_hat = ((L_f^2 h)_e - y_d'') + k1 e' + k2 e + k3 E, E = int e dt
   (state ``ie``, not integrated while the command is clipped). With
   sigma = sigma_hat + W2^T theta~ (true acceleration) the loop is

       sigma' + ki sigma = (W_p + ki W2)^T theta~,   sigma = (s^3 + k1 s^2 + k2 s + k3) E

   i.e. the designed poles (s + 20)^2 (s + 30) plus one at -ki, and a constant
   (or constantly lagging) theta~ leaves no steady error. F(s) keeps filtering
   v_e *without* the integral term, so the e_c identity above is untouched.

The paper's laws (A0, A1) and ``nonlinear_decoupling`` keep neither (baselines as published).
Measured (100 s, kf, delay 1): S5 RMS 2.6 / 1.7 um (was: lost at 13.7 s); each part alone:
q_R, q_rho 337 / 367 um; + coil rows 151 / 109 um; + integral action 35 / 35 um.

State arrays (all float64, owned by the caller; :class:`CEState` names them, :class:`CELaw` the constants):
    theta (NTH,)  theta_hat used by the law (unscaled, Eq. 44 order, then A rho/2, B rho/2:
                  per-coil resistance R1,2 = R +- rho, see :mod:`dem_ros.core.model`)
    v (NTH,)      estimate in estimation coordinates (A0: theta; A1: theta/scale;
                  A2: phi/phi0 in the first 4 entries, phi = (1/m, R, K, rho), rho scaled by R0)
    scale (NTH,)  the scaling (A0: ones; A1: theta magnitudes; A2: phi0)
    v0 (NTH,)     leakage target (A2e)
    P (NTH, NTH)  covariance (A0, A1 use the leading 8x8 and keep rho = 0; A2 the leading 4x4)
    Z (3, NZ)     F(s) filter bank: 2 NTH channels of W_p, 2 of v_e + k1 W2^T theta_hat
    uh (NUH, 2)   last commands, newest first: the voltage applied now is uh[delay]
    ie (2,)       integral of e (m s), A2 / A2e
    coil (5, 2)   coil-equation filters per coil: lp(u), lp(i), lp(b'), previous i, b (A2 / A2e)
    cp (NCP,)     configuration vector, layout CP_* below
    diag (NDIAG,) out: m_hat, R_hat, K_hat, ec1, ec2, e1, e2, adapting, fault
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..model import (
    IA,
    IB,
    IC,
    ID,
    IG,
    IK,
    IK2,
    IN1,
    IN2,
    IP,
    IQ,
    IR1,
    IR2,
    NPP,
    lie_terms,
    regressors,
    rk4,
    theta_jacobian,
    theta_of,
)

MODE_FIXED, MODE_PAPER, MODE_PAPER_FIX, MODE_ADAPTIVE, MODE_ENHANCED = 0, 1, 2, 3, 4

# configuration vector layout
(
    CP_K1, CP_K2, CP_K3, CP_P, CP_Q, CP_CA, CP_CC, CP_N1, CP_N2, CP_G,
    CP_FLOOR, CP_TS, CP_W, CP_R0, CP_DZ, CP_E0,
    CP_MU_MIN, CP_MU_MAX, CP_R_MIN, CP_R_MAX, CP_K_MIN, CP_K_MAX,
    CP_QM, CP_QR, CP_QK, CP_ULIM, CP_DELAY,
) = range(27)
CP_QRHO, CP_RHO_MAX, CP_KI, CP_COIL_W, CP_COIL_A = 27, 28, 29, 30, 31
NCP = 32
NUH = 9  # longest command delay (samples) + 1
NTH = 10  # theta entries (8 of Eq. 44 + 2 for the coil-resistance difference)
NZ = 2 * NTH + 2  # F(s) channels
NPHI = 4  # A2: phi = (1/m, R, K, rho)
DZ_PDOT, DZ_ERROR, DZ_OFF = 0, 1, 2
#: A2's coil rows as plain floats (no per-sample arrays): the weighted residuals rc_1, rc_2, their
#: derivatives w.r.t. the scaled R (rc_1, rc_2), then w.r.t. the scaled rho (rc_1, rc_2); the others are 0
CoilRows = tuple[float, float, float, float, float, float]
NO_COIL_ROWS: CoilRows = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

(D_M, D_R, D_K, D_EC1, D_EC2, D_E1, D_E2, D_ADAPT, D_FAULT) = range(9)
NDIAG = 9

#: :class:`dem_ros.core.controllers.CEController` keeps a law's arrays in two buffers (the records' fields are
#: views into them), so that a step called from Python passes two arrays, not sixteen (:func:`ce_step_buffers`).
#: The law buffer: cp, Ad (3 x 3), Bd (3,)
LB_CP = 0
LB_AD = LB_CP + NCP
LB_BD = LB_AD + 9
NLB = LB_BD + 3
#: The state buffer: the CEState fields in order, then the outputs u (2,) and diag (NDIAG,)
SB_THETA = 0
SB_V = SB_THETA + NTH
SB_SCALE = SB_V + NTH
SB_V0 = SB_SCALE + NTH
SB_P = SB_V0 + NTH
SB_Z = SB_P + NTH * NTH
SB_UH = SB_Z + 3 * NZ
SB_IE = SB_UH + NUH * 2
SB_COIL = SB_IE + 2
SB_U = SB_COIL + 5 * 2
SB_DIAG = SB_U + 2
NSB = SB_DIAG + NDIAG


class CELaw(NamedTuple):
    """What a CE law is (fixed between ``set_params``): one argument of :func:`ce_step`.

    Attributes:
        mode: MODE_* (which adaptation).
        cp (NCP,): configuration, layout CP_* above.
        Ad (3, 3), Bd (3,): F(s) = 1/(s^3 + k1 s^2 + k2 s + k3) discretised with zero-order hold.
    """

    mode: int
    cp: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray


class CEState(NamedTuple):
    """The state of a CE law (module docstring; all float64, owned by the caller)."""

    theta: np.ndarray  # (NTH,)
    v: np.ndarray  # (NTH,)
    scale: np.ndarray  # (NTH,)
    v0: np.ndarray  # (NTH,)
    P: np.ndarray  # (NTH, NTH)
    Z: np.ndarray  # (3, NZ)
    uh: np.ndarray  # (NUH, 2)
    ie: np.ndarray  # (2,) integral of e (m s), A2 / A2e only
    coil: np.ndarray  # (5, 2) coil-equation filters per coil: lp(u), lp(i), lp(b'), previous i, b (A2 / A2e)


@njit(cache=True)
def _sym2_norm(a: float, b: float, d: float) -> float:
    """2-norm of the symmetric 2x2 [[a, b], [b, d]]."""
    h = 0.5 * (a + d)
    r = np.sqrt(0.25 * (a - d) ** 2 + b * b)
    return float(max(abs(h + r), abs(h - r)))


@njit(cache=True)
def physical_estimates(theta: np.ndarray, out: np.ndarray) -> None:
    """(m_hat, R_hat, K_hat) implied by theta: C + D = 2/m, theta1/theta5 = -R, theta2/theta5 = 2K."""
    s = theta[6] + theta[7]
    out[0] = 2.0 / s if s != 0.0 else np.nan
    out[1] = -theta[0] / theta[4] if theta[4] != 0.0 else np.nan
    out[2] = theta[1] / (2.0 * theta[4]) if theta[4] != 0.0 else np.nan


@njit(cache=True)
def _rls_gain2(P: np.ndarray, X: np.ndarray, n: int, G: np.ndarray) -> None:
    """:func:`_rls_gain` for m = 2 (the e_c rows alone): the column loops have a constant length,
    so they unroll; the same operations in the same order as the general code."""
    PX = np.zeros((n, 2))
    for i in range(n):
        for j in range(2):
            s = 0.0
            for k in range(n):
                s += P[i, k] * X[k, j]
            PX[i, j] = s
    s00 = 1.0
    s01 = 0.0
    s11 = 1.0
    for k in range(n):
        s00 += X[k, 0] * PX[k, 0]
        s01 += X[k, 0] * PX[k, 1]
        s11 += X[k, 1] * PX[k, 1]
    det = s00 * s11 - s01 * s01
    i00 = s11 / det
    i01 = -s01 / det
    i11 = s00 / det
    for i in range(n):
        G[i, 0] = PX[i, 0] * i00 + PX[i, 1] * i01
        G[i, 1] = PX[i, 0] * i01 + PX[i, 1] * i11


@njit(cache=True)
def _rls_gain(P: np.ndarray, X: np.ndarray, n: int, G: np.ndarray) -> None:
    """G = P X (I + X^T P X)^{-1}; X: (n, m), G: (n, m) (m = 2: closed form, :func:`_rls_gain2`; else a solve)."""
    m = X.shape[1]
    if m == 2:
        _rls_gain2(P, X, n, G)
        return
    PX = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for k in range(n):
                s += P[i, k] * X[k, j]
            PX[i, j] = s
    S = np.eye(m)
    for a in range(m):
        for b in range(m):
            s = 0.0
            for k in range(n):
                s += X[k, a] * PX[k, b]
            S[a, b] += s
    G[:, :] = np.linalg.solve(S, np.ascontiguousarray(PX.T)).T


@njit(cache=True)
def _rls_cov_step(P: np.ndarray, G: np.ndarray, X: np.ndarray, n: int, dP: np.ndarray) -> None:
    """dP = G X^T P (the LS decrease); P is not modified. m = 2 has its own loop (constant length: unrolled)."""
    m = X.shape[1]
    if m == 2:
        for i in range(n):
            for j in range(n):
                s = 0.0
                for c in range(2):
                    t = 0.0
                    for k in range(n):
                        t += X[k, c] * P[k, j]
                    s += G[i, c] * t
                dP[i, j] = s
        return
    for i in range(n):
        for j in range(n):
            s = 0.0
            for c in range(m):
                t = 0.0
                for k in range(n):
                    t += X[k, c] * P[k, j]
                s += G[i, c] * t
            dP[i, j] = s


@njit(cache=True)
def _update_paper(cp: np.ndarray, theta: np.ndarray, v: np.ndarray, P: np.ndarray, xi: np.ndarray,
                  ec: np.ndarray) -> None:
    """A0: Eq. 36 as printed, Euler-integrated: theta' = -P xi e_c / n, P' = +P xi xi^T P / n."""
    Ts = cp[CP_TS]
    Pp = np.ascontiguousarray(P[:8, :8])
    xp = np.ascontiguousarray(xi[:8])
    PX = Pp @ xp  # (8, 2)
    S = xp.T @ PX
    nrm = 1.0 + _sym2_norm(S[0, 0], S[0, 1], S[1, 1])
    for i in range(8):
        v[i] -= Ts * (PX[i, 0] * ec[0] + PX[i, 1] * ec[1]) / nrm
    dP = Ts * (PX @ PX.T) / nrm  # the printed sign (erratum 13)
    for i in range(8):
        for j in range(8):
            P[i, j] += dP[i, j]
    for i in range(8):
        theta[i] = v[i]


@njit(cache=True)
def _update_paper_fixed(cp: np.ndarray, theta: np.ndarray, v: np.ndarray, scale: np.ndarray, P: np.ndarray,
                        xi: np.ndarray, ec: np.ndarray) -> None:
    """A1: per-sample RLS on scaled theta, decreasing P, cone projection -v5 >= |v6| + 0.01."""
    X = np.empty((8, 2))
    for i in range(8):
        X[i, 0] = scale[i] * xi[i, 0]
        X[i, 1] = scale[i] * xi[i, 1]
    G = np.empty((8, 2))
    _rls_gain(P, X, 8, G)
    dP = np.empty((8, 8))
    _rls_cov_step(P, G, X, 8, dP)
    for i in range(8):
        v[i] -= G[i, 0] * ec[0] + G[i, 1] * ec[1]
    for i in range(8):
        for j in range(8):
            P[i, j] -= 0.5 * (dP[i, j] + dP[j, i])
    # cone {-v5 >= |v6| + 0.01}: theta5 = -A/2 < 0 and |theta5| > |theta6| keep M_hat invertible.
    # Orthogonal projection onto the nearer face, or onto the apex when that face step
    # would carry v6 through zero (the region below both faces).
    s6 = 1.0 if v[5] >= 0.0 else -1.0
    g = -v[4] - s6 * v[5] - 0.01
    if g < 0.0:
        t = -0.5 * g
        if t > abs(v[5]):
            v[4] = -0.01
            v[5] = 0.0
        else:
            v[4] -= t
            v[5] -= s6 * t
    for i in range(8):
        theta[i] = scale[i] * v[i]


@njit(cache=True)
def _update_adaptive(cp: np.ndarray, theta: np.ndarray, v: np.ndarray, scale: np.ndarray, v0: np.ndarray, P: np.ndarray,
                     xi: np.ndarray, ec: np.ndarray, enhanced: bool, dz_mode: int, rows: CoilRows) -> float:
    """A2 / A2e: Gauss-Newton RLS on scaled phi = (1/m, R, K, rho); returns 1.0 if adapting.

    The rows are the augmented errors e_c (2) and, when the derivatives in ``rows`` are not all zero,
    the weighted coil equations (:data:`NO_COIL_ROWS`: none; see :func:`_coil_rows`).
    A2e's dead zone gates the whole least-squares step (estimate and covariance decrease):
    outside adaptation P only grows by the random walk, so adaptation can resume.
    """
    Ts = cp[CP_TS]
    phi = np.empty(NPHI)
    for i in range(NPHI):
        phi[i] = scale[i] * v[i]
    J = np.empty((NTH, NPHI))
    theta_jacobian(phi, cp[CP_CA], J)
    rc1, rc2, xr1, xr2, xh1, xh2 = rows
    coil = xr1 != 0.0 or xr2 != 0.0 or xh1 != 0.0 or xh2 != 0.0
    m = 4 if coil else 2
    X = np.zeros((NPHI, m))  # X = diag(phi0) J^T xi, then the coil rows (non-zero in R and rho only)
    for i in range(NPHI):
        for c in range(2):
            s = 0.0
            for k in range(NTH):
                s += J[k, i] * xi[k, c]
            X[i, c] = scale[i] * s
    if coil:
        X[1, 2] = xr1
        X[1, 3] = xr2
        X[3, 2] = xh1
        X[3, 3] = xh2
    G = np.empty((NPHI, m))
    _rls_gain(P, X, NPHI, G)
    dP = np.empty((NPHI, NPHI))
    _rls_cov_step(P, G, X, NPHI, dP)
    adapt = True
    if enhanced:
        if dz_mode == DZ_PDOT:
            adapt = np.max(np.abs(np.linalg.eigvalsh(0.5 * (dP + dP.T)))) / Ts > cp[CP_R0]
        elif dz_mode == DZ_ERROR:
            adapt = np.sqrt(ec[0] ** 2 + ec[1] ** 2) > cp[CP_E0]
    if adapt:
        if coil:
            for i in range(NPHI):
                v[i] -= G[i, 0] * ec[0]
                v[i] -= G[i, 1] * ec[1]
                v[i] -= G[i, 2] * rc1
                v[i] -= G[i, 3] * rc2
        else:
            for i in range(NPHI):
                v[i] -= G[i, 0] * ec[0]
                v[i] -= G[i, 1] * ec[1]
    if enhanced and cp[CP_W] > 0.0:
        # corrected Eq. 48b leakage towards v0: v' = -w |e_c| P (v - v0) / (1 + w^2 |P|)
        Pa = np.ascontiguousarray(P[:NPHI, :NPHI])
        Pn = np.max(np.abs(np.linalg.eigvalsh(Pa)))
        gain = Ts * cp[CP_W] * np.sqrt(ec[0] ** 2 + ec[1] ** 2) / (1.0 + cp[CP_W] ** 2 * Pn)
        dv = np.ascontiguousarray(v[:NPHI] - v0[:NPHI])
        lk = Pa @ dv
        for i in range(NPHI):
            v[i] -= gain * lk[i]
    q = (cp[CP_QM], cp[CP_QR], cp[CP_QK], cp[CP_QRHO])
    for i in range(NPHI):
        if adapt:
            for j in range(NPHI):
                P[i, j] -= 0.5 * (dP[i, j] + dP[j, i])
        P[i, i] += q[i] * Ts
    lo = (cp[CP_MU_MIN], cp[CP_R_MIN], cp[CP_K_MIN], -cp[CP_RHO_MAX])
    hi = (cp[CP_MU_MAX], cp[CP_R_MAX], cp[CP_K_MAX], cp[CP_RHO_MAX])
    for i in range(NPHI):
        ph = scale[i] * v[i]
        if ph < lo[i]:
            ph = lo[i]
        elif ph > hi[i]:
            ph = hi[i]
        v[i] = ph / scale[i]
        phi[i] = ph
    theta_of(phi, cp[CP_CA], cp[CP_CC], theta)
    return 1.0 if adapt else 0.0


@njit(cache=True)
def _coil_rows(cp: np.ndarray, scale: np.ndarray, v: np.ndarray, coil: np.ndarray, uprev: np.ndarray,
               i1: float, i2: float, b1: float, b2: float
               ) -> CoilRows:
    """The coil equations as regression rows of A2 (module docstring, "coil equations").

    ``coil`` (5, 2) filter state per coil: lp(u), lp(i), lp(b'), and the previous i, b (NaN: start).
    ``uprev`` (2,): the voltage applied over the last period (V); i_j (A), b_j = i_j/delta_j (A/m) now.
    Advances the filters over the last period, then returns the weighted residual
    rc_j = kappa_j (R_j_hat lp(i_j) + 2 K_hat lp(b_j') - lp(u_j)) and its derivatives w.r.t. v in R and
    rho, the only non-zero ones (K_hat is taken as known here): a :data:`CoilRows`, all zero at the start.
    """
    Ts = cp[CP_TS]
    a = cp[CP_COIL_A]
    start = not np.isfinite(coil[3, 0])
    ij = (i1, i2)
    bj = (b1, b2)
    for j in range(2):
        if start:
            coil[0, j] = uprev[j]
            coil[1, j] = ij[j]
            coil[2, j] = 0.0
        else:
            coil[0, j] += a * (uprev[j] - coil[0, j])
            coil[1, j] += a * (0.5 * (coil[3, j] + ij[j]) - coil[1, j])
            coil[2, j] += a * ((bj[j] - coil[4, j]) / Ts - coil[2, j])
        coil[3, j] = ij[j]
        coil[4, j] = bj[j]
    if start or cp[CP_COIL_W] <= 0.0:
        return NO_COIL_ROWS
    mu = scale[0] * v[0]
    R = scale[1] * v[1]
    Kc = scale[2] * v[2]
    rho = scale[3] * v[3]
    kap1 = cp[CP_COIL_W] * (mu + cp[CP_CA]) * abs(b1) / cp[CP_K3]  # kappa_j
    kap2 = cp[CP_COIL_W] * (mu + cp[CP_CA]) * abs(b2) / cp[CP_K3]
    return (kap1 * ((R + rho) * coil[1, 0] + 2.0 * Kc * coil[2, 0] - coil[0, 0]),
            kap2 * ((R - rho) * coil[1, 1] + 2.0 * Kc * coil[2, 1] - coil[0, 1]),
            kap1 * scale[1] * coil[1, 0], kap2 * scale[1] * coil[1, 1],
            kap1 * scale[3] * coil[1, 0], -(kap2 * scale[3]) * coil[1, 1])


@njit(cache=True)
def _ydd_hat(theta: np.ndarray, ab: np.ndarray, N1: float, N2: float, g: float) -> tuple[float, float]:
    """(L_f^2 h)_e = W2^T theta_hat + g (docs/manual/model.md, claim c)."""
    q1 = ab[4]
    q2 = ab[5]
    y1 = theta[1] * q1 + theta[3] * q2 + theta[6] * N1 + theta[7] * N2 + g
    y2 = theta[3] * q1 + theta[1] * q2 + theta[7] * N1 + theta[6] * N2 + g
    return y1, y2


@njit(cache=True)
def _ce_law(theta: np.ndarray, ab: np.ndarray, ve1: float, ve2: float, u: np.ndarray) -> None:
    """u = M_hat^{-1} (v_e - (L_f^3 h)_e) (Eq. 22 corrected); NaN when M_hat is singular."""
    a1, a2, b1, b2 = ab[0], ab[1], ab[2], ab[3]
    L3_1 = 2 * (theta[0] + theta[8]) * a1 + 2 * (theta[2] - theta[9]) * a2
    L3_2 = 2 * (theta[2] + theta[9]) * a1 + 2 * (theta[0] - theta[8]) * a2
    m00 = 2 * theta[4] * b1
    m01 = 2 * theta[5] * b2
    m10 = 2 * theta[5] * b1
    m11 = 2 * theta[4] * b2
    det = m00 * m11 - m01 * m10
    r1 = ve1 - L3_1
    r2 = ve2 - L3_2
    if det != 0.0 and np.isfinite(det):
        u[0] = (m11 * r1 - m01 * r2) / det
        u[1] = (-m10 * r1 + m00 * r2) / det
    else:
        u[0] = np.nan
        u[1] = np.nan


@njit(cache=True)
def _predict(mode: int, cp: np.ndarray, theta: np.ndarray, v: np.ndarray, scale: np.ndarray, uh: np.ndarray, delay: int,
             x: np.ndarray) -> bool:
    """Advance ``x`` by ``delay`` samples under uh[delay-1], ..., uh[0] with the estimated model."""
    if mode == MODE_PAPER or mode == MODE_PAPER_FIX:  # noqa: SIM109 (numba)

        # eight free thetas need not describe any physical (m, R, K): no model to predict with
        return False
    if mode == MODE_ADAPTIVE or mode == MODE_ENHANCED:  # noqa: SIM109 (numba)
        mu = scale[0] * v[0]
        R = scale[1] * v[1]
        Kc = scale[2] * v[2]
        rho = scale[3] * v[3]
    else:
        est = np.empty(3)
        physical_estimates(theta, est)
        if not (est[0] > 0.0 and est[1] > 0.0 and est[2] > 0.0):
            return False
        mu = 1.0 / est[0]
        R = est[1]
        Kc = est[2]
        rho = 0.0
    p = np.empty(NPP)
    p[IP] = cp[CP_P]
    p[IQ] = cp[CP_Q]
    p[IA] = mu + cp[CP_CA]
    p[IB] = mu - cp[CP_CA]
    p[IC] = mu + cp[CP_CC]
    p[ID] = mu - cp[CP_CC]
    p[IK] = Kc
    p[IK2] = Kc
    p[IR1] = R + rho
    p[IR2] = R - rho
    p[IN1] = cp[CP_N1]
    p[IN2] = cp[CP_N2]
    p[IG] = cp[CP_G]
    for j in range(delay - 1, -1, -1):
        rk4(x, uh[j], p, cp[CP_TS], 2)
    return bool(np.all(np.isfinite(x)))


@njit(cache=True)
def _integral_term(cp: np.ndarray, ydd1: float, ydd2: float, rd: np.ndarray, xd: np.ndarray, E1: float,
                   E2: float) -> tuple[float, float]:
    """(sigma_hat_1, sigma_hat_2): sigma_hat_j = (y_j''_e - y_dj'') + k1 e_j' + k2 e_j + k3 E_j, E_j = int e_j dt
    (module docstring).

    ``rd`` (8,): reference per magnet (y, y', y'', y'''), ``xd`` (6,): the state the law acts on.
    """
    k1 = cp[CP_K1]
    k2 = cp[CP_K2]
    k3 = cp[CP_K3]
    return ((ydd1 - rd[4]) + k1 * (xd[1] - rd[2]) + k2 * (xd[0] - rd[0]) + k3 * E1,
            (ydd2 - rd[5]) + k1 * (xd[3] - rd[3]) + k2 * (xd[2] - rd[1]) + k3 * E2)


@njit(cache=True)
def _advance_error_filters(Z: np.ndarray, Ad: np.ndarray, Bd: np.ndarray, W3: np.ndarray, W2: np.ndarray,
                           theta: np.ndarray, k1: float, ve1: float, ve2: float) -> None:
    """F(s) bank <- advance with W_p = W3 + k1 W2 (2 NTH channels) and v_e + k1 W2^T theta_hat (2 channels).

    :func:`dem_ros.core.lti.filter_step` on those NZ inputs, the same operations in the same order, without
    the input vector and the filter's scratch array (two allocations per sample).
    """
    for c in range(NZ):
        if c < 2 * NTH:
            r = c // 2
            j = c - 2 * r
            wc = W3[r, j] + k1 * W2[r, j]
        else:
            j = c - 2 * NTH
            s = 0.0
            for r in range(NTH):
                s += k1 * W2[r, j] * theta[r]
            wc = (ve1 if j == 0 else ve2) + s
        t0 = Bd[0] * wc
        for i in range(3):
            t0 += Ad[0, i] * Z[i, c]
        t1 = Bd[1] * wc
        for i in range(3):
            t1 += Ad[1, i] * Z[i, c]
        t2 = Bd[2] * wc
        for i in range(3):
            t2 += Ad[2, i] * Z[i, c]
        Z[0, c] = t0
        Z[1, c] = t1
        Z[2, c] = t2


@njit(cache=True)
def ce_step(law: CELaw, st: CEState, meas: np.ndarray, ref: np.ndarray, u: np.ndarray, diag: np.ndarray) -> None:
    """One sample of the CE family: ``law`` a :class:`CELaw`, ``st`` a :class:`CEState` (updated in place).

    ``meas`` = [d1, d1', d2, d2', i1, i2], ``ref`` = reference (8,), ``u`` (2,) out: the command (V).
    A non-finite measurement or reference leaves every state untouched: ``u`` keeps the
    previous command and the fault flag is set (the caller decides whether to send it).
    """
    if not (np.all(np.isfinite(meas)) and np.all(np.isfinite(ref))):
        diag[D_FAULT] = 1.0
        diag[D_ADAPT] = 0.0
        return
    mode = law.mode
    cp = law.cp
    theta = st.theta
    v = st.v
    scale = st.scale
    uh = st.uh
    Z = st.Z
    k1 = cp[CP_K1]
    k2 = cp[CP_K2]
    k3 = cp[CP_K3]
    N1 = cp[CP_N1]
    N2 = cp[CP_N2]
    g = cp[CP_G]
    ki = cp[CP_KI] if (mode == MODE_ADAPTIVE or mode == MODE_ENHANCED) else 0.0  # noqa: SIM109 (numba)
    d1 = max(meas[0], cp[CP_FLOOR])
    d2 = max(meas[2], cp[CP_FLOOR])
    i1 = meas[4]
    i2 = meas[5]
    ab = np.empty(6)
    lie_terms(d1, d2, i1, i2, cp[CP_P], cp[CP_Q], ab)
    xi = np.empty((NTH, 2))
    for r in range(NTH):
        xi[r, 0] = Z[0, 2 * r]
        xi[r, 1] = Z[0, 2 * r + 1]
    e1 = meas[0] - ref[0]
    e2 = meas[2] - ref[1]
    ec = np.zeros(2)
    adapting = 0.0
    if mode != MODE_FIXED:
        for j in range(2):
            s = -Z[0, 2 * NTH + j] - (e1 if j == 0 else e2)
            for r in range(NTH):
                s += xi[r, j] * theta[r]
            ec[j] = s
        if mode == MODE_PAPER:
            _update_paper(cp, theta, v, st.P, xi, ec)
            adapting = 1.0
        elif mode == MODE_PAPER_FIX:
            _update_paper_fixed(cp, theta, v, scale, st.P, xi, ec)
            adapting = 1.0
        else:
            rows = NO_COIL_ROWS
            if cp[CP_COIL_W] > 0.0:
                rows = _coil_rows(cp, scale, v, st.coil, uh[int(cp[CP_DELAY])], i1, i2, ab[2], ab[3])
            else:  # off: no filter work; the filters start afresh when switched on
                st.coil[3, 0] = np.nan
            adapting = _update_adaptive(cp, theta, v, scale, st.v0, st.P, xi, ec, mode == MODE_ENHANCED, int(cp[CP_DZ]),
                                        rows)
    # v_e at the measured state: enters the error filter whatever the law does
    ydd1, ydd2 = _ydd_hat(theta, ab, N1, N2, g)
    ve1 = ref[6] - k1 * (ydd1 - ref[4]) - k2 * (meas[1] - ref[2]) - k3 * e1
    ve2 = ref[7] - k1 * (ydd2 - ref[5]) - k2 * (meas[3] - ref[3]) - k3 * e2
    delay = int(cp[CP_DELAY])
    fault = 0.0
    sig1 = 0.0
    sig2 = 0.0
    if delay == 0:
        if ki > 0.0:
            sig1, sig2 = _integral_term(cp, ydd1, ydd2, ref, meas, st.ie[0], st.ie[1])
        _ce_law(theta, ab, ve1 - ki * sig1, ve2 - ki * sig2, u)
    else:
        # delay compensation: our command acts d samples from now, so compute it for the
        # state predicted there (estimated model, commands already in the pipe) and the
        # reference extrapolated there (it is smooth: Taylor to third order)
        xp = np.empty(6)
        for i in range(6):
            xp[i] = meas[i]
        xp[0] = d1
        xp[2] = d2
        if not _predict(mode, cp, theta, v, scale, uh, delay, xp):
            for i in range(6):  # no usable model: act on the measured state
                xp[i] = meas[i]
            xp[0] = d1
            xp[2] = d2
        rp = np.empty(8)
        tau = delay * cp[CP_TS]
        for j in range(2):
            rp[j] = ref[j] + ref[2 + j] * tau + ref[4 + j] * tau * tau / 2 + ref[6 + j] * tau ** 3 / 6
            rp[2 + j] = ref[2 + j] + ref[4 + j] * tau + ref[6 + j] * tau * tau / 2
            rp[4 + j] = ref[4 + j] + ref[6 + j] * tau
            rp[6 + j] = ref[6 + j]
        abp = np.empty(6)
        lie_terms(max(xp[0], cp[CP_FLOOR]), max(xp[2], cp[CP_FLOOR]), xp[4], xp[5], cp[CP_P], cp[CP_Q], abp)
        y1, y2 = _ydd_hat(theta, abp, N1, N2, g)
        vp1 = rp[6] - k1 * (y1 - rp[4]) - k2 * (xp[1] - rp[2]) - k3 * (xp[0] - rp[0])
        vp2 = rp[7] - k1 * (y2 - rp[5]) - k2 * (xp[3] - rp[3]) - k3 * (xp[2] - rp[1])
        if ki > 0.0:  # E predicted over the delay with the error of now
            sig1, sig2 = _integral_term(cp, y1, y2, rp, xp, st.ie[0] + tau * e1, st.ie[1] + tau * e2)
        _ce_law(theta, abp, vp1 - ki * sig1, vp2 - ki * sig2, u)
    lim = cp[CP_ULIM]
    clipped = False
    for j in range(2):
        if not np.isfinite(u[j]):
            u[j] = 0.0
            fault = 1.0
        elif u[j] > lim:
            u[j] = lim
            clipped = True
        elif u[j] < -lim:
            u[j] = -lim
            clipped = True
    if ki > 0.0 and fault == 0.0 and not clipped:  # anti-windup: no integration while the command is clipped
        st.ie[0] += cp[CP_TS] * e1
        st.ie[1] += cp[CP_TS] * e2
    # the voltage applied over this sample: our command of `delay` samples ago, uh[delay] once shifted
    for i in range(uh.shape[0] - 1, 0, -1):
        uh[i, 0] = uh[i - 1, 0]
        uh[i, 1] = uh[i - 1, 1]
    uh[0, 0] = u[0]
    uh[0, 1] = u[1]
    # regressor with the applied u, then advance F(s) on W_p and v_e + k1 W2^T theta_hat
    # (v_e without the integral term: the e_c identity holds whatever the command was)
    W3 = np.empty((NTH, 2))
    W2 = np.empty((NTH, 2))
    regressors(ab, uh[delay], N1, N2, W3, W2)
    _advance_error_filters(Z, law.Ad, law.Bd, W3, W2, theta, k1, ve1, ve2)
    # diagnostics
    if mode == MODE_ADAPTIVE or mode == MODE_ENHANCED:  # noqa: SIM109 (numba)
        diag[D_M] = 1.0 / (scale[0] * v[0])
        diag[D_R] = scale[1] * v[1]
        diag[D_K] = scale[2] * v[2]
    else:
        physical_estimates(theta, diag)  # diag[D_M], diag[D_R], diag[D_K]
    diag[D_EC1] = ec[0]
    diag[D_EC2] = ec[1]
    diag[D_E1] = e1
    diag[D_E2] = e2
    diag[D_ADAPT] = adapting
    diag[D_FAULT] = fault


@njit(cache=True)
def ce_step_arrays(mode: int, cp: np.ndarray, Ad: np.ndarray, Bd: np.ndarray, theta: np.ndarray, v: np.ndarray,
                   scale: np.ndarray, v0: np.ndarray, P: np.ndarray, Z: np.ndarray, uh: np.ndarray, ie: np.ndarray,
                   coil: np.ndarray, meas: np.ndarray, ref: np.ndarray, u: np.ndarray, diag: np.ndarray) -> None:
    """:func:`ce_step` for callers in Python: the fields of a :class:`CELaw` and a :class:`CEState`, in order.

    numba's dispatcher types array arguments in C but a NamedTuple in Python: a call with the
    records costs ~1.4 us more per 1 kHz step (p50 5.2 vs 3.8 us, #9 item 5). Compiled callers
    pass the records; :class:`~dem_ros.core.controllers.CEController` calls :func:`ce_step_buffers`
    (two arrays instead of sixteen).
    """
    ce_step(CELaw(mode, cp, Ad, Bd), CEState(theta, v, scale, v0, P, Z, uh, ie, coil), meas, ref, u, diag)


def law_views(lb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cp, Ad, Bd): the views of a law buffer (NLB,) (layout LB_*)."""
    return lb[LB_CP:LB_AD], lb[LB_AD:LB_BD].reshape((3, 3)), lb[LB_BD:NLB]


def state_views(sb: np.ndarray) -> tuple[CEState, np.ndarray, np.ndarray]:
    """(CEState, u, diag): the views of a state buffer (NSB,) (layout SB_*)."""
    st = CEState(sb[SB_THETA:SB_V], sb[SB_V:SB_SCALE], sb[SB_SCALE:SB_V0], sb[SB_V0:SB_P],
                 sb[SB_P:SB_Z].reshape((NTH, NTH)), sb[SB_Z:SB_UH].reshape((3, NZ)), sb[SB_UH:SB_IE].reshape((NUH, 2)),
                 sb[SB_IE:SB_COIL], sb[SB_COIL:SB_U].reshape((5, 2)))
    return st, sb[SB_U:SB_DIAG], sb[SB_DIAG:NSB]


@njit(cache=True)
def ce_step_buffers(mode: int, lb: np.ndarray, sb: np.ndarray, meas: np.ndarray, ref: np.ndarray) -> None:
    """:func:`ce_step` on a law buffer ``lb`` (NLB,) and a state buffer ``sb`` (NSB,) (layouts LB_*, SB_*):
    the command goes to sb[SB_U:SB_DIAG], the diagnostics to sb[SB_DIAG:].

    The step called from Python (nodes, ``bench sim``): numba's dispatcher types and unboxes every array
    argument of a call (~0.1 us each), so four arrays cost less than the sixteen of :func:`ce_step_arrays`;
    the views are taken here, in compiled code.
    """
    law = CELaw(mode, lb[LB_CP:LB_AD], lb[LB_AD:LB_BD].reshape((3, 3)), lb[LB_BD:NLB])
    st = CEState(sb[SB_THETA:SB_V], sb[SB_V:SB_SCALE], sb[SB_SCALE:SB_V0], sb[SB_V0:SB_P],
                 sb[SB_P:SB_Z].reshape((NTH, NTH)), sb[SB_Z:SB_UH].reshape((3, NZ)), sb[SB_UH:SB_IE].reshape((NUH, 2)),
                 sb[SB_IE:SB_COIL], sb[SB_COIL:SB_U].reshape((5, 2)))
    ce_step(law, st, meas, ref, sb[SB_U:SB_DIAG], sb[SB_DIAG:NSB])


# --------------------------------------------------------------------------
# Decentralised cascade PID (docs/manual/controllers.md): one loop per magnet, coupling ignored.
# --------------------------------------------------------------------------
(PID_KP, PID_KD, PID_KI, PID_KC, PID_R, PID_FF, PID_TS, PID_ULIM) = range(8)
NPID = 8


@njit(cache=True)
def pid_step(cp: np.ndarray, integ: np.ndarray, meas: np.ndarray, ref: np.ndarray, u: np.ndarray,
             diag: np.ndarray) -> None:
    """i_ref = y_m sqrt(F0/K) + kp e + kd (d' - y_m') + ki int e;  u = R i_ref + kc (i_ref - i).

    A non-finite measurement or reference leaves the integrators untouched and sets the fault flag.
    """
    if not (np.all(np.isfinite(meas)) and np.all(np.isfinite(ref))):
        diag[D_FAULT] = 1.0
        return
    fault = 0.0
    for j in range(2):
        e = meas[2 * j] - ref[j]
        i_ref = (ref[j] * cp[PID_FF] + cp[PID_KP] * e + cp[PID_KD] * (meas[2 * j + 1] - ref[2 + j])
                 + cp[PID_KI] * integ[j])
        uj = cp[PID_R] * i_ref + cp[PID_KC] * (i_ref - meas[4 + j])
        if not np.isfinite(uj):
            uj = 0.0
            fault = 1.0
        lim = cp[PID_ULIM]
        if uj > lim:
            uj = lim
        elif uj < -lim:
            uj = -lim
        u[j] = uj
        integ[j] += e * cp[PID_TS]
        diag[D_E1 + j] = e
    diag[D_M] = np.nan
    diag[D_R] = np.nan
    diag[D_K] = np.nan
    diag[D_EC1] = 0.0
    diag[D_EC2] = 0.0
    diag[D_ADAPT] = 0.0
    diag[D_FAULT] = fault
