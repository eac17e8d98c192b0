"""Controllers: one interface, selectable by name.

==========================  =====================================================
name                        what it is
==========================  =====================================================
``adaptive`` (default)      corrected adaptive design "A2" (docs/manual/controllers.md)
``adaptive_enhanced``       A2 + corrected leakage ``w`` and dead zone ``R0`` (Eq. 48, "A2e")
``paper``                   the adaptive law exactly as printed (Eq. 36, "A0"); it fails
``paper_fixed``             minimal errata fixes to the paper's 8-theta law ("A1")
``nonlinear_decoupling``    CE feedback linearisation with fixed nominal parameters
``decentralized_pid``       one cascade PID per magnet with an inner current loop
==========================  =====================================================

Every controller has ``reset(meas0, u0)`` (start from a measured hover with the
voltage that held it: one sample (6,), (2,) or a window of pre-roll samples
(n, 6), (n, 2), see :mod:`.hover`) and ``step(meas, ref) -> u`` where ``meas`` =
[d1, d1', d2, d2', i1, i2] (m, m/s, A) and ``ref`` the 8-vector of
:mod:`dem_ros.core.reference`; after a step, ``diag`` holds
m_hat, R_hat, K_hat, e_c (2), e (2), adapting, fault.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..lti import AllPoleFilter
from ..model import gap_weights, lie_terms, regressors, theta_of
from ..params import SCHEMA, ConfigError
from . import kernels
from .hover import HoverFit, solve_hover, window_means

__all__ = ["CONTROLLERS", "CEController", "Controller", "PIDController", "make_controller"]

_MODES = {
    "adaptive": kernels.MODE_ADAPTIVE,
    "adaptive_enhanced": kernels.MODE_ENHANCED,
    "paper": kernels.MODE_PAPER,
    "paper_fixed": kernels.MODE_PAPER_FIX,
    "nonlinear_decoupling": kernels.MODE_FIXED,
    "decentralized_pid": -1,
}
#: name -> kernel mode (-1: the PID), in the schema's order; the names are the schema's (``controller.type``)
CONTROLLERS = {name: _MODES[name] for name in SCHEMA.spec("controller", "type").choices or ()}
if set(CONTROLLERS) != set(_MODES):  # pragma: no cover - a law added on one side only
    raise ImportError(f"controller.type choices {sorted(CONTROLLERS)} != implemented laws {sorted(_MODES)}")


class Controller:
    """Common interface (see module docstring)."""

    name: str
    diag: np.ndarray

    def reset(self, meas0: np.ndarray, u0: np.ndarray,
              accel: np.ndarray | None = None) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def step(self, meas: np.ndarray, ref: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def set_params(self, cfg: Mapping[str, Any]) -> None:  # pragma: no cover - interface
        raise NotImplementedError


def _cp_vector(cfg: Mapping[str, Any]) -> np.ndarray:
    cp = np.zeros(kernels.NCP)
    L, l, I = cfg["L"], cfg["l"], cfg["I"]
    cp[kernels.CP_K1], cp[kernels.CP_K2], cp[kernels.CP_K3] = cfg["k1"], cfg["k2"], cfg["k3"]
    cp[kernels.CP_P], cp[kernels.CP_Q] = gap_weights(L, l)
    cp[kernels.CP_CA] = L * l / I
    cp[kernels.CP_CC] = L * L / I
    cp[kernels.CP_N1], cp[kernels.CP_N2], cp[kernels.CP_G] = cfg["N1"], cfg["N2"], cfg["g"]
    cp[kernels.CP_FLOOR] = cfg["gap_floor"]
    cp[kernels.CP_TS] = cfg["dt"]
    cp[kernels.CP_W] = cfg["w"]
    cp[kernels.CP_R0] = cfg["R0"]
    cp[kernels.CP_DZ] = {"pdot": kernels.DZ_PDOT, "error": kernels.DZ_ERROR, "off": kernels.DZ_OFF}[cfg["deadzone"]]
    cp[kernels.CP_E0] = cfg["e0"]
    cp[kernels.CP_MU_MIN] = 1.0 / cfg["m_max"]
    cp[kernels.CP_MU_MAX] = 1.0 / cfg["m_min"]
    cp[kernels.CP_R_MIN], cp[kernels.CP_R_MAX] = cfg["R_min"], cfg["R_max"]
    cp[kernels.CP_K_MIN], cp[kernels.CP_K_MAX] = cfg["K_min"], cfg["K_max"]
    cp[kernels.CP_QM], cp[kernels.CP_QR], cp[kernels.CP_QK] = cfg["q_m"], cfg["q_R"], cfg["q_K"]
    cp[kernels.CP_ULIM] = min(cfg["voltage_limit"], cfg["u_max"])  # the board's limit too (kernels.py)
    cp[kernels.CP_DELAY] = cfg["command_delay"]
    cp[kernels.CP_QRHO] = cfg["q_rho"]
    cp[kernels.CP_RHO_MAX] = cfg["rho_max"]
    cp[kernels.CP_KI] = cfg["ki"]
    cp[kernels.CP_COIL_W] = cfg["coil_weight"]
    cp[kernels.CP_COIL_A] = 1.0 - np.exp(-cfg["coil_bandwidth"] * cfg["dt"])
    return cp


def _theta(phi: np.ndarray, cp: np.ndarray) -> np.ndarray:
    """theta (NTH,) of phi = (1/m, R, K[, rho])."""
    th = np.empty(kernels.NTH)
    theta_of(np.asarray(phi, float), cp[kernels.CP_CA], cp[kernels.CP_CC], th)
    return th


def hover_regressors(cp: np.ndarray, meas0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(W3, W2) at the pre-start hover (x0, u0)."""
    ab = np.empty(6)
    lie_terms(max(meas0[0], cp[kernels.CP_FLOOR]), max(meas0[2], cp[kernels.CP_FLOOR]), meas0[4], meas0[5],
              cp[kernels.CP_P], cp[kernels.CP_Q], ab)
    W3 = np.empty((8, 2))
    W2 = np.empty((8, 2))
    regressors(ab, np.asarray(u0, float), cp[kernels.CP_N1], cp[kernels.CP_N2], W3, W2)
    return W3, W2


