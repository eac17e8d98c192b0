"""Independent sympy derivation of the DEM plant, from first principles.

Nothing here imports :mod:`dem_ros`: the model is rebuilt from the paper's
Newton equations and the circuit law so the tests compare two derivations.

    m d''     = -F1 - F2 + N1 + N2 + m g                       (Eq. 1a)
    I theta'' = N1 L - N2 L - F1 l + F2 l                      (Eq. 1b)
    d = (d1 + d2)/2,  theta = (d1 - d2)/(2L)                   (Eq. 2)
    delta_1 = d + l theta,  delta_2 = d - l theta              (Eq. 6, geometry)
    F_j = K i_j^2 / delta_j^2                                  (Eq. 5)
    u_j = R i_j + d(2K i_j/delta_j)/dt                         (erratum 1)

State x = [d1, d1', d2, d2', i1, i2], input u = [u1, u2], output h = [d1, d2].
"""

from __future__ import annotations

from functools import cache
from types import SimpleNamespace

import numpy as np
import sympy as sp

PARAM_NAMES = ("m", "I", "L", "l", "K", "R", "N1", "N2", "g")


@cache
def plant() -> SimpleNamespace:
    """Symbolic f(x), G(x), h(x) and helpers (cached: built once per session)."""
    m, I, L, l, K, R, N1, N2, g = sp.symbols(" ".join(PARAM_NAMES), positive=True)
    x = sp.symbols("x1:7", real=True)
    u = sp.symbols("u1:3", real=True)
    x1, x2, x3, x4, x5, x6 = x

    # --- mechanics: Newton (Eq. 1) for d'' and theta'' ---------------------
    d = (x1 + x3) / 2
    th = (x1 - x3) / (2 * L)
    de1 = d + l * th
    de2 = d - l * th
    F1 = K * x5**2 / de1**2
    F2 = K * x6**2 / de2**2
    dd, thdd = sp.symbols("dd thdd")
    newton = sp.linsolve(
        [m * dd - (-F1 - F2 + N1 + N2 + m * g), I * thdd - (N1 * L - N2 * L - F1 * l + F2 * l)], [dd, thdd]
    )
    dd_sol, thdd_sol = next(iter(newton))
    # d1 = d + L theta, d2 = d - L theta (inverse of Eq. 2)
    d1dd = dd_sol + L * thdd_sol
    d2dd = dd_sol - L * thdd_sol

    # --- circuit: u = R i + d/dt lambda(i, delta), lambda = 2K i/delta ------
    # d lambda/dt = lambda_i i' + lambda_delta delta', solved (linearly) for i'.
    i_s, dl_s, idot_s, dldot_s, u_s = sp.symbols("i_s dl_s idot_s dldot_s u_s")
    lam = 2 * K * i_s / dl_s
    lam_dot = sp.diff(lam, i_s) * idot_s + sp.diff(lam, dl_s) * dldot_s
    i_dot_expr = sp.solve(sp.Eq(u_s, R * i_s + lam_dot), idot_s)[0]
    dde1 = sp.diff(de1, x1) * x2 + sp.diff(de1, x3) * x4  # delta_1' by the chain rule
    dde2 = sp.diff(de2, x1) * x2 + sp.diff(de2, x3) * x4
    idot = [
        i_dot_expr.subs({i_s: x5, dl_s: de1, dldot_s: dde1, u_s: u[0]}),
        i_dot_expr.subs({i_s: x6, dl_s: de2, dldot_s: dde2, u_s: u[1]}),
    ]

    xdot = sp.Matrix([x2, d1dd, x4, d2dd, idot[0], idot[1]])
    G = xdot.jacobian(sp.Matrix(u))
    f = xdot.subs({u[0]: 0, u[1]: 0})
    h = sp.Matrix([x1, x3])
    X = sp.Matrix(x)

    def lie(vec, fld):
        return vec.jacobian(X) * fld

    Lfh = lie(h, f)
    Lf2h = lie(Lfh, f)
    dLf2h = Lf2h.jacobian(X)  # (2, 6): L_f^3 h = dLf2h f, L_g L_f^2 h = dLf2h G
    Lgh = h.jacobian(X) * G
    LgLfh = Lfh.jacobian(X) * G
    LgLf2h = dLf2h * G

    params = (m, I, L, l, K, R, N1, N2, g)
    args = (*x, *u, *params)
    return SimpleNamespace(
        x=x, u=u, params=params, f=f, G=G, h=h, X=X, de1=de1, de2=de2,
        Lfh=Lfh, Lf2h=Lf2h, dLf2h=dLf2h, Lgh=Lgh, LgLfh=LgLfh, LgLf2h=LgLf2h,
        xdot=xdot, lie=lie,
        xdot_fn=sp.lambdify(args, xdot, "numpy"),
        jac_fn=sp.lambdify(args, xdot.jacobian(X), "numpy"),
        f_fn=sp.lambdify(args, f, "numpy"),
        G_fn=sp.lambdify(args, G, "numpy"),
        Lf2h_fn=sp.lambdify(args, Lf2h, "numpy"),
        dLf2h_fn=sp.lambdify(args, dLf2h, "numpy"),
    )


def lie_numeric(P: SimpleNamespace, x, u, vals) -> dict:
    """Numeric Lie terms at (x, u): Lf2h (2,), Lf3h (2,), LgLf2h (2, 2), yddd = Lf3h + LgLf2h u (2,)."""
    args = (*x, *u, *vals)
    f = np.asarray(P.f_fn(*args), float).reshape(6)
    G = np.asarray(P.G_fn(*args), float).reshape(6, 2)
    dL = np.asarray(P.dLf2h_fn(*args), float).reshape(2, 6)
    Lf3h = dL @ f
    LgLf2h = dL @ G
    return {
        "Lf2h": np.asarray(P.Lf2h_fn(*args), float).reshape(2),
        "Lf3h": Lf3h,
        "LgLf2h": LgLf2h,
        "yddd": Lf3h + LgLf2h @ np.asarray(u, float),
        "xdot": np.asarray(P.xdot_fn(*args), float).reshape(6),
    }


def values(cfg: dict) -> tuple[float, ...]:
    """Numeric parameter tuple in :data:`PARAM_NAMES` order from a plant dict."""
    return tuple(float(cfg[n]) for n in PARAM_NAMES)
