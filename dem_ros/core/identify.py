r"""Grey-box identification of the plant's R1, R2, K and m from a recorded run, with the model's own equations.

Data: samples k = 0..N-1 at t_k of the measured gaps d_j (m), coil currents i_j (A) and the voltages u_j (V)
the board held over (t_{k-1}, t_k] (``/dem/applied_voltage``). Known: the geometry L, l, I, the loads N1, N2
and g (docs/manual/model.md). Unknown: theta = (R1, R2, K, m).

Stage 1: linear least squares on equations that need no differentiated data.

* Coil j (Eq. 9, corrected): u_j = R_j i_j + d/dt(2K i_j/delta_j). Integrated over a window [t_a, t_b]::

      int u_j dt = R_j int i_j dt + 2K (b_j(t_b) - b_j(t_a)),   b_j = i_j / delta_j (flux per turn ~ b_j)

  linear in R_j and K. The voltage integral is exact (u is held over each period); the current integral is
  the trapezoid rule.
* Heave (half the sum of Eqs. 3a, 3b): m (g - a) = K (q1 + q2) - (N1 + N2), a = (d1'' + d2'')/2,
  q_j = b_j^2. Weighted by phi(t) = sin^2(pi (t - t_a)/W), which vanishes with its slope at both ends of its
  window, so int phi a dt = int phi'' dbar dt (dbar = (d1 + d2)/2) by parts twice (a modulating function)::

      K int phi (q1 + q2) dt - m (g int phi dt - int phi'' dbar dt) = (N1 + N2) int phi dt

Each group of equations (coil 1, coil 2, heave) is weighted by the inverse of its residual variance
(two passes). The covariance is sigma^2 (A^T W A)^-1.

Identifiability: the information matrix of the scaled parameters theta / theta_nominal, F = J^T W J. A
parameter whose 95 % interval is wider than ``max_rel_ci`` of its nominal value is *not determined*: no number
is given, the weakest direction of F names the parameters it mixes, and the run's excitation says why
(the relative change of the coil fluxes b_j, the size of the heave accelerations).

Stage 2 (``refine``): :func:`scipy.optimize.least_squares` on the simulation error of the coils: each
flux lambda_j = 2K b_j is simulated from the measured voltages and gaps (exact for the held voltage,
lambda' = u_j - R_j delta_j lambda / 2K, stable: the coil's L/R) and its current i = lambda delta/2K is
compared with the measured one, together with the heave equations of stage 1. The intervals come from the
Jacobian at the optimum, each residual group scaled by its RMS and its integrated autocorrelation time
(correlated residuals carry less information than their count).

Cross-validation: the estimates come from the first ``1 - holdout`` of the run; the rest is simulated with
them (coil currents, heave balance) and the fit is reported.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "PARAMS",
    "Estimate",
    "IdentError",
    "IdentResult",
    "RunData",
    "Validation",
    "coil_rows",
    "flux_noise",
    "heave_rows",
    "identify",
    "simulate_coils",
]

#: the identified parameters, in the order of theta
PARAMS = ("R1", "R2", "K", "m")
UNITS = {"R1": "ohm", "R2": "ohm", "K": "N m^2/A^2", "m": "kg"}
Z95 = 1.959964


class IdentError(ValueError):
    """The data cannot be used (too short, not finite, no current); the message says what."""


@dataclass(frozen=True)
class RunData:
    """A recorded run, one row per sample.

    Attributes:
        t (N,): sample times [s], strictly increasing.
        gap (N, 2): measured gaps d1, d2 [m].
        current (N, 2): measured coil currents i1, i2 [A].
        voltage (N, 2): coil voltages u1, u2 [V] held over (t_{k-1}, t_k] (row 0: before t_0, unused).
    """

    t: np.ndarray
    gap: np.ndarray
    current: np.ndarray
    voltage: np.ndarray

    def __post_init__(self) -> None:
        n = self.t.shape[0]
        for name in ("gap", "current", "voltage"):
            a = getattr(self, name)
            if a.shape != (n, 2):
                raise IdentError(f"{name}: expected shape ({n}, 2), got {a.shape}")
        if n < 2 or not np.all(np.diff(self.t) > 0):
            raise IdentError("the sample times must be at least two and strictly increasing")
        for name in ("t", "gap", "current", "voltage"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise IdentError(f"{name} has non-finite samples")

    def slice(self, a: int, b: int) -> RunData:
        return RunData(self.t[a:b], self.gap[a:b], self.current[a:b], self.voltage[a:b])


@dataclass(frozen=True)
class Estimate:
    """One parameter: its value and 95 % interval, or (``determined`` False) why it cannot be given."""

    name: str
    unit: str
    determined: bool
    value: float = math.nan
    std: float = math.nan
    ci95: tuple[float, float] = (math.nan, math.nan)
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "unit": self.unit, "determined": self.determined}
        if self.determined:
            d |= {"value": self.value, "std": self.std, "ci95": list(self.ci95)}
        else:
            d["reason"] = self.reason
        return d


@dataclass(frozen=True)
class Validation:
    """The held-out part simulated with the estimates.

    Attributes:
        t_from, t_to: the held-out span [s].
        current_rms (2,): RMS of simulated - measured coil current [A].
        current_fit (2,): 100 (1 - ||i_sim - i|| / ||i - mean i||) [%] (NRMSE fit; meaningless when i is constant).
        current_rel (2,): current_rms / mean |i|.
        heave_rms: RMS of the heave balance's residual [N] (per window, divided by int phi).
    """

    t_from: float
    t_to: float
    current_rms: tuple[float, float]
    current_fit: tuple[float, float]
    current_rel: tuple[float, float]
    heave_rms: float

    def to_dict(self) -> dict[str, Any]:
        return {"t_from_s": self.t_from, "t_to_s": self.t_to, "current_rms_A": list(self.current_rms),
                "current_fit_pct": list(self.current_fit), "current_rel": list(self.current_rel),
                "heave_rms_N": self.heave_rms}


@dataclass
class IdentResult:
    """Estimates, their excitation measures, the cross-validation and the stage-1 / stage-2 details."""

    estimates: dict[str, Estimate]
    excitation: dict[str, float]
    condition: float  # of the scaled information matrix
    weak_direction: dict[str, float]  # unit eigenvector of its smallest eigenvalue, per parameter
    validation: Validation | None
    refined: bool
    samples: int
    duration_s: float
    notes: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return all(e.determined for e in self.estimates.values())

    def values(self) -> dict[str, float]:
        return {k: e.value for k, e in self.estimates.items() if e.determined}

    def to_dict(self) -> dict[str, Any]:
        return {"estimates": {k: e.to_dict() for k, e in self.estimates.items()}, "complete": self.complete,
                "excitation": self.excitation, "condition": self.condition, "weak_direction": self.weak_direction,
                "validation": self.validation.to_dict() if self.validation else None, "refined": self.refined,
                "samples": self.samples, "duration_s": self.duration_s, "notes": list(self.notes)}


# -- the equations ---------------------------------------------------------------------------------------------
def _deltas(gap: np.ndarray, geo: Mapping[str, float]) -> np.ndarray:
    """delta_j = P d_j + Q d_other (Eq. 6), shape (N, 2) [m]."""
    P = (geo["L"] + geo["l"]) / (2 * geo["L"])
    Q = (geo["L"] - geo["l"]) / (2 * geo["L"])
    return np.stack([P * gap[:, 0] + Q * gap[:, 1], Q * gap[:, 0] + P * gap[:, 1]], axis=1)


def _windows(n: int, w: int) -> np.ndarray:
    """Start indices of non-overlapping windows of w intervals inside n samples."""
    return np.arange(0, n - w, w)


def coil_rows(d: RunData, geo: Mapping[str, float], window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The integrated coil equations, both coils: A (2 M, 4) over theta = (R1, R2, K, m), b (2 M,) [V s], and
    the variance of each regressor's noise (2 M, 4) (the K column: 2 (b(t_b) - b(t_a)) with b's white noise).

    Rows 0..M-1 are coil 1, M..2M-1 coil 2; ``window``: samples per window.
    """
    dt = np.diff(d.t)
    b = d.current / _deltas(d.gap, geo)
    iu = np.concatenate([[[0.0, 0.0]], np.cumsum(d.voltage[1:] * dt[:, None], axis=0)])
    ii = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (d.current[1:] + d.current[:-1]) * dt[:, None], axis=0)])
    k0 = _windows(d.t.size, window)
    k1 = k0 + window
    M = k0.size
    A = np.zeros((2 * M, 4))
    rhs = np.zeros(2 * M)
    noise = np.zeros((2 * M, 4))
    sb2 = flux_noise(d, geo)
    for j in (0, 1):
        rows = slice(j * M, (j + 1) * M)
        A[rows, j] = ii[k1, j] - ii[k0, j]
        A[rows, 2] = 2.0 * (b[k1, j] - b[k0, j])
        rhs[rows] = iu[k1, j] - iu[k0, j]
        noise[rows, 2] = 8.0 * sb2[j]  # (2 (n_b - n_a))^2, n white
    return A, rhs, noise