class CEController(Controller):
    """Certainty-equivalence feedback linearisation, fixed or adaptive (modes of :mod:`.kernels`)."""

    def __init__(self, cfg: Mapping[str, Any], name: str | None = None):
        self.name = name or cfg["type"]
        if self.name not in CONTROLLERS or self.name == "decentralized_pid":
            raise ConfigError(f"controller.type: {self.name!r} is not a CE controller")
        self.mode = CONTROLLERS[self.name]
        self.cfg = SCHEMA.validate_group("controller", dict(cfg))
        # the law's arrays are views into one buffer and the state's into another (kernels.LB_*, SB_*): a step
        # passes the compiled code two arrays, not sixteen (kernels.ce_step_buffers)
        self._lb = np.zeros(kernels.NLB)
        self.cp, self._Ad, self._Bd = kernels.law_views(self._lb)
        self.cp[:] = _cp_vector(self.cfg)
        self.law = kernels.CELaw(self.mode, self.cp, self._Ad, self._Bd)
        self._filter()
        self.hover_fit: HoverFit | None = None
        self.reset(None, None)

    def _filter(self) -> None:
        c = self.cfg
        self.F = AllPoleFilter([c["k3"], c["k2"], c["k1"]], 1.0, c["dt"])
        self._Ad[:] = self.F.Ad
        self._Bd[:] = self.F.Bd

    # -- state ------------------------------------------------------------
    def reset(self, meas0: np.ndarray | None, u0: np.ndarray | None, accel: np.ndarray | None = None) -> None:
        """Fresh estimates and zero filters; with a measured hover (meas0, u0), hover-initialise A1/A2.

        ``accel`` (2,) or (n, 2): the gaps' measured accelerations [m/s^2] at meas0 when the plate is not at rest
        (it leaves its support: A2 fits the heave equation to them, so that the law's model does not take the
        lift-off's net force for a force bias; A1 ignores them)."""
        c = self.cfg
        cp = self.cp
        window = None
        if meas0 is not None and u0 is not None:
            window = (np.atleast_2d(np.asarray(meas0, float)), np.atleast_2d(np.asarray(u0, float)))
            meas0, u0 = window_means(*window)
        self.hover_fit = None
        self._sb = np.zeros(kernels.NSB)  # all zero: Z, P, v, v0, ie
        self.state, self.u, self.diag = kernels.state_views(self._sb)
        self.theta, self.v, self.scale, self.v0, self.P, self.Z, self.uh, self.ie, self.coil = self.state
        if u0 is not None:
            self.uh[:] = np.asarray(u0, float)  # before t = 0 the coils held u0
        self.scale[:] = 1.0
        if self.mode == kernels.MODE_FIXED:
            self.theta[:] = _theta(np.array([1 / c["m_nominal"], c["R_nominal"], c["K_nominal"]]), cp)
        else:
            phi0 = np.array([1 / c["m_init"], c["R_init"], c["K_init"]])
            th0 = _theta(phi0, cp)
            if self.mode == kernels.MODE_PAPER:
                self.theta[:] = th0
                self.v[:] = th0
                self.P[:8, :8] = np.eye(8)
            elif self.mode == kernels.MODE_PAPER_FIX:
                A0 = phi0[0] + cp[kernels.CP_CA]
                C0 = phi0[0] + cp[kernels.CP_CC]
                self.scale[:8] = [A0 * phi0[1] / 2, A0 * phi0[2], A0 * phi0[1] / 2, A0 * phi0[2],
                                  A0 / 2, A0 / 2, C0, C0]
                self.v[:] = th0 / self.scale  # entries 8, 9 (rho) stay 0: A1 keeps the paper's 8 thetas
                self.P[:8, :8] = 1e4 * np.eye(8)
                if meas0 is not None and u0 is not None and c["hover_init"]:
                    self._hover_init_a1(meas0, u0)
                self.theta[:] = self.scale * self.v
            else:
                n = kernels.NPHI
                self.scale[:n] = [phi0[0], phi0[1], phi0[2], phi0[1]]  # rho in units of R_init
                self.v[:n] = [1.0, 1.0, 1.0, 0.0]
                self.P[:n, :n] = np.diag([c["P0_m"], c["P0_R"], c["P0_K"], c["P0_rho"]])
                if window is not None and c["hover_init"]:
                    self._hover_init_a2(*window, accel)
                self.theta[:] = _theta(self.scale[:n] * self.v[:n], cp)
            self.v0[:] = self.v
        if u0 is not None:
            self.u[:] = np.asarray(u0, float)
        self.coil[:] = np.nan  # coil-equation filters: start at the first sample
        self.diag[:] = np.nan
        self._fill_estimates()

    def _fill_estimates(self) -> None:
        if self.mode in (kernels.MODE_ADAPTIVE, kernels.MODE_ENHANCED):
            phi = self.scale[:3] * self.v[:3]
            self.diag[:3] = [1 / phi[0], phi[1], phi[2]]
        else:
            kernels.physical_estimates(self.theta, self.diag)

    def _hover_init_a2(self, Zw: np.ndarray, Uw: np.ndarray, accel: np.ndarray | None = None) -> None:
        """Notes 6 A2 (iv) from a window of pre-roll samples: :func:`.hover.solve_hover`."""
        cp = self.cp
        geo = {"P": cp[kernels.CP_P], "Q": cp[kernels.CP_Q], "cA": cp[kernels.CP_CA], "cC": cp[kernels.CP_CC],
               "N1": cp[kernels.CP_N1], "N2": cp[kernels.CP_N2], "g": cp[kernels.CP_G], "floor": cp[kernels.CP_FLOOR]}
        lo = np.array([cp[kernels.CP_MU_MIN], cp[kernels.CP_R_MIN], cp[kernels.CP_K_MIN], -cp[kernels.CP_RHO_MAX]])
        hi = np.array([cp[kernels.CP_MU_MAX], cp[kernels.CP_R_MAX], cp[kernels.CP_K_MAX], cp[kernels.CP_RHO_MAX]])
        n = kernels.NPHI
        scale = self.scale[:n].copy()
        A = None if accel is None else np.broadcast_to(np.asarray(accel, float), (len(Zw), 2))
        fit = solve_hover(scale * self.v[:n], scale, self.P[:n, :n], Zw, Uw, geo, lo, hi, A=A)
        self.v[:n] = fit.phi / scale
        self.hover_fit = fit

    def _hover_init_a1(self, meas0: np.ndarray, u0: np.ndarray) -> None:
        """Notes 6 A1: minimum-norm correction so that W_p^T theta = -k1 g; then P = 1e5 (I - proj)."""
        cp = self.cp
        W3, W2 = hover_regressors(cp, meas0, u0)
        k1 = cp[kernels.CP_K1]
        Xh = (W3 + k1 * W2) * self.scale[:8, None]
        P0 = self.P[:8, :8]
        v = self.v[:8]
        target = -k1 * cp[kernels.CP_G] * np.ones(2)
        v += P0 @ Xh @ np.linalg.pinv(Xh.T @ P0 @ Xh, rcond=1e-10) @ (target - Xh.T @ v)
        proj = Xh @ np.linalg.pinv(Xh.T @ Xh, rcond=1e-10) @ Xh.T
        self.P[:8, :8] = 1e5 * (np.eye(8) - proj)


    # -- loop -------------------------------------------------------------
    def step(self, meas: np.ndarray, ref: np.ndarray) -> np.ndarray:
        kernels.ce_step_buffers(self.mode, self._lb, self._sb, meas, ref)  # into self.u, self.diag (views of _sb)
        return self.u

    def set_params(self, cfg: Mapping[str, Any]) -> None:
        """Apply a validated live change at the next step (gains, leakage, dead zone, limits).

        Changing k1..k3 re-discretises F(s); its states are kept (a transient in e_c follows).
        Initial estimates and nominal parameters take effect at the next ``reset``.
        """
        new = SCHEMA.validate_group("controller", dict(cfg))
        gains_changed = any(new[k] != self.cfg[k] for k in ("k1", "k2", "k3", "dt"))
        self.cfg = new
        self.cp[:] = _cp_vector(new)
        if gains_changed:
            self._filter()
        if self.mode == kernels.MODE_FIXED:
            self.theta[:] = _theta(np.array([1 / new["m_nominal"], new["R_nominal"], new["K_nominal"]]), self.cp)



