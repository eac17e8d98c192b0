r"""DEM plant model: dynamics, Lie derivatives and the linear parameterisation.

State ``x = [d1, d1', d2, d2', i1, i2]`` (m, m/s, m, m/s, A, A), input
``u = [u1, u2]`` (V), output ``y = [d1, d2]`` (m). Positive down. With

    P = (L+l)/(2L),  Q = (L-l)/(2L)                              (Eq. 7)
    delta1 = P d1 + Q d2,  delta2 = Q d1 + P d2                    (Eq. 6)
    A = 1/m + Ll/I, B = 1/m - Ll/I, C = 1/m + L^2/I, D = 1/m - L^2/I (Eq. 4)
    F_j = K i_j^2 / delta_j^2                                      (Eq. 5, 8)

the corrected dynamics are (docs/manual/model.md; errata 1-3)::

    d1'' = -A F1 - B F2 + C N1 + D N2 + g                           (Eq. 3a)
    d2'' = -B F1 - A F2 + D N1 + C N2 + g                           (Eq. 3b)
    i_j' = (delta_j / 2K)(u_j - R_j i_j) + i_j delta_j' / delta_j    (from u = R_j i + d(2K i/delta)/dt)

(each coil has its own resistance R_j, and each magnet its own force coefficient K_j in F_j and in its coil
equation: K1 = K2 = K unless set; the control laws assume R1 = R2 = R and K1 = K2 = K).

With a_j = i_j^2/delta_j, b_j = i_j/delta_j, q_j = b_j^2 the output has
relative degree (3, 3) and (docs/manual/model.md a-b)::

    y'   = [d1', d2']
    y''  = L_f^2 h = W2^T theta + g
    y''' = L_f^3 h + L_g L_f^2 h u = W3^T theta

with theta = [AR/2, -AK, BR/2, -BK, -A/2, -B/2, C, D] (Eq. 44) when both
coils have the resistance R. Coils that differ, R1 = R + rho, R2 = R - rho,
add y1''' += rho (A a1 - B a2), y2''' += rho (B a1 - A a2): two more entries
theta_8 = A rho/2, theta_9 = B rho/2 with W3 rows [2 a1, -2 a2] and
[-2 a2, 2 a1] (the 10-entry form; the 8-entry arrays of the paper's laws
are accepted everywhere and mean rho = 0). The paper's
tracking-error regressor (Eq. 45, corrected) is ``W_p = W3 + k1 W2`` so that
``e''' + k1 e'' + k2 e' + k3 e = W_p^T (theta - theta_hat)``.

All functions here are pure and compiled with numba (``cache=True``); they are
called from the simulators and from the controller classes alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "apply_schedule",
    "derived",
    "dynamics",
    "equilibrium",
    "force_coefficients",
    "gap_weights",
    "hover_current",
    "hover_forces",
    "hover_state",
    "initial_state",
    "lie_terms",
    "plant_vector",
    "regressors",
    "rk4",
    "theta_jacobian",
    "theta_of",
]

# Layout of the plant parameter vector ``p`` used by the kernels (R1, R2: per coil; IK: K1 of magnet 1, IK2: K2).
IP, IQ, IA, IB, IC, ID, IK, IR1, IN1, IN2, IG, IR2, IK2 = range(13)
NPP = 13

# Layout of a row of the plant schedule (time-varying truth, one row per sample):
# mass m (kg), pitch inertia I (kg m^2), loads N1, N2 (N), resistances R1, R2 (ohm).
SM, SI, SN1, SN2, SR1, SR2 = range(6)
NSCHED = 6


def gap_weights(L: float, l: float) -> tuple[float, float]:
    """(P, Q) of Eq. 4: the magnet gaps from the load-point gaps, delta_1 = P d1 + Q d2, delta_2 = Q d1 + P d2
    (L: centre to load points, l: centre to magnets [m]); the one place they are computed."""
    return (L + l) / (2 * L), (L - l) / (2 * L)


def derived(L: float, l: float, m: float, I: float) -> tuple[float, float, float, float, float, float]:
    """(P, Q, A, B, C, D) of Eqs. 4 and 7."""
    return (
        *gap_weights(L, l),
        1 / m + L * l / I,
        1 / m - L * l / I,
        1 / m + L * L / I,
        1 / m - L * L / I,
    )


def coil_resistances(cfg: Mapping[str, Any]) -> tuple[float, float]:
    """(R1, R2) at t = 0 (ohm): ``R1``/``R2`` when set (non-zero), else ``R`` for both."""
    R = cfg["R"]
    return (cfg.get("R1") or R, cfg.get("R2") or R)


def force_coefficients(cfg: Mapping[str, Any]) -> tuple[float, float]:
    """(K1, K2) (N m^2/A^2): ``K1``/``K2`` when set (non-zero), else ``K`` for both magnets."""
    K = cfg["K"]
    return (cfg.get("K1") or K, cfg.get("K2") or K)


def plant_vector(cfg: Mapping[str, Any], m: float | None = None) -> np.ndarray:
    """Kernel parameter vector from a ``plant_sim``-like dict (L, l, I, m, K [, K1, K2], R [, R1, R2], N1, N2, g)."""
    mass = cfg["m"] if m is None else m
    P, Q, A, B, C, D = derived(cfg["L"], cfg["l"], mass, cfg["I"])
    R1, R2 = coil_resistances(cfg)
    K1, K2 = force_coefficients(cfg)
    return np.array([P, Q, A, B, C, D, K1, R1, cfg["N1"], cfg["N2"], cfg["g"], R2, K2])


@njit(cache=True)
def set_mass(p: np.ndarray, m: float, L: float, l: float, I: float) -> None:
    """Update A, B, C, D of ``p`` in place for mass ``m`` (added mass at O)."""
    p[IA] = 1.0 / m + L * l / I
    p[IB] = 1.0 / m - L * l / I
    p[IC] = 1.0 / m + L * L / I
    p[ID] = 1.0 / m - L * L / I


@njit(cache=True)
def apply_schedule(p: np.ndarray, row: np.ndarray, L: float, l: float) -> None:
    """Set the time-varying truth of ``p`` from a schedule row (layout S*: m, I, N1, N2, R1, R2)."""
    set_mass(p, row[SM], L, l, row[SI])
    p[IN1] = row[SN1]
    p[IN2] = row[SN2]
    p[IR1] = row[SR1]
    p[IR2] = row[SR2]


@njit(cache=True)
def dynamics(x: np.ndarray, u: np.ndarray, p: np.ndarray, dx: np.ndarray) -> None:
    """dx = f(x) + G(x) u, written into ``dx`` (shape (6,))."""
    P, Q, A, B, C, D, K, K2 = p[IP], p[IQ], p[IA], p[IB], p[IC], p[ID], p[IK], p[IK2]
    d1 = P * x[0] + Q * x[2]
    d2 = Q * x[0] + P * x[2]
    dd1 = P * x[1] + Q * x[3]
    dd2 = Q * x[1] + P * x[3]
    F1 = K * x[4] * x[4] / (d1 * d1)
    F2 = K2 * x[5] * x[5] / (d2 * d2)
    load = p[IG]
    dx[0] = x[1]
    dx[1] = -A * F1 - B * F2 + C * p[IN1] + D * p[IN2] + load
    dx[2] = x[3]
    dx[3] = -B * F1 - A * F2 + D * p[IN1] + C * p[IN2] + load
    dx[4] = d1 / (2.0 * K) * (u[0] - p[IR1] * x[4]) + x[4] * dd1 / d1
    dx[5] = d2 / (2.0 * K2) * (u[1] - p[IR2] * x[5]) + x[5] * dd2 / d2


@njit(cache=True)
def rk4(x: np.ndarray, u: np.ndarray, p: np.ndarray, T: float, n: int) -> None:
    """Advance ``x`` in place over ``T`` seconds with ``n`` RK4 sub-steps, ``u`` held (ZOH)."""
    h = T / n
    k1 = np.empty(6)
    k2 = np.empty(6)
    k3 = np.empty(6)
    k4 = np.empty(6)
    xt = np.empty(6)
    for _ in range(n):
        dynamics(x, u, p, k1)
        for j in range(6):
            xt[j] = x[j] + 0.5 * h * k1[j]
        dynamics(xt, u, p, k2)
        for j in range(6):
            xt[j] = x[j] + 0.5 * h * k2[j]
        dynamics(xt, u, p, k3)
        for j in range(6):
            xt[j] = x[j] + h * k3[j]
        dynamics(xt, u, p, k4)
        for j in range(6):
            x[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])


@njit(cache=True)
def theta_of(phi: np.ndarray, cA: float, cC: float, theta: np.ndarray) -> None:
    """theta(phi) for phi = (1/m, R, K[, rho]) (docs/manual/controllers.md, A2 i); cA = Ll/I, cC = L^2/I;
    theta (8,) or (10,)."""
    mu, R, K = phi[0], phi[1], phi[2]
    Ap = mu + cA
    Bp = mu - cA
    theta[0] = Ap * R / 2
    theta[1] = -Ap * K
    theta[2] = Bp * R / 2
    theta[3] = -Bp * K
    theta[4] = -Ap / 2
    theta[5] = -Bp / 2
    theta[6] = mu + cC
    theta[7] = mu - cC
    if theta.shape[0] > 8:
        rho = phi[3] if phi.shape[0] > 3 else 0.0
        theta[8] = Ap * rho / 2
        theta[9] = Bp * rho / 2


@njit(cache=True)
def theta_jacobian(phi: np.ndarray, cA: float, J: np.ndarray) -> None:
    """J = d theta / d phi, shape (8, 3) or (10, 4)."""
    mu, R, K = phi[0], phi[1], phi[2]
    Ap = mu + cA
    Bp = mu - cA
    J[:, :] = 0.0
    J[0, 0] = R / 2
    J[1, 0] = -K
    J[2, 0] = R / 2
    J[3, 0] = -K
    J[4, 0] = -0.5
    J[5, 0] = -0.5
    J[6, 0] = 1.0
    J[7, 0] = 1.0
    J[0, 1] = Ap / 2
    J[2, 1] = Bp / 2
    J[1, 2] = -Ap
    J[3, 2] = -Bp
    if J.shape[0] > 8:
        rho = phi[3]
        J[8, 0] = rho / 2
        J[9, 0] = rho / 2
        J[8, 3] = Ap / 2
        J[9, 3] = Bp / 2


@njit(cache=True)
def lie_terms(d1: float, d2: float, i1: float, i2: float, P: float, Q: float, ab: np.ndarray) -> None:
    """ab = [a1, a2, b1, b2, q1, q2] from gaps and currents (delta from Eq. 6)."""
    de1 = P * d1 + Q * d2
    de2 = Q * d1 + P * d2
    b1 = i1 / de1
    b2 = i2 / de2
    ab[0] = i1 * b1
    ab[1] = i2 * b2
    ab[2] = b1
    ab[3] = b2
    ab[4] = b1 * b1
    ab[5] = b2 * b2


@njit(cache=True)
def regressors(ab: np.ndarray, u: np.ndarray, N1: float, N2: float, W3: np.ndarray, W2: np.ndarray) -> None:
    """W3 (8x2 or 10x2): y''' = W3^T theta;  W2 (same shape): y'' - g = W2^T theta (docs/manual/model.md)."""
    a1, a2, b1, b2, q1, q2 = ab[0], ab[1], ab[2], ab[3], ab[4], ab[5]
    W3[:, :] = 0.0
    W2[:, :] = 0.0
    W3[0, 0] = 2 * a1
    W3[0, 1] = 2 * a2
    W3[2, 0] = 2 * a2
    W3[2, 1] = 2 * a1
    W3[4, 0] = 2 * b1 * u[0]
    W3[4, 1] = 2 * b2 * u[1]
    W3[5, 0] = 2 * b2 * u[1]
    W3[5, 1] = 2 * b1 * u[0]
    W2[1, 0] = q1
    W2[1, 1] = q2
    W2[3, 0] = q2
    W2[3, 1] = q1
    W2[6, 0] = N1
    W2[6, 1] = N2
    W2[7, 0] = N2
    W2[7, 1] = N1
    if W3.shape[0] > 8:
        W3[8, 0] = 2 * a1
        W3[8, 1] = -2 * a2
        W3[9, 0] = -2 * a2
        W3[9, 1] = 2 * a1



def hover_forces(cfg: Mapping[str, Any], m: float | None = None) -> tuple[float, float]:
    """Magnet forces (F1, F2) (N) that hold the plate at rest, at any gaps (level or tilted).

    With d'' = 0 in Eq. 3: the sum of Eqs. 3a, 3b gives F1 + F2 = N1 + N2 + m g (A + B = C + D = 2/m)
    and their difference F1 - F2 = (L/l)(N1 - N2) ((C - D)/(A - B) = L/l). The gaps do not enter:
    a tilted equilibrium carries the same forces as the level one, with i_j = delta_j sqrt(F_j/K).
    """
    from .params import ConfigError

    mass = cfg["m"] if m is None else m
    heave = 0.5 * (cfg["N1"] + cfg["N2"] + mass * cfg["g"])
    pitch = 0.5 * cfg["L"] / cfg["l"] * (cfg["N1"] - cfg["N2"])
    F1, F2 = heave + pitch, heave - pitch
    if not (F1 > 0.0 and F2 > 0.0):
        raise ConfigError(f"no hover: the loads N1 = {cfg['N1']:g} N, N2 = {cfg['N2']:g} N need magnet forces "
                          f"({F1:.3g}, {F2:.3g}) N; a magnet can only attract (both must be > 0)")
    return F1, F2


def equilibrium(cfg: Mapping[str, Any], d1: float, d2: float,
                R: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(x0, u0): the exact equilibrium with gaps (d1, d2) (m) and the voltages (V) that hold it.

    Currents i_j = delta_j sqrt(F_j / K_j) with F_j of :func:`hover_forces`, delta_j of Eq. 6 and K_j of
    :func:`force_coefficients`;
    voltages u_j = R_j i_j (R: per-coil resistances, default :func:`coil_resistances`).
    """
    P, Q = (cfg["L"] + cfg["l"]) / (2 * cfg["L"]), (cfg["L"] - cfg["l"]) / (2 * cfg["L"])
    F1, F2 = hover_forces(cfg)
    de1, de2 = P * d1 + Q * d2, Q * d1 + P * d2
    K1, K2 = force_coefficients(cfg)
    i1, i2 = de1 * np.sqrt(F1 / K1), de2 * np.sqrt(F2 / K2)
    R1, R2 = coil_resistances(cfg) if R is None else R
    return np.array([d1, 0.0, d2, 0.0, i1, i2]), np.array([R1 * i1, R2 * i2])


def initial_state(pc: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(x0, u0) of a ``plant_sim`` group: the equilibrium at (d1_0, d2_0) (0: gap0) with R1, R2 at t = 0."""
    d1 = pc.get("d1_0") or pc["gap0"]
    d2 = pc.get("d2_0") or pc["gap0"]
    return equilibrium(pc, d1, d2)


def hover_current(cfg: Mapping[str, Any], gap: float, m: float | None = None) -> float:
    """Coil current that holds a symmetric hover at ``gap``: K i^2/gap^2 = N + m g/2."""
    mass = cfg["m"] if m is None else m
    if abs(cfg["N1"] - cfg["N2"]) > 1e-12:
        raise ValueError("symmetric hover needs N1 == N2")
    F0 = cfg["N1"] + mass * cfg["g"] / 2
    return float(gap * np.sqrt(F0 / cfg["K"]))


def hover_state(cfg: Mapping[str, Any], gap: float) -> tuple[np.ndarray, np.ndarray]:
    """(x0, u0): exact level equilibrium at ``gap`` (both magnets) and the voltages that hold it."""
    return equilibrium(cfg, gap, gap)
