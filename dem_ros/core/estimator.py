r"""State estimator: extended Kalman filter on the DEM plant model.

State (10,): ``s = [d1, d1', d2, d2', i1, i2, beta1, beta2, w1, w2]``
(m, m/s, A, m/s^2, V): the plant state of :mod:`dem_ros.core.model` plus

* an acceleration bias per gap, beta_j, that absorbs what the nominal model
  gets wrong in the mechanics (an unknown added mass, load changes);
* a voltage bias per coil, w_j, that absorbs what it gets wrong in the coil
  circuit: the filter does not assume a known R. With the true R_j,
  u_j - R_j i_j = u_j + w_j - R i_j for w_j = (R - R_j) i_j, so a resistance
  error (tolerance, one coil hotter than the other, heating during the run)
  and any voltage offset of the driver are one slowly varying voltage per
  coil, observable through the measured current (one sample of w moves i_j
  by delta_j w T / 2K, about 9 mA per volt at 8 mm, against 1 mA sensor noise).

Why not take R_hat from the adaptive law (``/dem/controller/state``)? That
closes a second loop estimator -> law -> estimator whose gain nobody designed
(the law's R_hat is identified through the estimator's own currents), delays
R_hat by a sample in the graph, and the law's single R cannot describe two
coils. The bias states need no other node and are per coil. Measured effect
(``adaptive``, S1, 100 s, delay 1): true R = 18 ohm, 28 um RMS with the old
8-state filter, see docs/results.md for the figures with this one.

Model (continuous, nominal m, R, K of the ``estimator`` group)::

    s' = f(s, u) + G n,   f = [plant dynamics under u + w, d_j'' += beta_j ; beta' = 0 ; w' = 0]
    n  = per-sample (held) disturbances: acceleration sigma_accel, voltage sigma_voltage,
         bias changes sigma_bias T and sigma_voltage_bias T; Q = G diag(sigma^2) G^T T^2

Discrete step (period T)::

    predict   s <- RK4(f, s, u_{k-1}, T)
              F  = I + A T + (A T)^2 / 2,     A = df/ds (central differences)
              Pk = F P F^T + Q
    update    y  = z - H s                    (innovation)
              S  = H P H^T + Rm
              Kg = P H^T S^-1
              s <- s + Kg y ;  P <- (I - Kg H) P (I - Kg H)^T + Kg Rm Kg^T   (Joseph form)

``H`` picks the gaps and currents, and the gap rates when the sensors deliver
them. Innovation, gain and covariance are kept for inspection.

Plausibility gates (:class:`KalmanEstimator`; the ``gate`` array of :func:`ekf_step`). Before the
update each gap sensor j (state index i = 0, 2) is tested twice:

* range: its reading must lie inside the sensor's physical range, ``gap_range_min < z_i < gap_range_max``
  (a dead, saturated or disconnected sensor reads outside it; a NaN fails too);
* innovation: the normalised innovation squared of that gap alone,
  NIS_j = y_i^2 / S_ii with S_ii = P_ii + sigma_gap^2 (after the prediction), is chi^2 with one degree of
  freedom when the filter is consistent; the sample is rejected when NIS_j > chi2.isf(p_fa, 1)
  (``gate_false_alarm`` = p_fa: the probability of rejecting a good sample; 1e-5: 4.4 sigma).

A rejected sensor's gap and rate are left out of this update (the prediction holds for them; the other
sensor and the currents still update), counted per reason, and after ``fault_samples`` rejections in a
row the sensor is declared faulty (latched until :meth:`KalmanEstimator.reset`). While a sensor is
rejected P_ii grows with every prediction, so the gate widens by itself: a true jump of the plate is
accepted again after a few samples, a dead one is not. A sensor stuck at a plausible value passes both
gates: the acceleration bias beta_j absorbs the difference between it and the model (3 mm of travel
needs ~8 m/s^2). So beta_j is a third check: beyond ``bias_max`` (default 5 m/s^2, an unknown load of
+50 % of the module's mass) for ``fault_samples`` samples in a row, the measurements of gap j and the
model disagree beyond any load the plate can carry: declared as a fault of gap j (latched) as well.
A sensor stuck while the plate holds still is not detectable at all (and harmless until it moves).

The support (``support_gap`` = d_s, default the board's ``landing_gap``; hovering references lie below it).
A plate whose magnets carry less than its load falls away from the rail until its support stops it; the
model alone predicts the fall (~14.7 m/s^2 at 0 A) and, with the support missing, the acceleration bias
absorbed the support's reaction (beyond ``bias_max``: a false fault) or the gates rejected every reading
(the estimate fell through the support). So the prediction has a hard stop. Gap j is *on its support* in a
sample when its estimate is at or beyond d_s and the free prediction d_j^- moves it further away from the rail::

    contact_j  <=>  d_j >= d_s  and  d_j^- > d_j      (d_j: the estimate before the prediction)

i.e. at the support the model's motion (magnet force, load, beta_j, rate) points away from the rail: the
magnets carry less than the load at that load point and the support carries the rest. Then the
support holds the plate: d_j^- = d_j, d_j'^- = 0 (rows d_j, d_j' of F become [e_j; 0]), with no process noise on
d_j' nor on beta_j: the contact force, not a bias, explains the missing fall, and beta_j is 0 (it cannot be
observed there; a bias left from the landing's transient held the estimate on the support after the plate had left
it, and the controller's next lift-off started blind to its speed: docs/manual/estimator.md). As soon as the
magnets carry the load (lift-off) the free prediction moves the gap toward the rail and the model is the flying one
again. Where the sensor puts the support is measured, not assumed: a gap on its support whose reading the
innovation gate rejects, the last ``SUPPORT_REINIT`` rejected readings in a row steady (each within 2 sqrt(chi2)
sigma_gap of the first), is re-initialised from the reading (d_j = z_j, d_j' = 0, their covariance rows cleared,
P_jj = sigma_gap^2; counted, no fault): a plate that dropped onto its support, or a support a little off d_s. Off
the support a steady rejected reading is never taken over (a stuck sensor on a moving plate must latch its fault).

Numerical guard: the update is skipped (counted) when S is not finite or singular, and a state or
covariance that became non-finite (a gap near zero makes the model singular: delta^-2 terms) is
re-initialised from the measurement, so the filter never raises; both end the convergence run below.

Convergence (:attr:`KalmanEstimator.converged`): a node publishes no estimate of a (re)started filter
until it has converged (see docs/manual/topics.md). The filter starts at the measurement (:meth:`reset`),
which has passed only the range gate: an in-range spike would start it millimetres off, and the innovation
gate would then reject the true samples after it. So the start must be *confirmed*: the sample after it
must pass both gates on every gap (:attr:`KalmanEstimator.confirmed`). When it does not, the start is
taken to be the outlier (or this sample is) and the filter starts again from this sample, to be confirmed
by the next (counted ``unconfirmed_starts``): a spike as the first sample costs one sample more, never a
filter stuck at the spike. What has to converge beyond that is what was not measured:

* every published state measured (gaps, gap rates and currents, ``measure_velocity``): the start *is* the
  measurement, as good as any later estimate, and counts as converged once confirmed (two samples: the
  start and the next, 1 ms later; 2 ms after a spike start; every later sample passes the innovation gate
  or is held as usual). Measured on S1 with sensor noise (sigma 10 um, 1 mm/s, 1 mA), filters restarted
  at t = 2, 5, 9 s: the first estimate's rate error was 0.5-1.3 mm/s and its gap error 8-24 um, the errors
  of the running filter (0.1-1.2 mm/s, 1-9 um);
* gap rates not measured (hardware): a rate starts at 0 (P = (1 mm/s)^2) and is built from the gaps; on
  the same runs its error rose to 2.6-4.7 mm/s at 5-10 samples and was back at the running filter's
  (about 1 mm/s) by 20. It counts as converged once ``converge_samples`` (default 30: 30 ms, inside the
  board's ``hold_timeout`` of 50 ms) consecutive samples passed both gates on every gap without a guard
  event (the start counts as the first: a confirmed start is two).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

from .model import IK, IP, IQ, dynamics, plant_vector
from .params import SCHEMA

__all__ = ["GATE_SIZE", "Estimator", "KalmanEstimator", "PassThrough", "make_estimator"]

NS = 10

# the ``gate`` array of ekf_step (float64): settings, then counters the kernel updates in place
G_CHI2 = 0  # NIS threshold chi2.isf(p_fa, 1)
G_LO = 1  # gap sensor range (m): a reading must lie strictly inside (G_LO, G_HI)
G_HI = 2
G_NFAULT = 3  # rejections in a row that declare a sensor fault
G_W0 = 4  # initial variance of the voltage biases (V^2), for a re-initialisation
G_RUN = 5  # (2) rejections in a row, per gap sensor
G_RANGE = 7  # (2) rejected: outside the range or non-finite, per sensor
G_INNOV = 9  # (2) rejected: NIS above the threshold, per sensor
G_FAULT = 11  # (2) 1.0 once the sensor is declared faulty (latched)
G_NIS = 13  # (2) the newest NIS per sensor (NaN when not tested)
G_GOOD = 15  # samples in a row with every gap accepted and no guard event
G_SKIPPED = 16  # updates skipped: S not finite or singular
G_REINIT = 17  # state or covariance non-finite: re-initialised from the measurement
G_BMAX = 18  # |beta_j| above this (m/s^2) ...
G_BRUN = 19  # (2) ... samples in a row, per gap
G_BFAULT = 21  # (2) 1.0 once beta_j stayed beyond G_BMAX for G_NFAULT samples (latched)
G_SUPPORT = 23  # support gap (m): the hard stop of the prediction; 0: none
G_CONTACT = 24  # (2) 1.0 while gap j rests on its support (this sample's prediction)
G_ZREF = 26  # (2) the first of the latest run of steady rejected readings, per gap
G_ZRUN = 28  # (2) rejected readings in a row within the steadiness bound of G_ZREF
G_SREINIT = 30  # (2) re-initialisations at the support from a steady rejected reading, per gap
GATE_SIZE = 32
SUPPORT_REINIT = 3  # rejected, steady readings in a row that re-initialise a gap resting on its support
_GAPS = (0, 2)  # state indices of the gaps; each sensor's rate follows its gap


@njit(cache=True)
def _f(s: np.ndarray, u: np.ndarray, p: np.ndarray, ds: np.ndarray) -> None:
    dx = np.empty(6)
    ue = np.empty(2)
    ue[0] = u[0] + s[8]
    ue[1] = u[1] + s[9]
    dynamics(s[:6], ue, p, dx)
    ds[:6] = dx
    ds[1] += s[6]
    ds[3] += s[7]
    for j in range(6, NS):
        ds[j] = 0.0


@njit(cache=True)
def _rk4(s: np.ndarray, u: np.ndarray, p: np.ndarray, T: float) -> None:
    k1 = np.empty(NS)
    k2 = np.empty(NS)
    k3 = np.empty(NS)
    k4 = np.empty(NS)
    _f(s, u, p, k1)
    _f(s + 0.5 * T * k1, u, p, k2)
    _f(s + 0.5 * T * k2, u, p, k3)
    _f(s + T * k3, u, p, k4)
    s += T / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@njit(cache=True)
def jacobian(s: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """A = df/ds by central differences, step scaled to each state."""
    A = np.empty((NS, NS))
    fp = np.empty(NS)
    fm = np.empty(NS)
    for j in range(NS):
        h = 1e-6 * max(abs(s[j]), 1e-3)
        sp = s.copy()
        sm = s.copy()
        sp[j] += h
        sm[j] -= h
        _f(sp, u, p, fp)
        _f(sm, u, p, fm)
        for i in range(NS):
            A[i, j] = (fp[i] - fm[i]) / (2.0 * h)
    return A


@njit(cache=True)
def _init_cov(P: np.ndarray, rm: np.ndarray, w0: float) -> None:
    """P of a (re)start: the measurement variances on [d, d', i], 1 (m/s^2)^2 on beta, ``w0`` V^2 on w."""
    P[:, :] = 0.0
    for i in range(6):
        P[i, i] = rm[i]
    P[1, 1] = max(rm[1], 1e-6)
    P[3, 3] = max(rm[3], 1e-6)
    P[6, 6] = P[7, 7] = 1.0
    P[8, 8] = P[9, 9] = w0


@njit(cache=True)
def _gate(s: np.ndarray, P: np.ndarray, z: np.ndarray, use: np.ndarray, rm: np.ndarray, gate: np.ndarray) -> bool:
    """Range and chi^2 gates of the module docstring on each gap sensor; clears ``use`` of a rejected
    sensor's gap and rate and counts. True when every gap was accepted."""
    good = True
    for j in range(2):
        i = _GAPS[j]
        zi = z[i]
        reason = 0
        gate[G_NIS + j] = np.nan
        if not (gate[G_LO] < zi < gate[G_HI]):  # NaN fails too
            reason = G_RANGE
        else:
            y = zi - s[i]
            nis = y * y / (P[i, i] + rm[i])
            gate[G_NIS + j] = nis
            if not nis <= gate[G_CHI2]:
                reason = G_INNOV
        if reason:
            good = False
            use[i] = 0.0
            use[i + 1] = 0.0
            gate[reason + j] += 1.0
            gate[G_RUN + j] += 1.0
            if gate[G_RUN + j] > 1.0 and abs(zi - gate[G_ZREF + j]) <= 2.0 * np.sqrt(gate[G_CHI2] * rm[i]):
                gate[G_ZRUN + j] += 1.0  # steady: within the spread of two good readings (NaN: not steady)
            else:
                gate[G_ZREF + j] = zi
                gate[G_ZRUN + j] = 1.0
            if reason == G_INNOV and gate[G_CONTACT + j] > 0.0 and gate[G_ZRUN + j] >= SUPPORT_REINIT:
                # resting on the support, the reading steady: the support is where the sensor says
                s[i] = zi
                s[i + 1] = 0.0
                P[i, :] = 0.0
                P[:, i] = 0.0
                P[i + 1, :] = 0.0
                P[:, i + 1] = 0.0
                P[i, i] = rm[i]
                gate[G_SREINIT + j] += 1.0
                gate[G_RUN + j] = 0.0
                continue
            if gate[G_RUN + j] >= gate[G_NFAULT]:
                gate[G_FAULT + j] = 1.0
        else:
            gate[G_RUN + j] = 0.0
    return good


@njit(cache=True)
def _finite(a: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(a)))