class PIDController(Controller):
    """Decentralised cascade PID on the nominal single-magnet model (coupling ignored)."""

    def __init__(self, cfg: Mapping[str, Any]):
        self.name = "decentralized_pid"
        self.cfg = SCHEMA.validate_group("controller", dict(cfg))
        self.cp = np.zeros(kernels.NPID)
        self._fill()
        self.integ = np.zeros(2)
        self.u = np.zeros(2)
        self.diag = np.full(kernels.NDIAG, np.nan)

    def _fill(self) -> None:
        c = self.cfg
        F0 = c["N1"] + c["m_nominal"] * c["g"] / 2
        self.cp[:] = [c["pid_kp"], c["pid_kd"], c["pid_ki"], c["pid_kc"], c["R_nominal"],
                      np.sqrt(F0 / c["K_nominal"]), c["dt"], min(c["voltage_limit"], c["u_max"])]

    def reset(self, meas0: np.ndarray | None, u0: np.ndarray | None, accel: np.ndarray | None = None) -> None:
        self.integ[:] = 0.0
        self.u = np.zeros(2) if u0 is None else np.asarray(u0, float).copy()

    def step(self, meas: np.ndarray, ref: np.ndarray) -> np.ndarray:
        kernels.pid_step(self.cp, self.integ, meas, ref, self.u, self.diag)
        return self.u

    def set_params(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = SCHEMA.validate_group("controller", dict(cfg))
        self._fill()


def make_controller(cfg: Mapping[str, Any], name: str | None = None) -> Controller:
    """Build the controller ``name`` (default ``cfg['type']``) from a ``controller`` group."""
    name = name or cfg["type"]
    if name not in CONTROLLERS:
        raise ConfigError(f"controller.type: got {name!r}, expected one of {', '.join(CONTROLLERS)}")
    c = dict(cfg)
    c["type"] = name
    if name == "decentralized_pid":
        return PIDController(c)
    return CEController(c, name)