def heave_rows(d: RunData, geo: Mapping[str, float], window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The heave balance under the modulating function phi: A (M, 4), b (M,) [N s], and int phi dt (M,) [s]."""
    de = _deltas(d.gap, geo)
    q = (d.current / de) ** 2
    qs = q[:, 0] + q[:, 1]
    dbar = 0.5 * (d.gap[:, 0] + d.gap[:, 1])
    k0 = _windows(d.t.size, window)
    M = k0.size
    A = np.zeros((M, 4))
    rhs = np.zeros(M)
    wphi = np.zeros(M)
    for r, a in enumerate(k0):
        t = d.t[a:a + window + 1]
        W = t[-1] - t[0]
        s = (t - t[0]) / W
        phi = np.sin(np.pi * s) ** 2
        phi2 = 2.0 * (np.pi / W) ** 2 * np.cos(2 * np.pi * s)  # phi''
        ip = np.trapezoid(phi, t)
        A[r, 2] = np.trapezoid(phi * qs[a:a + window + 1], t)
        A[r, 3] = -(geo["g"] * ip - np.trapezoid(phi2 * dbar[a:a + window + 1], t))
        rhs[r] = (geo["N1"] + geo["N2"]) * ip
        wphi[r] = ip
    return A, rhs, wphi


@njit(cache=True)
def _coil_sim(t: np.ndarray, delta: np.ndarray, u: np.ndarray, i0: float, R: float, K: float) -> np.ndarray:
    """Current of one coil simulated from its held voltages and measured gaps (see :func:`simulate_coils`)."""
    n = t.shape[0]
    out = np.empty(n)
    lam = 2.0 * K * i0 / delta[0]
    out[0] = i0
    for k in range(1, n):
        h = t[k] - t[k - 1]
        a = R * 0.5 * (delta[k] + delta[k - 1]) / (2.0 * K)
        e = math.exp(-a * h)
        lam = e * lam + (1.0 - e) * u[k] / a
        out[k] = lam * delta[k] / (2.0 * K)
    return out


def simulate_coils(d: RunData, geo: Mapping[str, float], R1: float, R2: float, K: float) -> np.ndarray:
    """Coil currents (N, 2) [A] simulated from the held voltages and the measured gaps, from the measured i(t_0).

    The flux linkage lambda = 2K i/delta obeys lambda' = u - R delta lambda/(2K): integrated exactly over each
    period with u held and delta at the period's mean.
    """
    de = np.ascontiguousarray(_deltas(d.gap, geo))
    t = np.ascontiguousarray(d.t, dtype=float)
    return np.stack([_coil_sim(t, np.ascontiguousarray(de[:, j]), np.ascontiguousarray(d.voltage[:, j], dtype=float),
                               float(d.current[0, j]), R, K) for j, R in ((0, R1), (1, R2))], axis=1)


# -- estimation ---------------------------------------------------------------------------------------------------
def _wls(A: np.ndarray, b: np.ndarray, groups: Sequence[slice], scale: np.ndarray,
         noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group-weighted least squares in scaled parameters: (theta, its covariance, the weighted scaled Jacobian).

    ``noise`` (same shape as A): variances of the regressors' own noise (errors in variables); their
    weighted sum is taken off the normal matrix (bias-compensated least squares), so a noisy regressor does
    not pull its parameter towards zero.
    """
    As = A * scale
    Ns = np.zeros_like(A) if noise is None else noise * scale ** 2
    w = np.ones(b.size)
    theta_s = np.zeros(A.shape[1])
    for _ in range(3):  # weights from the residuals of the previous pass
        Aw, bw = As * w[:, None], b * w
        Nm = Aw.T @ Aw - np.diag((Ns * w[:, None] ** 2).sum(axis=0))
        theta_s = np.linalg.pinv(Nm) @ (Aw.T @ bw)
        r = As @ theta_s - b
        for g in groups:
            s = float(np.sqrt(np.mean(r[g] ** 2))) if r[g].size else 1.0
            w[g] = 1.0 / max(s, 1e-300)
    Aw = As * w[:, None]
    dof = max(b.size - A.shape[1], 1)
    s2 = float(np.sum(((As @ theta_s - b) * w) ** 2) / dof)
    Nm = Aw.T @ Aw - np.diag((Ns * w[:, None] ** 2).sum(axis=0))
    cov_s = s2 * np.linalg.pinv(Nm)
    return theta_s * scale, cov_s * np.outer(scale, scale), Aw * math.sqrt(1.0 / s2)


def _lsb(x: np.ndarray) -> float:
    """The smallest step between samples of a quantised signal (its ADC's LSB); ~0 for an unquantised one."""
    d = np.abs(np.diff(x))
    d = d[d > 1e-12 * max(float(np.max(np.abs(x))), 1e-300)]
    return float(d.min()) if d.size else 0.0


def flux_noise(d: RunData, geo: Mapping[str, float]) -> np.ndarray:
    """Variance of the noise on b_j = i_j/delta_j, (2,) [(A/m)^2]: the larger of the white part (var of the
    second differences / 6: white noise of variance s^2 has second differences of variance 6 s^2, a smooth
    signal almost none) and the ADCs' quantisation, LSB^2/12 of the current and of the gap carried through
    b = i/delta. Quantisation of a slowly moving signal is not white (the second differences miss most of it)
    and, fed back through the controller, correlates with the voltages: it must count in full."""
    de = _deltas(d.gap, geo)
    b = d.current / de
    white = np.var(np.diff(b, 2, axis=0), axis=0) / 6.0
    out = np.empty(2)
    for j in (0, 1):
        qi, qd = _lsb(d.current[:, j]), max(_lsb(d.gap[:, 0]), _lsb(d.gap[:, 1]))
        db = float(np.mean(np.abs(de[:, j])))
        quant = (qi ** 2 / 12.0) / db ** 2 + (float(np.mean(np.abs(b[:, j]))) / db) ** 2 * qd ** 2 / 12.0
        out[j] = max(float(white[j]), quant)
    return out


def _tau(r: np.ndarray, max_lag: int = 1000) -> float:
    """Integrated autocorrelation time (samples) of a residual series, >= 1: sum of its autocorrelation up to
    the first lag where it drops below zero."""
    r = r - r.mean()
    v = float(r @ r)
    if v <= 0 or r.size < 4:
        return 1.0
    n = r.size
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: min(max_lag, n - 1)] / v
    neg = np.nonzero(ac < 0)[0]
    end = int(neg[0]) if neg.size else ac.size
    return max(1.0, float(1.0 + 2.0 * ac[1:end].sum()))


