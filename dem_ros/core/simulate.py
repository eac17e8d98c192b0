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
from typing import Any, NamedTuple

import numpy as np
from numba import njit, prange

from .controllers import CEController, Controller, PIDController, make_controller
from .controllers import kernels as CK
from .controllers.sequence import ControlSequence
from .estimator import NS, KalmanEstimator, PassThrough, ekf_step, make_estimator
from .hold import command_sample
from .model import IP, IQ, NPP, SM, apply_schedule, initial_state, plant_vector, rk4
from .params import with_board_limit
from .reference import hover_start, reference_trajectory
from .scenarios import NOISE_UNIT, disturbances, plant_schedule, sensor_model

__all__ = ["Preroll", "SimResult", "preroll", "simulate", "simulate_batch"]


class LawArgs(NamedTuple):
    """The control law of a run, as the compiled loop takes it: a CE law or the PID."""

    is_pid: bool
    ce: CK.CELaw
    ce_state: CK.CEState
    pid_cp: np.ndarray  # (NPID,)
    pid_integ: np.ndarray  # (2,) PID integrators (m s)


class EstimatorArgs(NamedTuple):
    """The estimator of a run (``on`` False: the law gets the masked measurement); see :func:`.estimator.ekf_step`."""

    on: bool
    s: np.ndarray  # (NS,) EKF state
    P: np.ndarray  # (NS, NS)
    mask: np.ndarray  # (6,) 1 = measured
    p: np.ndarray  # (NPP,) the filter's model
    T: float  # s
    qc: np.ndarray  # (4,) process noise
    rm: np.ndarray  # (6,) measurement variances


class PlantArgs(NamedTuple):
    """The simulated plant and board of a run (SI units)."""

    x: np.ndarray  # (6,) state, advanced in place
    p: np.ndarray  # (NPP,) kernel parameter vector (truth set from ``sched`` every sample)
    L: float  # m
    l: float  # m
    sched: np.ndarray  # (n, NSCHED) time-varying truth
    sg: np.ndarray  # (6,) sensor gains
    sb: np.ndarray  # (6,) sensor offsets
    noise: np.ndarray  # (n, 6) measurement noise
    pert: np.ndarray  # (n, 2) input perturbation (V)
    dt: float  # s
    nsub: int  # RK4 sub-steps per sample
    gap_min: float  # m, rail contact at or below
    gap_max: float  # m, dropped above
    u_max: float  # V, the coil driver's limit (the board's Supervisor u_max)
    delay: int  # samples between a command's sample and the period it is held over
    u0: np.ndarray  # (2,) voltage held before t = 0 (V)


class Logs(NamedTuple):
    """Per-sample logs filled by the loop when ``on``: X (n, 6) true state, U (n, 2) applied voltage, D (n, NDIAG)."""

    X: np.ndarray
    U: np.ndarray
    D: np.ndarray
    on: bool