@njit(cache=True)
def ekf_step(s: np.ndarray, P: np.ndarray, z: np.ndarray, mask: np.ndarray, u_prev: np.ndarray, p: np.ndarray,
             T: float, qc: np.ndarray, rm: np.ndarray, out: np.ndarray, gate: np.ndarray | None = None) -> None:
    """One predict + update. ``z`` (6,) measured [d1, d1', d2, d2', i1, i2]; ``mask`` (6,) 1 = measured.

    ``qc`` = (sigma_accel^2, sigma_voltage^2, sigma_bias^2, sigma_voltage_bias^2), ``rm`` (6,) measurement variances.
    Writes the estimate [d1, d1', d2, d2', i1, i2] into ``out``. ``gate`` (GATE_SIZE,): the plausibility
    gates and the numerical guard of the module docstring (settings and counters, updated in place);
    None: every finite measurement is used (a non-finite S skips the update all the same).
    """
    A = jacobian(s, u_prev, p)
    prior = s.copy()
    _rk4(s, u_prev, p, T)
    AT = A * T
    F = np.eye(NS) + AT + 0.5 * (AT @ AT)
    # process noise: acceleration on d', voltage through delta/(2K) on i', random walk on beta
    # per-sample (zero-order-hold) disturbances of standard deviation sigma: a held
    # acceleration a changes the rate by a T, a held voltage v the current by (delta/2K) v T,
    # and the bias walks by sigma_bias T per sample
    Q = np.zeros((NS, NS))
    T2 = T * T
    Q[1, 1] = qc[0] * T2
    Q[3, 3] = qc[0] * T2
    de1 = p[IP] * s[0] + p[IQ] * s[2]
    de2 = p[IQ] * s[0] + p[IP] * s[2]
    Q[4, 4] = qc[1] * (de1 / (2.0 * p[IK])) ** 2 * T2
    Q[5, 5] = qc[1] * (de2 / (2.0 * p[IK])) ** 2 * T2
    Q[6, 6] = qc[2] * T2
    Q[7, 7] = qc[2] * T2
    Q[8, 8] = qc[3] * T2
    Q[9, 9] = qc[3] * T2
    if gate is not None and gate[G_SUPPORT] > 0.0:
        for j in range(2):  # the support: a hard stop (module docstring)
            i = _GAPS[j]
            contact = prior[i] >= gate[G_SUPPORT] and s[i] > prior[i]
            gate[G_CONTACT + j] = 1.0 if contact else 0.0
            if contact:
                s[i] = prior[i]
                s[i + 1] = 0.0
                F[i, :] = 0.0
                F[i, i] = 1.0
                F[i + 1, :] = 0.0
                Q[i + 1, i + 1] = 0.0
                Q[6 + j, 6 + j] = 0.0
                s[6 + j] = 0.0  # no bias on a gap its support carries (module docstring)
    P[:, :] = F @ P @ F.T + Q
    use = mask.copy()
    good = True
    if gate is not None:
        good = _gate(s, P, z, use, rm, gate)
    nm = 0
    for i in range(6):
        if use[i] > 0.0 and np.isfinite(z[i]):
            nm += 1
    if nm > 0:
        H = np.zeros((nm, NS))
        y = np.empty(nm)
        Rm = np.zeros((nm, nm))
        r = 0
        for i in range(6):
            if use[i] > 0.0 and np.isfinite(z[i]):
                H[r, i] = 1.0
                y[r] = z[i] - s[i]
                Rm[r, r] = rm[i]
                r += 1
        S = H @ P @ H.T + Rm
        HP = H @ P
        solved = _finite(S) and _finite(HP)
        Kt = HP
        if solved:
            try:
                Kt = np.linalg.solve(S, HP)  # Kg^T = S^-1 H P (S symmetric)
            except Exception:  # singular S: no update this sample
                solved = False
        if solved:
            Kg = np.ascontiguousarray(Kt.T)
            s += Kg @ y
            IKH = np.eye(NS) - Kg @ H
            P[:, :] = IKH @ P @ IKH.T + Kg @ Rm @ Kg.T
        else:
            good = False
            if gate is not None:
                gate[G_SKIPPED] += 1.0
    if gate is not None and not (_finite(s) and _finite(P)):
        # re-initialise from what was measured and passed the gates (the rest NaN: nothing to trust)
        for i in range(6):
            s[i] = z[i] if use[i] > 0.0 and np.isfinite(z[i]) else (0.0 if (i == 1 or i == 3) else np.nan)
        s[6:] = 0.0
        _init_cov(P, rm, gate[G_W0])
        gate[G_REINIT] += 1.0
        good = False
    if gate is not None:
        for j in range(2):
            if abs(s[6 + j]) > gate[G_BMAX]:
                gate[G_BRUN + j] += 1.0
                if gate[G_BRUN + j] >= gate[G_NFAULT]:
                    gate[G_BFAULT + j] = 1.0
            else:
                gate[G_BRUN + j] = 0.0
        gate[G_GOOD] = gate[G_GOOD] + 1.0 if good else 0.0
    for i in range(6):
        out[i] = s[i]