def _excitation(d: RunData, geo: Mapping[str, float], window: int) -> dict[str, float]:
    b = d.current / _deltas(d.gap, geo)
    k0 = _windows(d.t.size, window)
    db = b[k0 + window] - b[k0]
    dbar = 0.5 * (d.gap[:, 0] + d.gap[:, 1])
    acc = np.diff(dbar, 2) / np.diff(d.t)[1:] ** 2 if d.t.size > 3 else np.zeros(1)
    return {
        "flux_change_rel_1": float(np.sqrt(np.mean(db[:, 0] ** 2)) / max(np.mean(np.abs(b[:, 0])), 1e-300)),
        "flux_change_rel_2": float(np.sqrt(np.mean(db[:, 1] ** 2)) / max(np.mean(np.abs(b[:, 1])), 1e-300)),
        "mean_current_1_A": float(np.mean(d.current[:, 0])),
        "mean_current_2_A": float(np.mean(d.current[:, 1])),
        "heave_accel_rms_m_s2": float(np.sqrt(np.mean(acc ** 2))),
        "gap_span_mm": float((dbar.max() - dbar.min()) * 1e3),
    }


def _why(name: str, weak: dict[str, float], exc: dict[str, float], rel_ci: float) -> str:
    mixed = [k for k, v in weak.items() if abs(v) > 0.2 and k != name]
    flux = max(exc["flux_change_rel_1"], exc["flux_change_rel_2"])
    if name in ("R1", "R2"):
        j = name[1]
        if abs(exc[f"mean_current_{j}_A"]) < 1e-3:
            return f"coil {j} carried no current (mean {exc[f'mean_current_{j}_A']:.2g} A): u = R i has nothing to fit"
    base = f"its 95 % interval would be +-{rel_ci * 100:.3g} % of the nominal value"
    if name == "K":
        return (f"{base}: K enters the coil equation only through changes of the flux i/delta, and the run's fluxes "
                f"barely change (relative change per window {flux:.2g}; hover alone holds them constant, because "
                f"the magnet forces at any equilibrium are the same); the heave balance fixes only K (q1 + q2) - m g"
                + (f" (the weakest direction mixes {', '.join([name, *mixed])})" if mixed else ""))
    if name == "m":
        return (f"{base}: the heave balance m (g - a) = K (q1 + q2) - (N1 + N2) gives m only with K known, and the "
                f"heave accelerations are small (RMS {exc['heave_accel_rms_m_s2']:.2g} m/s^2)"
                + (f"; the weakest direction mixes {', '.join([name, *mixed])}" if mixed else ""))
    return f"{base}" + (f"; the weakest direction mixes {', '.join([name, *mixed])}" if mixed else "")