@njit(cache=True)
def _closed_loop(law: LawArgs, est: EstimatorArgs, plant: PlantArgs, ref: np.ndarray, logs: Logs) -> int:
    """Run the loop (``law`` :class:`LawArgs`, ``est`` :class:`EstimatorArgs`, ``plant`` :class:`PlantArgs`,
    ``ref`` (n, 8), ``logs`` :class:`Logs`); returns the index of the first failed sample or -1.

    The applied voltage is the command of ``delay`` samples ago clipped to +-u_max (the board's coil
    driver, :class:`dem_ros.board.Supervisor` in RUN), plus the input perturbation.
    """
    n = ref.shape[0]
    # the records' fields as locals, once: an array field read inside the loop costs numba a
    # reference-count increment and decrement per sample (#9 item 5: records at no cost)
    delay = plant.delay
    x = plant.x
    pp = plant.p
    u_max = plant.u_max
    sg, sb, noise, pert, sched = plant.sg, plant.sb, plant.noise, plant.pert, plant.sched
    ce, ce_state, pid_cp, pid_integ = law.ce, law.ce_state, law.pid_cp, law.pid_integ
    s, Pe, mask, pe, qc, rm = est.s, est.P, est.mask, est.p, est.qc, est.rm
    X_log, U_log, D_log = logs.X, logs.U, logs.D
    ubuf = np.zeros((delay + 1, 2))
    for j in range(delay + 1):
        ubuf[j, 0] = plant.u0[0]
        ubuf[j, 1] = plant.u0[1]
    u = np.empty(2)
    diag = np.zeros(CK.NDIAG)
    z = np.empty(6)
    xh = np.empty(6)
    u_prev = plant.u0.copy()
    ua = np.empty(2)
    for k in range(n):
        for i in range(6):
            z[i] = sg[i] * x[i] + sb[i] + noise[k, i]
        if est.on:
            ekf_step(s, Pe, z, mask, u_prev, pe, est.T, qc, rm, xh)
        else:
            for i in range(6):
                xh[i] = z[i] if mask[i] > 0.0 else 0.0
        if law.is_pid:
            CK.pid_step(pid_cp, pid_integ, xh, ref[k], u, diag)
        else:
            CK.ce_step(ce, ce_state, xh, ref[k], u, diag)
        # delay line: slot k % (delay+1) holds u_k; apply the command of sample command_sample(k, delay)
        # (u0 before the first), clipped by the coil driver
        slot = k % (delay + 1)
        ubuf[slot, 0] = u[0]
        ubuf[slot, 1] = u[1]
        old = command_sample(k, delay) % (delay + 1)
        for j in range(2):
            u_prev[j] = min(max(ubuf[old, j], -u_max), u_max)
            ua[j] = u_prev[j] + pert[k, j]
        if logs.on:
            for i in range(6):
                X_log[k, i] = x[i]
            U_log[k, 0] = u_prev[0]
            U_log[k, 1] = u_prev[1]
            for i in range(CK.NDIAG):
                D_log[k, i] = diag[i]
        apply_schedule(pp, sched[k], plant.L, plant.l)
        rk4(x, ua, pp, plant.dt, plant.nsub)
        de1 = pp[IP] * x[0] + pp[IQ] * x[2]
        de2 = pp[IQ] * x[0] + pp[IP] * x[2]
        bad = False
        for i in range(6):
            if not np.isfinite(x[i]):
                bad = True
        if bad or min(x[0], x[2], de1, de2) <= plant.gap_min or max(x[0], x[2]) > plant.gap_max:
            return k + 1
    return -1


@njit(cache=True)
def _batch_metrics(X: np.ndarray, ref: np.ndarray, start: int) -> np.ndarray:
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
    config: dict[str, dict[str, Any]]
    t: np.ndarray  # (N,) s
    x: np.ndarray  # (N, 6) true state [d1, d1', d2, d2', i1, i2] (m, m/s, A)
    u: np.ndarray  # (N, 2) applied voltage over [t_k, t_k+1): the command of sample k - delay clipped to +-u_max (V)
    #                (the board's output; the coils get u + d)
    d: np.ndarray  # (N, 2) input perturbation (V)
    ref: np.ndarray  # (N, 8) reference [y, y', y'', y'''] per magnet
    r: np.ndarray  # (N, 2) command (m)
    diag: np.ndarray  # (N, 9) m_hat, R_hat, K_hat, ec1, ec2, e1, e2, adapting, fault
    mass: np.ndarray  # (N,) kg
    schedule: np.ndarray  # (N, 6) true m, I, N1, N2, R1, R2 (model.S*)
    failed: bool
    fail_time: float | None
    wall_time: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def error(self) -> np.ndarray:
        """Tracking error e = true gap - y_m (N, 2) in m."""
        return np.asarray(self.x[:, [0, 2]] - self.ref[:, :2])

    def metrics(self) -> dict[str, Any]:
        from .metrics import tracking_metrics

        return tracking_metrics(self)


def _final_estimates(D: np.ndarray) -> dict[str, float] | None:
    if D.shape[0] == 0 or not np.all(np.isfinite(D[-1, :3])):
        return None
    return {"m_kg": float(D[-1, 0]), "R_ohm": float(D[-1, 1]), "K": float(D[-1, 2])}


def _estimator_args(est: KalmanEstimator | PassThrough, measure_velocity: bool) -> EstimatorArgs:
    if isinstance(est, KalmanEstimator):
        return EstimatorArgs(True, *est.kernel_args())
    mask = np.array([1.0, float(measure_velocity), 1.0, float(measure_velocity), 1.0, 1.0])
    return EstimatorArgs(False, np.zeros(NS), np.eye(NS), mask, np.zeros(NPP), 1e-3, np.zeros(4), np.zeros(6))


