r"""Offline closed-loop simulator (compiled), one run or a batch of plants.

Timing model (docs/manual/controllers.md "common loop", the same as the node graph's): at each
sample t_k = k T the sensors read x(t_k) (+ noise), the estimator and the
controller produce u_k, and u_k (+ the input perturbation) is held over
[t_k, t_{k+1}) while the plant is integrated with ``substeps`` RK4 steps.
``delay = d`` holds u_{k-d} instead (a command that arrives d periods late).

The result is one :class:`SimResult` with labelled signals in SI units.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit, prange

from .controllers import CEController, PIDController, make_controller
from .controllers import kernels as CK
from .estimator import NS, KalmanEstimator, ekf_step, make_estimator
from .model import IP, IQ, NPP, SM, apply_schedule, initial_state, plant_vector, rk4
from .reference import hover_start, reference_trajectory
from .scenarios import NOISE_UNIT, disturbances, plant_schedule, sensor_model

__all__ = ["Preroll", "SimResult", "preroll", "simulate", "simulate_batch"]


@njit(cache=True)
def _closed_loop(
    is_pid, mode, cp, theta, v, scale, v0, Pc, Z, uh, Ad, Bd, pid_cp, integ,
    est_on, s, Pe, mask, pe, Te, qc, rm,
    x, pp, L, l, sched, sg, sb, noise, pert, ref, dt, nsub, gap_min, gap_max, delay, u0,
    X_log, U_log, D_log, log,
):
    """Run the loop; returns the index of the first failed sample or -1."""
    n = ref.shape[0]
    ubuf = np.zeros((delay + 1, 2))
    for j in range(delay + 1):
        ubuf[j, 0] = u0[0]
        ubuf[j, 1] = u0[1]
    u = np.empty(2)
    diag = np.zeros(CK.NDIAG)
    z = np.empty(6)
    xh = np.empty(6)
    u_prev = u0.copy()
    ua = np.empty(2)
    for k in range(n):
        for i in range(6):
            z[i] = sg[i] * x[i] + sb[i] + noise[k, i]
        if est_on:
            ekf_step(s, Pe, z, mask, u_prev, pe, Te, qc, rm, xh)
        else:
            for i in range(6):
                xh[i] = z[i] if mask[i] > 0.0 else 0.0
        if is_pid:
            CK.pid_step(pid_cp, integ, xh, ref[k], u, diag)
        else:
            CK.ce_step(mode, cp, theta, v, scale, v0, Pc, Z, uh, Ad, Bd, xh, ref[k], u, diag)
        # delay line: slot k % (delay+1) holds u_k; apply u_{k-delay}
        slot = k % (delay + 1)
        ubuf[slot, 0] = u[0]
        ubuf[slot, 1] = u[1]
        old = (k + 1) % (delay + 1) if delay > 0 else slot
        u_prev[0] = ubuf[old, 0]
        u_prev[1] = ubuf[old, 1]
        ua[0] = u_prev[0] + pert[k, 0]
        ua[1] = u_prev[1] + pert[k, 1]
        if log:
            for i in range(6):
                X_log[k, i] = x[i]
            U_log[k, 0] = u_prev[0]
            U_log[k, 1] = u_prev[1]
            for i in range(CK.NDIAG):
                D_log[k, i] = diag[i]
        apply_schedule(pp, sched[k], L, l)
        rk4(x, ua, pp, dt, nsub)
        de1 = pp[IP] * x[0] + pp[IQ] * x[2]
        de2 = pp[IQ] * x[0] + pp[IP] * x[2]
        bad = False
        for i in range(6):
            if not np.isfinite(x[i]):
                bad = True
        if bad or min(x[0], x[2], de1, de2) <= gap_min or max(x[0], x[2]) > gap_max:
            return k + 1
    return -1


@njit(cache=True)
def _batch_metrics(X, ref, start):
    """(rms (2,), max (2,), rms after ``start`` (2,)) of e = gaps - y_m over rows of X."""
    n = X.shape[0]
    out = np.zeros(6)
    cnt2 = 0
    for k in range(n):
        for j in range(2):
            e = X[k, 2 * j] - ref[k, j]
            out[j] += e * e
            out[2 + j] = max(out[2 + j], abs(e))
            if k >= start:
                out[4 + j] += e * e
        if k >= start:
            cnt2 += 1
    for j in range(2):
        out[j] = np.sqrt(out[j] / max(n, 1))
        out[4 + j] = np.sqrt(out[4 + j] / max(cnt2, 1))
    return out


@dataclass
class SimResult:
    """One closed-loop run. Arrays are per sample k (t_k = k T)."""

    scenario: str
    controller: str
    estimator: str
    config: dict
    t: np.ndarray  # (N,) s
    x: np.ndarray  # (N, 6) true state [d1, d1', d2, d2', i1, i2] (m, m/s, A)
    u: np.ndarray  # (N, 2) commanded voltage held over [t_k, t_k+1) (V)
    d: np.ndarray  # (N, 2) input perturbation (V)
    ref: np.ndarray  # (N, 8) reference [y, y', y'', y'''] per magnet
    r: np.ndarray  # (N, 2) command (m)
    diag: np.ndarray  # (N, 9) m_hat, R_hat, K_hat, ec1, ec2, e1, e2, adapting, fault
    mass: np.ndarray  # (N,) kg
    schedule: np.ndarray  # (N, 6) true m, I, N1, N2, R1, R2 (model.S*)
    failed: bool
    fail_time: float | None
    wall_time: float
    extra: dict = field(default_factory=dict)

    @property
    def error(self) -> np.ndarray:
        """Tracking error e = true gap - y_m (N, 2) in m."""
        return self.x[:, [0, 2]] - self.ref[:, :2]

    def metrics(self) -> dict[str, Any]:
        from .metrics import tracking_metrics

        return tracking_metrics(self)


def _final_estimates(D: np.ndarray) -> dict | None:
    if D.shape[0] == 0 or not np.all(np.isfinite(D[-1, :3])):
        return None
    return {"m_kg": float(D[-1, 0]), "R_ohm": float(D[-1, 1]), "K": float(D[-1, 2])}


def _estimator_args(est, measure_velocity: bool):
    if isinstance(est, KalmanEstimator):
        return (True,) + est.kernel_args()
    mask = np.array([1.0, float(measure_velocity), 1.0, float(measure_velocity), 1.0, 1.0])
    return (False, np.zeros(NS), np.eye(NS), mask, np.zeros(NPP), 1e-3, np.zeros(4), np.zeros(6))


def _controller_args(ctrl):
    if isinstance(ctrl, PIDController):
        dummy = np.zeros(CK.NTH)
        return (True, 0, np.zeros(CK.NCP), dummy, dummy.copy(), dummy.copy(), dummy.copy(), np.zeros((CK.NTH, CK.NTH)),
                np.zeros((3, CK.NZ)), np.zeros((CK.NUH, 2)), np.eye(3), np.zeros(3), ctrl.cp, ctrl.integ)
    assert isinstance(ctrl, CEController)
    mode, cp, theta, v, scale, v0, P, Z, uh, Ad, Bd = ctrl.kernel_args()
    return (False, mode, cp, theta, v, scale, v0, P, Z, uh, Ad, Bd, np.zeros(CK.NPID), np.zeros(2))


def prepare(cfg: Mapping, duration: float, seed: int | None = None):
    """(t, r, ref, mass, noise, pert) of a run of ``duration`` s (see :func:`.scenarios.disturbances`)."""
    pc = cfg["plant_sim"]
    dt = pc["dt"]
    n = round(duration / dt)
    t = np.arange(n) * dt
    r, ref = reference_trajectory({**cfg["reference"], "dt": dt}, n)
    dist = disturbances(pc, n, seed)
    return t, r, ref, dist.schedule[:, SM].copy(), dist.noise, dist.pert


@dataclass(frozen=True)
class Preroll:
    """What the pre-roll leaves behind.

    Attributes:
        window_z (n, 6): the controller's hover window: the estimates it saw over the last ``hover_window`` s.
        window_u (n, 2): the voltages applied meanwhile (V).
        gaps (n_pre, 2): the measured gaps of the whole pre-roll (m), where the reference starts.
    """

    window_z: np.ndarray
    window_u: np.ndarray
    gaps: np.ndarray


def preroll(pc: Mapping, est, x0: np.ndarray, u0: np.ndarray, sg: np.ndarray, sb: np.ndarray,
            window: float, seed: int | None = None) -> Preroll:
    """The graph's pre-roll, offline: the plate rests at x0 under u0 for ``preroll`` s before t = 0.

    The estimator runs on the sensor readings z = G x0 + b + noise (noise from a separate stream,
    so the run's own sequences are unchanged).
    """
    dt = pc["dt"]
    n_pre = max(round(pc["preroll"] / dt), 1)
    n_win = min(max(round(window / dt), 1), n_pre)
    rng = np.random.default_rng([pc["seed"] if seed is None else seed, 1])
    a = pc["noise_scale"] * NOISE_UNIT
    Zw = np.empty((n_win, 6))
    gaps = np.empty((n_pre, 2))
    for k in range(n_pre):
        z = sg * x0 + sb + (rng.uniform(-1.0, 1.0, 6) * a if pc["noise_scale"] > 0 else 0.0)
        if not pc["measure_velocity"]:
            z[[1, 3]] = 0.0
        gaps[k] = z[0], z[2]
        if k == 0:
            est.reset(z)
            xh = est.out
        else:
            xh = est.step(z, u0)
        if k >= n_pre - n_win:
            Zw[k - (n_pre - n_win)] = xh
    return Preroll(Zw, np.repeat(u0[None], n_win, axis=0), gaps)


def simulate(
    cfg: Mapping[str, Mapping[str, Any]],
    *,
    controller: str | None = None,
    estimator: str | None = None,
    duration: float = 100.0,
    seed: int | None = None,
    delay: int | None = None,
    scenario: str = "custom",
) -> SimResult:
    """Simulate the closed loop for ``duration`` s from the 8 mm hover (docs/manual/scenarios.md).

    ``delay`` (samples) sets both the plant's command delay and the controller's
    knowledge of it; ``None`` takes ``plant_sim.command_delay`` and
    ``controller.command_delay`` from ``cfg``.
    """
    if duration <= 0:
        from .params import ConfigError

        raise ConfigError(f"duration: got {duration!r}, expected a positive number of seconds")
    wall0 = time.perf_counter()
    if delay is not None:
        cfg = {g: dict(v) for g, v in cfg.items()}
        cfg["plant_sim"]["command_delay"] = int(delay)
        cfg["controller"]["command_delay"] = int(delay)
    pc = cfg["plant_sim"]
    delay = pc["command_delay"]
    dt = pc["dt"]
    n = round(duration / dt)
    t = np.arange(n) * dt
    dist = disturbances(pc, n, seed)
    x0, u0 = initial_state(pc)
    sg, sb = sensor_model(pc)
    ctrl = make_controller(cfg["controller"], controller)
    est = make_estimator(cfg["estimator"], estimator, pc["measure_velocity"])
    pre = preroll(pc, est, x0, u0, sg, sb, cfg["controller"]["hover_window"], seed)
    ctrl.reset(pre.window_z, pre.window_u)
    r, ref = reference_trajectory({**cfg["reference"], "dt": dt}, n, hover_start(pre.gaps))
    x = x0.copy()
    pp = plant_vector(pc)
    X = np.zeros((n, 6))
    U = np.zeros((n, 2))
    D = np.full((n, CK.NDIAG), np.nan)
    k_fail = _closed_loop(
        *_controller_args(ctrl), *_estimator_args(est, pc["measure_velocity"]),
        x, pp, pc["L"], pc["l"], dist.schedule, sg, sb, dist.noise, dist.pert, ref, dt, pc["substeps"],
        pc["gap_min"], pc["gap_max"], int(delay), u0.copy(), X, U, D, True,
    )
    mass = dist.schedule[:, SM]
    pert = dist.pert
    failed = k_fail >= 0
    m = k_fail if failed else n
    return SimResult(
        scenario=scenario, controller=ctrl.name, estimator=est.name, config={g: dict(v) for g, v in cfg.items()},
        t=t[:m], x=X[:m], u=U[:m], d=pert[:m], ref=ref[:m], r=r[:m], diag=D[:m], mass=mass[:m],
        schedule=dist.schedule[:m],
        failed=bool(failed), fail_time=float(k_fail * pc["dt"]) if failed else None,
        wall_time=time.perf_counter() - wall0,
        extra={"delay": int(delay), "final_estimates": _final_estimates(D[:m])},
    )


@njit(cache=True, parallel=True)
def _batch(
    is_pid, mode, cp, theta, v, scale, v0, Pc, Z, uh, Ad, Bd, pid_cp, integ,
    x0, pp, L, l, scheds, ref, dt, nsub, gap_min, gap_max, u0, start, delay, out,
):
    B = scheds.shape[0]
    n = ref.shape[0]
    noise = np.zeros((n, 6))
    pert = np.zeros((n, 2))
    mask = np.ones(6)
    sg = np.ones(6)
    sb = np.zeros(6)
    for b in prange(B):
        X = np.zeros((n, 6))
        U = np.zeros((n, 2))
        D = np.zeros((n, CK.NDIAG))
        x = x0.copy()
        ppb = pp.copy()
        kf = _closed_loop(
            is_pid, mode, cp.copy(), theta[b], v[b], scale[b], v0[b], Pc[b], Z[b], uh[b], Ad, Bd, pid_cp, integ[b],
            False, np.zeros(NS), np.eye(NS), mask, pp, dt, np.zeros(4), np.zeros(6),
            x, ppb, L, l, scheds[b], sg, sb, noise, pert, ref, dt, nsub, gap_min, gap_max, delay, u0,
            X, U, D, True,
        )
        m = n if kf < 0 else kf
        out[b, 6] = kf
        out[b, :6] = _batch_metrics(X[:m], ref[:m], start)


def simulate_batch(cfg: Mapping, mass_offsets: np.ndarray, *, controller: str | None = None, duration: float = 100.0) -> np.ndarray:
    """Run ``len(mass_offsets)`` plants (added mass, kg) in parallel (no noise, no estimator).

    Returns (B, 7): rms e1, rms e2, max e1, max e2, rms e1 after 40 s, rms e2 after 40 s (m),
    fail index (-1 = none).
    """
    pc = cfg["plant_sim"]
    n = round(duration / pc["dt"])
    t = np.arange(n) * pc["dt"]
    scheds = np.stack([plant_schedule({**pc, "mass_delta": float(dm)}, t) for dm in mass_offsets])
    x0, u0 = initial_state(pc)
    ctrl = make_controller(cfg["controller"], controller)
    sg, sb = sensor_model(pc)
    pre = preroll(pc, make_estimator(cfg["estimator"], "none", pc["measure_velocity"]), x0, u0, sg, sb,
                  cfg["controller"]["hover_window"])
    ctrl.reset(pre.window_z, pre.window_u)
    _, ref = reference_trajectory({**cfg["reference"], "dt": pc["dt"]}, n, hover_start(pre.gaps))

    args = list(_controller_args(ctrl))
    B = len(mass_offsets)
    for i in (3, 4, 5, 6, 7, 8, 9, 13):  # per-run state arrays
        args[i] = np.ascontiguousarray(np.repeat(args[i][None], B, axis=0))
    out = np.zeros((B, 7))
    _batch(*args, x0, plant_vector(pc), pc["L"], pc["l"], scheds, ref, pc["dt"], pc["substeps"],
           pc["gap_min"], pc["gap_max"], u0, round(40.0 / pc["dt"]), int(pc["command_delay"]), out)
    return out