def _why_flux(name: str, exc: dict[str, float], limit: float) -> str:
    share = exc["flux_noise_share"]
    flux = max(exc["flux_change_rel_1"], exc["flux_change_rel_2"])
    head = ("K enters the coil equation only through changes of the flux i/delta" if name == "K" else
            "m follows from the heave balance m (g - a) = K (q1 + q2) - (N1 + N2) only once K is known, and K")
    tail = "" if name == "K" else " is not determined"
    return (f"{head}{tail}: the run's flux changes are at the sensors' noise level ({share * 100:.3g} % of their "
            f"energy is noise, limit {limit * 100:.3g} %; relative change per window {flux:.2g}). Hover and slow "
            f"references hold the fluxes constant (every equilibrium needs the same magnet forces); record a run "
            f"with faster reference steps (docs/manual/hardware.md, bring-up step 5)")


def identify(d: RunData, geo: Mapping[str, float], nominal: Mapping[str, float], *, coil_window: float = 0.02,
             heave_window: float = 0.2, holdout: float = 0.3, refine: bool = True,
             max_rel_ci: float = 0.1, max_flux_noise: float = 0.4, rel_floor: float = 1e-4) -> IdentResult:
    """Estimate (R1, R2, K, m) from ``d`` (see the module docstring).

    Args:
        geo: L, l, I [m, m, kg m^2], N1, N2 [N], g [m/s^2].
        nominal: R1, R2, K, m: the data sheet's values; they scale the problem and judge the intervals.
        coil_window, heave_window: window lengths [s] of the coil and heave equations.
        holdout: fraction of the run (its end) kept out of the fit and simulated with the estimates.
        refine: stage 2 (simulation error) after the linear stage.
        max_rel_ci: a parameter whose 95 % half-width exceeds this fraction of its nominal value is not determined.
        max_flux_noise: K (and with it m) is not determined when more than this share of the flux changes'
            energy (both coils) is the sensors' noise (the changes are too small to tell K). On the emulated
            rig: 19-31 % in the excitation runs that identify K within 0.4 %, 50-100 % in S1 and hover runs
            (a hover run at 50 % gave K 21 % off with a 5 % interval: closed-loop quantisation noise biases it).
        rel_floor: a relative standard deviation added to each statistical one (in quadrature): what the
            statistics cannot see (the trapezoid rule's error, the ADC's quantisation, unmodelled dynamics).
    Raises:
        IdentError: too few samples for the windows.
    """
    n = d.t.size
    dt = float(np.median(np.diff(d.t)))
    wc, wh = max(2, round(coil_window / dt)), max(4, round(heave_window / dt))
    n_fit = round(n * (1.0 - holdout)) if holdout > 0 else n
    if n_fit < 4 * max(wc, wh) or (holdout > 0 and n - n_fit < 2 * wh):
        raise IdentError(f"{n} samples ({n * dt:.3g} s) are too few: the fit needs at least {4 * max(wc, wh)} samples "
                         f"and the held-out part {2 * wh} (coil window {coil_window:g} s, heave window "
                         f"{heave_window:g} s, holdout {holdout:g})")
    fit = d.slice(0, n_fit)
    scale = np.array([nominal[k] for k in PARAMS], float)
    Ac, bc, Nc = coil_rows(fit, geo, wc)
    Ah, bh, _ = heave_rows(fit, geo, wh)
    A, b = np.vstack([Ac, Ah]), np.concatenate([bc, bh])
    M = Ac.shape[0] // 2
    groups = [slice(0, M), slice(M, 2 * M), slice(2 * M, b.size)]
    theta, cov, J = _wls(A, b, groups, scale, np.vstack([Nc, np.zeros_like(Ah)]))
    exc = _excitation(fit, geo, wc)
    # errors in variables: the share of the K column's energy that is the flux's own noise, per coil
    share = [float(Nc[g, 2].sum() / max(float(np.sum(Ac[g, 2] ** 2)), 1e-300)) for g in groups[:2]]
    exc["flux_noise_share_1"], exc["flux_noise_share_2"] = share
    exc["flux_noise_share"] = float(Nc[:, 2].sum() / max(float(np.sum(Ac[:, 2] ** 2)), 1e-300))  # both coils
    flux_ok = exc["flux_noise_share"] < max_flux_noise
    refined = False
    notes: list[str] = []
    if refine and flux_ok:
        start = np.where(theta > 0, theta, scale)
        theta, cov, J, refined = _refine(fit, geo, start, cov, J, scale, wh, notes)
    F = J.T @ J
    evals, evecs = np.linalg.eigh(F)
    cond = float(evals[-1] / max(evals[0], 1e-300))
    weak = {k: float(v) for k, v in zip(PARAMS, evecs[:, 0] * np.sign(evecs[np.argmax(np.abs(evecs[:, 0])), 0]),
                                        strict=True)}
    std = np.sqrt(np.maximum(np.diag(cov), 0.0) + (rel_floor * theta) ** 2)
    rel = Z95 * std / scale
    est: dict[str, Estimate] = {}
    for i, k in enumerate(PARAMS):
        if k in ("K", "m") and not flux_ok:
            est[k] = Estimate(k, UNITS[k], False, reason=_why_flux(k, exc, max_flux_noise))
        elif rel[i] < max_rel_ci and theta[i] > 0:
            est[k] = Estimate(k, UNITS[k], True, float(theta[i]), float(std[i]),
                              (float(theta[i] - Z95 * std[i]), float(theta[i] + Z95 * std[i])))
        else:
            est[k] = Estimate(k, UNITS[k], False, reason=_why(k, weak, exc, float(rel[i])))
    val = None
    if n_fit < n:
        val = _validate(d, geo, n_fit, theta, wh)
    return IdentResult(est, exc, cond, weak, val, refined, n, float(d.t[-1] - d.t[0]), notes)