def _law_args(ctrl: Controller) -> LawArgs:
    if isinstance(ctrl, PIDController):
        dummy = CK.CEState(*(np.zeros(a.shape) for a in _ce_shapes()))
        return LawArgs(True, CK.CELaw(0, np.zeros(CK.NCP), np.eye(3), np.zeros(3)), dummy, ctrl.cp, ctrl.integ)
    assert isinstance(ctrl, CEController)
    return LawArgs(False, ctrl.law, ctrl.state, np.zeros(CK.NPID), np.zeros(2))


def _ce_shapes() -> tuple[np.ndarray, ...]:
    """Zero arrays of the shapes of a :class:`~.controllers.kernels.CEState`."""
    nth = CK.NTH
    return (np.zeros(nth), np.zeros(nth), np.zeros(nth), np.zeros(nth), np.zeros((nth, nth)), np.zeros((3, CK.NZ)),
            np.zeros((CK.NUH, 2)), np.zeros(2), np.zeros((5, 2)))


def prepare(cfg: Mapping[str, Mapping[str, Any]], duration: float, seed: int | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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


def preroll(pc: Mapping[str, Any], est: KalmanEstimator | PassThrough, x0: np.ndarray, u0: np.ndarray, sg: np.ndarray,
            sb: np.ndarray, window: float, seed: int | None = None) -> Preroll:
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


def _start_law(ccfg: Mapping[str, Any], ctrl: Controller, pre: Preroll) -> None:
    """Start the law from the pre-roll's hover window, by the controller node's own hover fit
    (:meth:`.controllers.sequence.ControlSequence.fit_window`: one start for the graph and the offline loop)."""
    if not ControlSequence(ccfg, ctrl).fit_window(pre.window_z, pre.window_u):
        from .params import ConfigError

        raise ConfigError("the pre-roll's plate rests on its support (the magnets carry less than a quarter of its"
                          " load): the offline loop starts from a hover; check plant_sim's initial gap and mass")


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
    knowledge of it, and widens a non-zero ``controller.max_age`` to (delay + 1) dt
    where it is shorter (the stamp budget that follows from the delay: an on-time
    estimate is up to delay samples old); ``None`` takes ``plant_sim.command_delay``
    and ``controller.command_delay`` from ``cfg``.
    """
    if duration <= 0:
        from .params import ConfigError

        raise ConfigError(f"duration: got {duration!r}, expected a positive number of seconds")
    wall0 = time.perf_counter()
    if delay is not None:
        copy = {g: dict(v) for g, v in cfg.items()}
        copy["plant_sim"]["command_delay"] = int(delay)
        copy["controller"]["command_delay"] = int(delay)
        age = copy["controller"].get("max_age", 0.0)
        if age > 0.0:
            copy["controller"]["max_age"] = max(age, (int(delay) + 1) * copy["controller"]["dt"])
        cfg = copy
    cfg = with_board_limit(cfg)  # the law clips where the board does (its u_max)
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
    _start_law(cfg["controller"], ctrl, pre)
    r, ref = reference_trajectory({**cfg["reference"], "dt": dt}, n, hover_start(pre.gaps))
    x = x0.copy()
    pp = plant_vector(pc)
    X = np.zeros((n, 6))
    U = np.zeros((n, 2))
    D = np.full((n, CK.NDIAG), np.nan)
    plant = PlantArgs(x, pp, pc["L"], pc["l"], dist.schedule, sg, sb, dist.noise, dist.pert, dt, pc["substeps"],
                      pc["gap_min"], pc["gap_max"], pc["u_max"], int(delay), u0.copy())
    k_fail = _closed_loop(_law_args(ctrl), _estimator_args(est, pc["measure_velocity"]), plant, ref,
                          Logs(X, U, D, True))
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
def _batch(law: LawArgs, states: CK.CEState, integ: np.ndarray, plant: PlantArgs, scheds: np.ndarray, ref: np.ndarray,
           start: int, out: np.ndarray) -> None:
    """Run plant b with schedule ``scheds[b]`` and law state ``states`` row b, for every b in parallel.

    ``law`` :class:`LawArgs` (its states unused), ``states`` stacked CEState, ``integ`` (B, 2) PID integrators,
    ``plant`` :class:`PlantArgs` (its x, p, sched are copied per run). ``out`` (B, 7): see :func:`simulate_batch`.
    The records are taken apart before the parallel loop and rebuilt inside it (numba's parallel
    region takes arrays and scalars, not records of arrays).
    """
    B = scheds.shape[0]
    n = ref.shape[0]
    is_pid, mode, cp, Ad, Bd, pid_cp = law.is_pid, law.ce.mode, law.ce.cp, law.ce.Ad, law.ce.Bd, law.pid_cp
    th, v, sc, v0, P, Z, uh, ie, coil = (states.theta, states.v, states.scale, states.v0, states.P, states.Z,
                                         states.uh, states.ie, states.coil)
    x0, p0, L, l, sg, sb, noise, pert = plant.x, plant.p, plant.L, plant.l, plant.sg, plant.sb, plant.noise, plant.pert
    dt, nsub, gap_min, gap_max, u_max, delay, u0 = (plant.dt, plant.nsub, plant.gap_min, plant.gap_max, plant.u_max,
                                                    plant.delay, plant.u0)
    for b in prange(B):
        X = np.zeros((n, 6))
        U = np.zeros((n, 2))
        D = np.zeros((n, CK.NDIAG))
        st = CK.CEState(th[b], v[b], sc[b], v0[b], P[b], Z[b], uh[b], ie[b], coil[b])
        lb = LawArgs(is_pid, CK.CELaw(mode, cp.copy(), Ad, Bd), st, pid_cp, integ[b])
        est = EstimatorArgs(False, np.zeros(NS), np.eye(NS), np.ones(6), p0, dt, np.zeros(4), np.zeros(6))
        pb = PlantArgs(x0.copy(), p0.copy(), L, l, scheds[b], sg, sb, noise, pert, dt, nsub, gap_min, gap_max, u_max,
                       delay, u0)
        kf = _closed_loop(lb, est, pb, ref, Logs(X, U, D, True))
        m = n if kf < 0 else kf
        out[b, 6] = kf
        out[b, :6] = _batch_metrics(X[:m], ref[:m], start)


def simulate_batch(cfg: Mapping[str, Mapping[str, Any]], mass_offsets: np.ndarray, *, controller: str | None = None,
                   duration: float = 100.0) -> np.ndarray:
    """Run ``len(mass_offsets)`` plants (added mass, kg) in parallel (no noise, no estimator).

    Returns (B, 7): rms e1, rms e2, max e1, max e2, rms e1 after 40 s, rms e2 after 40 s (m),
    fail index (-1 = none).
    """
    cfg = with_board_limit(cfg)
    pc = cfg["plant_sim"]
    n = round(duration / pc["dt"])
    t = np.arange(n) * pc["dt"]
    scheds = np.stack([plant_schedule({**pc, "mass_delta": float(dm)}, t) for dm in mass_offsets])
    x0, u0 = initial_state(pc)
    ctrl = make_controller(cfg["controller"], controller)
    sg, sb = sensor_model(pc)
    pre = preroll(pc, make_estimator(cfg["estimator"], "none", pc["measure_velocity"]), x0, u0, sg, sb,
                  cfg["controller"]["hover_window"])
    _start_law(cfg["controller"], ctrl, pre)
    _, ref = reference_trajectory({**cfg["reference"], "dt": pc["dt"]}, n, hover_start(pre.gaps))

    law = _law_args(ctrl)
    B = len(mass_offsets)
    states = CK.CEState(*(np.ascontiguousarray(np.repeat(a[None], B, axis=0)) for a in law.ce_state))
    integ = np.ascontiguousarray(np.repeat(law.pid_integ[None], B, axis=0))
    plant = PlantArgs(x0, plant_vector(pc), pc["L"], pc["l"], scheds[0], sg, sb, np.zeros((n, 6)), np.zeros((n, 2)),
                      pc["dt"], pc["substeps"], pc["gap_min"], pc["gap_max"], pc["u_max"], int(pc["command_delay"]), u0)
    out = np.zeros((B, 7))
    _batch(law, states, integ, plant, scheds, ref, round(40.0 / pc["dt"]), out)
    return out