class KalmanEstimator:
    """EKF of the module docstring; ``step(z, u_prev) -> x_hat`` (6,), with the plausibility gates.

    Attributes kept for inspection: ``s`` (10,) state, ``P`` (10, 10) covariance, ``gate``
    (GATE_SIZE,) gate settings and counters (read them through :meth:`counters`).
    """

    name = "kf"

    def __init__(self, cfg: Mapping[str, Any], measure_velocity: bool = True):
        self.mask = np.array([1.0, float(measure_velocity), 1.0, float(measure_velocity), 1.0, 1.0])
        self.s = np.zeros(NS)
        self.P = np.eye(NS)
        self.out = np.zeros(6)
        self.gate = np.zeros(GATE_SIZE)
        self.started = False
        self.confirmed = False  # the sample after the (re)start passed both gates (module docstring)
        self.unconfirmed_starts = 0  # starts the next sample did not confirm (the filter started again from it)
        self.configure(cfg)

    def configure(self, cfg: Mapping[str, Any]) -> None:
        """Take new settings (noise levels, model, gates) without restarting: state and covariance stay."""
        from scipy.stats import chi2

        self.cfg = SCHEMA.validate_group("estimator", dict(cfg))
        c = self.cfg
        self.p = plant_vector(c)
        self.T = float(c["dt"])
        self.qc = np.array([c["sigma_accel"] ** 2, c["sigma_voltage"] ** 2, c["sigma_bias"] ** 2,
                            c["sigma_voltage_bias"] ** 2])
        self.rm = np.array([c["sigma_gap"], c["sigma_rate"], c["sigma_gap"], c["sigma_rate"],
                            c["sigma_current"], c["sigma_current"]]) ** 2
        g = self.gate
        g[G_CHI2] = chi2.isf(c["gate_false_alarm"], 1)
        g[G_LO], g[G_HI] = c["gap_range_min"], c["gap_range_max"]
        g[G_NFAULT] = c["fault_samples"]
        g[G_W0] = c["voltage_bias_prior"] ** 2
        g[G_BMAX] = c["bias_max"]
        g[G_SUPPORT] = c["support_gap"]

    @property
    def chi2_threshold(self) -> float:
        """The NIS above which a gap sample is rejected: chi2.isf(gate_false_alarm, 1)."""
        return float(self.gate[G_CHI2])

    def reset(self, z0: np.ndarray) -> None:
        """(Re)start at measurement ``z0`` (velocities 0 when not measured, no bias); clears the sensor
        faults and the convergence run. A gap outside the sensor range cannot start the filter: see :meth:`step`."""
        z0 = np.asarray(z0, float)
        self.s[:6] = np.where(self.mask > 0, z0, 0.0)
        self.s[6:] = 0.0
        _init_cov(self.P, self.rm, self.gate[G_W0])
        self.out[:] = self.s[:6]
        g = self.gate
        g[G_RUN:G_RUN + 2] = 0.0
        g[G_FAULT:G_FAULT + 2] = 0.0
        g[G_BRUN:G_BRUN + 2] = 0.0
        g[G_BFAULT:G_BFAULT + 2] = 0.0
        g[G_CONTACT:G_CONTACT + 2] = 0.0
        g[G_GOOD] = 1.0  # the start sample itself passed the range gate (the next one must confirm it)
        self.started = True
        self.confirmed = False

    def _startable(self, z: np.ndarray) -> bool:
        g = self.gate
        return all(g[G_LO] < z[i] < g[G_HI] for i in _GAPS) and bool(np.all(np.isfinite(z[self.mask > 0])))

    def step(self, z: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """Estimate for this sample from measurement ``z`` (6,) [m, m/s, m, m/s, A, A] and the voltage
        ``u_prev`` (2,) [V] applied since the last one. Before the first plausible measurement (both gaps
        in range, every measured value finite) the output is NaN."""
        z = np.asarray(z, float)
        if not self.started:
            if self._startable(z):
                self.reset(z)
            else:
                self.out[:] = np.nan
                self.gate[G_RANGE] += 1.0
            return self.out
        ekf_step(self.s, self.P, z, self.mask, np.asarray(u_prev, float), self.p, self.T, self.qc, self.rm,
                 self.out, self.gate)
        if not self.confirmed:
            if self.gate[G_GOOD] >= 2.0:  # the start, and this sample passing both gates on every gap
                self.confirmed = True
            elif self._startable(z):
                # not confirmed: the start was an outlier (an in-range spike), or this sample is; start again
                # from this one, to be confirmed by the next (never a filter stuck at a spike)
                self.unconfirmed_starts += 1
                self.reset(z)
        return self.out

    @property
    def converged(self) -> bool:
        """Started on a measurement of every published state and the start confirmed by the next sample (2
        samples), or ``converge_samples`` samples in a row passed both gates on every gap with no guard event
        (module docstring)."""
        need = 2 if self.mask.all() else self.cfg["converge_samples"]
        return self.started and self.confirmed and self.gate[G_GOOD] >= need

    @property
    def faulty(self) -> bool:
        """A sensor fault is latched (cheap: for the 1 kHz path; :attr:`faults` says why)."""
        g = self.gate
        return bool(g[G_FAULT] or g[G_FAULT + 1] or g[G_BFAULT] or g[G_BFAULT + 1])

    @property
    def faults(self) -> list[str]:
        """Why each faulty gap sensor was declared faulty (latched), e.g. ``"gap sensor 1: 20 rejections in a row"``."""
        g = self.gate
        out = [f"gap sensor {j + 1}: {int(g[G_NFAULT])} rejections in a row (outside the range"
               f" {g[G_LO]:g}..{g[G_HI]:g} m: {int(g[G_RANGE + j])}, innovation: {int(g[G_INNOV + j])} so far)"
               for j in range(2) if g[G_FAULT + j] > 0]
        out += [f"gap sensor {j + 1} or the load: acceleration bias {self.s[6 + j]:.2f} m/s^2 beyond bias_max"
                f" {g[G_BMAX]:g} m/s^2 for {int(g[G_NFAULT])} samples"
                " (a stuck sensor, or a load the model cannot carry)"
                for j in range(2) if g[G_BFAULT + j] > 0]
        return out

    def counters(self) -> dict[str, int]:
        """Gate and guard counts since construction: rejected per sensor and reason, guard events."""
        g = self.gate
        out = {}
        for j in range(2):
            out[f"gap{j + 1}_out_of_range"] = int(g[G_RANGE + j])
            out[f"gap{j + 1}_innovation"] = int(g[G_INNOV + j])
            out[f"gap{j + 1}_support_reinit"] = int(g[G_SREINIT + j])
        out["updates_skipped"] = int(g[G_SKIPPED])
        out["reinitialised"] = int(g[G_REINIT])
        out["unconfirmed_starts"] = self.unconfirmed_starts
        return out

    def kernel_args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
        return (self.s, self.P, self.mask, self.p, self.T, self.qc, self.rm)


class PassThrough:
    """No estimator: the controller gets the raw measurement (velocities 0 if not measured)."""

    name = "none"

    def __init__(self, measure_velocity: bool = True):
        self.mask = np.array([1.0, float(measure_velocity), 1.0, float(measure_velocity), 1.0, 1.0])
        self.out = np.zeros(6)

    def reset(self, z0: np.ndarray) -> None:
        self.out[:] = np.where(self.mask > 0, z0, 0.0)

    def step(self, z: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        self.out[:] = np.where(self.mask > 0, z, 0.0)
        return self.out


#: what :func:`make_estimator` makes: ``reset(z0)``, ``step(z, u_prev) -> x_hat`` (6,)
Estimator = KalmanEstimator | PassThrough


def make_estimator(cfg: Mapping[str, Any], kind: str | None = None, measure_velocity: bool = True) -> Estimator:
    kind = kind or cfg["type"]
    if kind == "kf":
        return KalmanEstimator(cfg, measure_velocity)
    if kind == "none":
        return PassThrough(measure_velocity)
    from .params import ConfigError

    raise ConfigError(f"estimator.type: got {kind!r}, expected one of 'kf', 'none'")
