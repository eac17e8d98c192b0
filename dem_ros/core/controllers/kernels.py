r"""Compiled control laws (numba). One step = one sample of the 1 kHz loop.

Certainty-equivalence (CE) family, paper Eqs. 17-36 corrected (docs/manual/controllers.md).
Every member shares the control law and the augmented error; they differ in
how theta_hat is adapted (``mode``):

    MODE_FIXED     nonlinear decoupling with fixed theta (De-Sheng et al. 2006)
    MODE_PAPER     "A0": Eq. 36 as printed (continuous normalised LS, +P')
    MODE_PAPER_FIX "A1": 8 free theta, per-sample RLS, scaled, cone projection
    MODE_ADAPTIVE  "A2": phi = (1/m, R, K), Gauss-Newton RLS, random walk on 1/m, bounds
    MODE_ENHANCED  "A2e": A2 + corrected leakage and dead zone of Eq. 48

Per sample k (docs/manual/controllers.md, "common loop")::

    xi, zeta  <- outputs of F(s) from the previous updates
    e         = y - y_d
    e_c       = xi^T theta_hat - zeta - e            (= xi^T (theta_hat - theta))
    theta_hat <- update(e_c)
    v_e       = y_d''' - k1((L_f^2 h)_e - y_d'') - k2(y' - y_d') - k3 e     (Eq. 21, erratum 7)
    u         = M_hat^{-1} (v_e - (L_f^3 h)_e)                                (Eq. 22)
    u_a       = the voltage applied over this sample: u_{k-delay} (and clipped)
    W_p       = W3(x, u_a) + k1 W2(x)
    F(s) bank <- advance with W_p (2 NTH channels) and v_e + k1 W2^T theta_hat (2 channels)

The last input equals W_p^T theta_hat when u_a is the law's own unclipped output
(W3(u)^T theta_hat = v_e). In general the error equation is

    e^(3) + k1 e^(2) + k2 e^(1) + k3 e = W_p(u_a)^T (theta - theta_hat) + [W3(u_a)^T theta_hat - v_e]

and the bracket is known, so filtering v_e + k1 W2^T theta_hat keeps
e_c = xi^T (theta_hat - theta) exact under a command delay and under clipping.

State arrays (all float64, owned by the caller):
    theta (NTH,)  theta_hat used by the law (unscaled, Eq. 44 order, then A rho/2, B rho/2:
                  per-coil resistance R1,2 = R +- rho, see :mod:`dem_ros.core.model`)
    v (NTH,)      estimate in estimation coordinates (A0: theta; A1: theta/scale;
                  A2: phi/phi0 in the first 4 entries, phi = (1/m, R, K, rho), rho scaled by R0)
    scale (NTH,)  the scaling (A0: ones; A1: theta magnitudes; A2: phi0)
    v0 (NTH,)     leakage target (A2e)
    P (NTH, NTH)  covariance (A0, A1 use the leading 8x8 and keep rho = 0; A2 the leading 4x4)
    Z (3, NZ)     F(s) filter bank: 2 NTH channels of W_p, 2 of v_e + k1 W2^T theta_hat
    uh (NUH, 2)   last commands, newest first: the voltage applied now is uh[delay]
    cp (NCP,)     configuration vector, layout CP_* below
    diag (NDIAG,) out: m_hat, R_hat, K_hat, ec1, ec2, e1, e2, adapting, fault
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..lti import filter_step
from ..model import (
    IA,
    IB,
    IC,
    ID,
    IG,
    IK,
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
CP_QRHO, CP_RHO_MAX = 27, 28
NCP = 29
NUH = 9  # longest command delay (samples) + 1
NTH = 10  # theta entries (8 of Eq. 44 + 2 for the coil-resistance difference)
NZ = 2 * NTH + 2  # F(s) channels
NPHI = 4  # A2: phi = (1/m, R, K, rho)
DZ_PDOT, DZ_ERROR, DZ_OFF = 0, 1, 2

(D_M, D_R, D_K, D_EC1, D_EC2, D_E1, D_E2, D_ADAPT, D_FAULT) = range(9)
NDIAG = 9


@njit(cache=True)
def _sym2_norm(a: float, b: float, d: float) -> float:
    """2-norm of the symmetric 2x2 [[a, b], [b, d]]."""
    h = 0.5 * (a + d)
    r = np.sqrt(0.25 * (a - d) ** 2 + b * b)
    return max(abs(h + r), abs(h - r))


@njit(cache=True)
def physical_estimates(theta: np.ndarray, out: np.ndarray) -> None:
    """(m_hat, R_hat, K_hat) implied by theta: C + D = 2/m, theta1/theta5 = -R, theta2/theta5 = 2K."""
    s = theta[6] + theta[7]
    out[0] = 2.0 / s if s != 0.0 else np.nan
    out[1] = -theta[0] / theta[4] if theta[4] != 0.0 else np.nan
    out[2] = theta[1] / (2.0 * theta[4]) if theta[4] != 0.0 else np.nan


@njit(cache=True)
def _rls_gain(P: np.ndarray, X: np.ndarray, n: int, G: np.ndarray) -> None:
    """G = P X (I2 + X^T P X)^{-1}; X: (n, 2), G: (n, 2)."""
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
def _rls_cov_step(P: np.ndarray, G: np.ndarray, X: np.ndarray, n: int, dP: np.ndarray) -> None:
    """dP = G X^T P (the LS decrease); P is not modified."""
    for i in range(n):
        for j in range(n):
            s = 0.0
            for c in range(2):
                t = 0.0
                for k in range(n):
                    t += X[k, c] * P[k, j]
                s += G[i, c] * t
            dP[i, j] = s


@njit(cache=True)
def _update_paper(cp, theta, v, P, xi, ec) -> None:
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
def _update_paper_fixed(cp, theta, v, scale, P, xi, ec) -> None:
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
def _update_adaptive(cp, theta, v, scale, v0, P, xi, ec, enhanced, dz_mode) -> float:
    """A2 / A2e: Gauss-Newton RLS on scaled phi = (1/m, R, K, rho); returns 1.0 if adapting.

    A2e's dead zone gates the whole least-squares step (estimate and covariance decrease):
    outside adaptation P only grows by the random walk, so adaptation can resume.
    """
    Ts = cp[CP_TS]
    phi = np.empty(NPHI)
    for i in range(NPHI):
        phi[i] = scale[i] * v[i]
    J = np.empty((NTH, NPHI))
    theta_jacobian(phi, cp[CP_CA], J)
    X = np.zeros((NPHI, 2))  # X = diag(phi0) J^T xi
    for i in range(NPHI):
        for c in range(2):
            s = 0.0
            for r in range(NTH):
                s += J[r, i] * xi[r, c]
            X[i, c] = scale[i] * s
    G = np.empty((NPHI, 2))
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
        for i in range(NPHI):
            v[i] -= G[i, 0] * ec[0] + G[i, 1] * ec[1]
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
def _ydd_hat(theta, ab, N1, N2, g):
    """(L_f^2 h)_e = W2^T theta_hat + g (docs/manual/model.md, claim c)."""
    q1 = ab[4]
    q2 = ab[5]
    y1 = theta[1] * q1 + theta[3] * q2 + theta[6] * N1 + theta[7] * N2 + g
    y2 = theta[3] * q1 + theta[1] * q2 + theta[7] * N1 + theta[6] * N2 + g
    return y1, y2


@njit(cache=True)
def _ce_law(theta, ab, ve1, ve2, u) -> None:
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
def _predict(mode, cp, theta, v, scale, uh, delay, x) -> bool:
    """Advance ``x`` by ``delay`` samples under uh[delay-1], ..., uh[0] with the estimated model."""
    est = np.empty(3)
    if mode == MODE_PAPER or mode == MODE_PAPER_FIX:  # noqa: SIM109 (numba)

        # eight free thetas need not describe any physical (m, R, K): no model to predict with
        return False
    if mode == MODE_ADAPTIVE or mode == MODE_ENHANCED:  # noqa: SIM109 (numba)
        mu = scale[0] * v[0]
        R = scale[1] * v[1]
        Kc = scale[2] * v[2]
        rho = scale[3] * v[3]
    else:
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
    p[IR1] = R + rho
    p[IR2] = R - rho
    p[IN1] = cp[CP_N1]
    p[IN2] = cp[CP_N2]
    p[IG] = cp[CP_G]
    ua = np.empty(2)
    for j in range(delay - 1, -1, -1):
        ua[0] = uh[j, 0]
        ua[1] = uh[j, 1]
        rk4(x, ua, p, cp[CP_TS], 2)
    return np.all(np.isfinite(x))


@njit(cache=True)
def ce_step(mode, cp, theta, v, scale, v0, P, Z, uh, Ad, Bd, meas, ref, u, diag) -> None:
    """One sample of the CE family. ``meas`` = [d1, d1', d2, d2', i1, i2], ``ref`` = reference (8,).

    A non-finite measurement or reference leaves every state untouched: ``u`` keeps the
    previous command and the fault flag is set (the caller decides whether to send it).
    """
    if not (np.all(np.isfinite(meas)) and np.all(np.isfinite(ref))):
        diag[D_FAULT] = 1.0
        diag[D_ADAPT] = 0.0
        return
    k1 = cp[CP_K1]
    k2 = cp[CP_K2]
    k3 = cp[CP_K3]
    N1 = cp[CP_N1]
    N2 = cp[CP_N2]
    g = cp[CP_G]
    d1 = max(meas[0], cp[CP_FLOOR])
    d2 = max(meas[2], cp[CP_FLOOR])
    i1 = meas[4]
    i2 = meas[5]
    xi = np.empty((NTH, 2))
    for r in range(NTH):
        xi[r, 0] = Z[0, 2 * r]
        xi[r, 1] = Z[0, 2 * r + 1]
    e = np.empty(2)
    e[0] = meas[0] - ref[0]
    e[1] = meas[2] - ref[1]
    ec = np.zeros(2)
    adapting = 0.0
    if mode != MODE_FIXED:
        for j in range(2):
            s = -Z[0, 2 * NTH + j] - e[j]
            for r in range(NTH):
                s += xi[r, j] * theta[r]
            ec[j] = s
        if mode == MODE_PAPER:
            _update_paper(cp, theta, v, P, xi, ec)
            adapting = 1.0
        elif mode == MODE_PAPER_FIX:
            _update_paper_fixed(cp, theta, v, scale, P, xi, ec)
            adapting = 1.0
        else:
            adapting = _update_adaptive(cp, theta, v, scale, v0, P, xi, ec, mode == MODE_ENHANCED, int(cp[CP_DZ]))
    ab = np.empty(6)
    lie_terms(d1, d2, i1, i2, cp[CP_P], cp[CP_Q], ab)
    # v_e at the measured state: enters the error filter whatever the law does
    ydd1, ydd2 = _ydd_hat(theta, ab, N1, N2, g)
    ve1 = ref[6] - k1 * (ydd1 - ref[4]) - k2 * (meas[1] - ref[2]) - k3 * e[0]
    ve2 = ref[7] - k1 * (ydd2 - ref[5]) - k2 * (meas[3] - ref[3]) - k3 * e[1]
    delay = int(cp[CP_DELAY])
    fault = 0.0
    if delay == 0:
        _ce_law(theta, ab, ve1, ve2, u)
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
        _ce_law(theta, abp, vp1, vp2, u)
    lim = cp[CP_ULIM]
    for j in range(2):
        if not np.isfinite(u[j]):
            u[j] = 0.0
            fault = 1.0
        elif u[j] > lim:
            u[j] = lim
        elif u[j] < -lim:
            u[j] = -lim
    # the voltage applied over this sample: our command of `delay` samples ago
    ua = np.empty(2)
    if delay == 0:
        ua[0] = u[0]
        ua[1] = u[1]
    else:
        ua[0] = uh[delay - 1, 0]
        ua[1] = uh[delay - 1, 1]
    for i in range(uh.shape[0] - 1, 0, -1):
        uh[i, 0] = uh[i - 1, 0]
        uh[i, 1] = uh[i - 1, 1]
    uh[0, 0] = u[0]
    uh[0, 1] = u[1]
    # regressor with the applied u, then advance F(s) on W_p and v_e + k1 W2^T theta_hat
    W3 = np.empty((NTH, 2))
    W2 = np.empty((NTH, 2))
    regressors(ab, ua, N1, N2, W3, W2)
    w = np.empty(NZ)
    for r in range(NTH):
        w[2 * r] = W3[r, 0] + k1 * W2[r, 0]
        w[2 * r + 1] = W3[r, 1] + k1 * W2[r, 1]
    w[2 * NTH] = ve1
    w[2 * NTH + 1] = ve2
    for j in range(2):
        s = 0.0
        for r in range(NTH):
            s += k1 * W2[r, j] * theta[r]
        w[2 * NTH + j] += s
    filter_step(Z, Ad, Bd, w)
    # diagnostics
    est = np.empty(3)
    if mode == MODE_ADAPTIVE or mode == MODE_ENHANCED:  # noqa: SIM109 (numba)
        est[0] = 1.0 / (scale[0] * v[0])
        est[1] = scale[1] * v[1]
        est[2] = scale[2] * v[2]
    else:
        physical_estimates(theta, est)
    diag[D_M] = est[0]
    diag[D_R] = est[1]
    diag[D_K] = est[2]
    diag[D_EC1] = ec[0]
    diag[D_EC2] = ec[1]
    diag[D_E1] = e[0]
    diag[D_E2] = e[1]
    diag[D_ADAPT] = adapting
    diag[D_FAULT] = fault


# --------------------------------------------------------------------------
# Decentralised cascade PID (docs/manual/controllers.md): one loop per magnet, coupling ignored.
# --------------------------------------------------------------------------
(PID_KP, PID_KD, PID_KI, PID_KC, PID_R, PID_FF, PID_TS, PID_ULIM) = range(8)
NPID = 8


@njit(cache=True)
def pid_step(cp, integ, meas, ref, u, diag) -> None:
    """i_ref = y_m sqrt(F0/K) + kp e + kd (d' - y_m') + ki int e;  u = R i_ref + kc (i_ref - i).

    A non-finite measurement or reference leaves the integrators untouched and sets the fault flag.
    """
    if not (np.all(np.isfinite(meas)) and np.all(np.isfinite(ref))):
        diag[D_FAULT] = 1.0
        return
    fault = 0.0
    for j in range(2):
        e = meas[2 * j] - ref[j]
        i_ref = ref[j] * cp[PID_FF] + cp[PID_KP] * e + cp[PID_KD] * (meas[2 * j + 1] - ref[2 + j]) + cp[PID_KI] * integ[j]
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