def _refine(fit: RunData, geo: Mapping[str, float], theta0: np.ndarray, cov0: np.ndarray, J0: np.ndarray,
            scale: np.ndarray, wh: int, notes: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Stage 2: least squares on the coils' simulation error and the heave equations over all four parameters;
    (theta, covariance, weighted scaled Jacobian, refined) with the covariance from the Jacobian (see the module)."""
    from scipy.optimize import least_squares

    Ah, bh, _ = heave_rows(fit, geo, wh)

    def groups(th: np.ndarray) -> list[np.ndarray]:
        i_sim = simulate_coils(fit, geo, th[0], th[1], th[2])
        e = i_sim - fit.current
        return [e[:, 0], e[:, 1], Ah @ th - bh]

    g0 = groups(theta0)
    w = [1.0 / max(float(np.sqrt(np.mean(g ** 2))), 1e-12) for g in g0]

    def resid(v: np.ndarray, w: list[float]) -> np.ndarray:
        return np.concatenate([g * wi for g, wi in zip(groups(v * scale), w, strict=True)])

    sol = least_squares(resid, theta0 / scale, args=(w,), method="lm")
    gs = groups(sol.x * scale)
    taus = [_tau(g) for g in gs]
    w = [1.0 / (max(float(np.sqrt(np.mean(g ** 2))), 1e-12) * math.sqrt(t)) for g, t in zip(gs, taus, strict=True)]
    sol = least_squares(resid, sol.x, args=(w,), method="lm")
    if not sol.success or not np.all(np.isfinite(sol.x)):
        notes.append(f"refinement did not converge ({sol.message}); stage-1 estimates kept")
        return theta0, cov0, J0, False
    J = sol.jac
    cov = np.linalg.pinv(J.T @ J) * np.outer(scale, scale)
    notes.append("autocorrelation times of the refined residuals (samples): coil 1 {:.3g}, coil 2 {:.3g}, "
                 "heave {:.3g}".format(*taus))
    return sol.x * scale, cov, J, True


def _validate(d: RunData, geo: Mapping[str, float], n_fit: int, theta: np.ndarray, wh: int) -> Validation:
    hold = d.slice(n_fit, d.t.size)
    i_sim = simulate_coils(hold, geo, theta[0], theta[1], theta[2])
    e = i_sim - hold.current
    skip = min(50, hold.t.size // 10)  # the simulation starts from the measured current: its first transient
    e, ic = e[skip:], hold.current[skip:]
    rms = np.sqrt(np.mean(e ** 2, axis=0))
    spread = np.linalg.norm(ic - ic.mean(axis=0), axis=0)
    fitp = 100.0 * (1.0 - np.linalg.norm(e, axis=0) / np.maximum(spread, 1e-300))
    Ah, bh, wphi = heave_rows(hold, geo, wh)
    hr = (Ah @ theta - bh) / wphi
    return Validation(float(hold.t[0]), float(hold.t[-1]), (float(rms[0]), float(rms[1])),
                      (float(fitp[0]), float(fitp[1])),
                      (float(rms[0] / max(abs(ic[:, 0].mean()), 1e-300)),
                       float(rms[1] / max(abs(ic[:, 1].mean()), 1e-300))),
                      float(np.sqrt(np.mean(hr ** 2))))
