r"""Grey-box identification of the plant's R1, R2, K1, K2 (or one K) and m from a recorded run, with the model's
own equations.

Data: samples k = 0..N-1 at t_k of the measured gaps d_j (m), coil currents i_j (A) and the voltages u_j (V)
the board held over (t_{k-1}, t_k] (``/dem/applied_voltage``). Known: the geometry L, l, I, the loads N1, N2
and g (docs/manual/model.md). Unknown: theta = (R1, R2, K1, K2, m): each coil's resistance, each magnet's force
coefficient (F_j = K_j i_j^2/delta_j^2, its coil's flux linkage 2 K_j i_j/delta_j) and the mass.

Stage 1: linear least squares on equations that need no differentiated data.

* Coil j (Eq. 9, corrected): u_j = R_j i_j + d/dt(2 K_j i_j/delta_j). Integrated over a window [t_a, t_b]::

      int u_j dt = R_j int i_j dt + 2 K_j (b_j(t_b) - b_j(t_a)),   b_j = i_j / delta_j (flux per turn ~ b_j)

  linear in its own R_j and K_j: each coil measures its own magnet's K. The voltage integral is exact (u is
  held over each period); the current integral is the trapezoid rule.
* Heave (half the sum of Eqs. 3a, 3b): m (g - a) = K1 q1 + K2 q2 - (N1 + N2), a = (d1'' + d2'')/2,
  q_j = b_j^2. Weighted by phi(t) = sin^2(pi (t - t_a)/W), which vanishes with its slope at both ends of its
  window, so int phi a dt = int phi'' dbar dt (dbar = (d1 + d2)/2) by parts twice (a modulating function)::

      K1 int phi q1 dt + K2 int phi q2 dt - m (g int phi dt - int phi'' dbar dt) = (N1 + N2) int phi dt

* Pitch (half the difference of Eqs. 3a, 3b, times I/(L l)): K1 q1 - K2 q2 = (L/l)(N1 - N2) - (I/(L l)) Delta'',
  Delta = (d1 - d2)/2, modulated the same way. It is not fitted: at any equilibrium it fixes the ratio of the
  magnets' forces, so it *checks* the split the coils measure (the split s = (K1 - K2)/(K1 + K2) it needs
  against the coils'); a disagreement means the loads' moment, a current sensor's gain or the split is off.

Each group of equations (coil 1, coil 2, heave) is weighted by the inverse of its residual variance
(two passes).

One K or two: K1 and K2 are given when each coil's flux changes are above the sensors' noise (each coil's
noise share below ``max_flux_noise``), each interval is narrow enough and the interval of K1 - K2 excludes 0.
Otherwise the fit is repeated with K1 = K2 = K and one K is given, with the reason (the magnets agree within
the intervals, or the run cannot separate them). K is always given when determined: with a split, the mean
(K1 + K2)/2 (what the single-K laws and the board's model take: it centres the board's +-25 % model band on
both magnets).

Intervals: the estimating equations' residuals are correlated in time (the coil simulation's error, the
ADCs' quantisation fed back through the controller), so the covariance is a sandwich H^-1 S H^-1 whose middle
S is the sum over time blocks of ``block`` s of the outer products of the blocks' summed scores (batch means,
heteroskedasticity- and autocorrelation-consistent), with the t quantile of its degrees of freedom.

Identifiability: the information matrix of the scaled parameters theta / theta_nominal, F = J^T W J. A
parameter whose 95 % interval is wider than ``max_rel_ci`` of its nominal value is *not determined*: no number
is given, the weakest direction of F names the parameters it mixes, and the run's excitation says why
(the relative change of the coil fluxes b_j, the size of the heave accelerations).

Stage 2 (``refine``): :func:`scipy.optimize.least_squares` on the simulation error of the coils: each
flux lambda_j = 2 K_j b_j is simulated from the measured voltages and gaps (exact for the held voltage,
lambda' = u_j - R_j delta_j lambda / 2 K_j, stable: the coil's L/R) and its current i = lambda delta/2 K_j is
compared with the measured one, together with the heave equations of stage 1.

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
    "FIT",
    "NAMES",
    "PARAMS",
    "SPLIT",
    "Estimate",
    "IdentError",
    "IdentResult",
    "RunData",
    "Validation",
    "coil_rows",
    "flux_noise",
    "heave_rows",
    "identify",
    "pitch_rows",
    "simulate_coils",
]

#: the fitted parameters, in the order of theta (the columns of the equations' rows)
FIT = ("R1", "R2", "K1", "K2", "m")
#: the parameters every run must give (the project's parameter names): with a split, K is (K1 + K2)/2
PARAMS = ("R1", "R2", "K", "m")
#: each magnet's own K, given when the run separates them
SPLIT = ("K1", "K2")
#: the estimates of a result, in this order
NAMES = ("R1", "R2", "K1", "K2", "K", "m")
UNITS = {"R1": "ohm", "R2": "ohm", "K1": "N m^2/A^2", "K2": "N m^2/A^2", "K": "N m^2/A^2", "m": "kg"}
Z95 = 1.959964
#: theta = T_ONE @ (R1, R2, K, m): the fit with one K
T_ONE = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
ONE = ("R1", "R2", "K", "m")


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
    """One parameter: its value and 95 % interval, or (``determined`` False) why it cannot be given.

    ``dof``: the degrees of freedom of its variance (time blocks that carry its information); the interval is
    value +- t_0.975(dof) std.
    """

    name: str
    unit: str
    determined: bool
    value: float = math.nan
    std: float = math.nan
    ci95: tuple[float, float] = (math.nan, math.nan)
    reason: str = ""
    dof: float = math.inf

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "unit": self.unit, "determined": self.determined}
        if self.determined:
            d |= {"value": self.value, "std": self.std, "ci95": list(self.ci95), "dof": self.dof}
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


@dataclass(frozen=True)
class SplitCheck:
    """Whether the run separates the magnets' K1 and K2, and the moment balance's check of the split.

    Attributes:
        verdict: ``split`` (K1, K2 given), ``one K: agree`` (the interval of K1 - K2 holds 0), ``one K: cannot
            separate`` (a coil's flux changes at noise level, or an interval too wide) or ``not determined``
            (no K at all).
        coils, coils_ci (half-width): the split s = (K1 - K2)/(K1 + K2) of the coil equations (nan: not fitted).
        moment, moment_ci: the split the pitch balance needs with the loads as configured (nan: not formed).
        consistent: the two agree within their intervals (None: not compared).
    """

    verdict: str
    coils: float = math.nan
    coils_ci: float = math.nan
    moment: float = math.nan
    moment_ci: float = math.nan
    consistent: bool | None = None

    @property
    def split(self) -> bool:
        return self.verdict == "split"

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"verdict": self.verdict, "split": self.split, "consistent": self.consistent}
        if math.isfinite(self.coils):
            d |= {"coils": self.coils, "coils_ci95": self.coils_ci}
        if math.isfinite(self.moment):
            d |= {"moment": self.moment, "moment_ci95": self.moment_ci}
        return d


@dataclass
class IdentResult:
    """Estimates, the K split, their excitation measures, the cross-validation and the stage-1 / stage-2 details."""

    estimates: dict[str, Estimate]
    excitation: dict[str, float]
    condition: float  # of the scaled information matrix
    weak_direction: dict[str, float]  # unit eigenvector of its smallest eigenvalue, per fitted parameter
    validation: Validation | None
    refined: bool
    samples: int
    duration_s: float
    notes: list[str] = field(default_factory=list)
    k_split: SplitCheck = field(default_factory=lambda: SplitCheck("not determined"))

    @property
    def complete(self) -> bool:
        """R1, R2, K and m are determined (K1, K2 only when the run separates them)."""
        return all(self.estimates[k].determined for k in PARAMS)

    def values(self) -> dict[str, float]:
        return {k: e.value for k, e in self.estimates.items() if e.determined}

    def to_dict(self) -> dict[str, Any]:
        return {"estimates": {k: e.to_dict() for k, e in self.estimates.items()}, "complete": self.complete,
                "k_split": self.k_split.to_dict(), "excitation": self.excitation, "condition": self.condition,
                "weak_direction": self.weak_direction,
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
    """The integrated coil equations, both coils: A (2 M, 5) over theta = (R1, R2, K1, K2, m), b (2 M,) [V s], and
    the variance of each regressor's noise (2 M, 5) (the K_j column: 2 (b(t_b) - b(t_a)) with b's white noise).

    Rows 0..M-1 are coil 1 (columns R1, K1), M..2M-1 coil 2 (R2, K2); ``window``: samples per window.
    """
    dt = np.diff(d.t)
    b = d.current / _deltas(d.gap, geo)
    iu = np.concatenate([[[0.0, 0.0]], np.cumsum(d.voltage[1:] * dt[:, None], axis=0)])
    ii = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (d.current[1:] + d.current[:-1]) * dt[:, None], axis=0)])
    k0 = _windows(d.t.size, window)
    k1 = k0 + window
    M = k0.size
    A = np.zeros((2 * M, 5))
    rhs = np.zeros(2 * M)
    noise = np.zeros((2 * M, 5))
    sb2 = flux_noise(d, geo)
    for j in (0, 1):
        rows = slice(j * M, (j + 1) * M)
        A[rows, j] = ii[k1, j] - ii[k0, j]
        A[rows, 2 + j] = 2.0 * (b[k1, j] - b[k0, j])
        rhs[rows] = iu[k1, j] - iu[k0, j]
        noise[rows, 2 + j] = 8.0 * sb2[j]  # (2 (n_b - n_a))^2, n white
    return A, rhs, noise


def _modulated(d: RunData, window: int, sig: np.ndarray, low: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per window (M,): int phi sig_c dt for each column c of ``sig`` (M, C), int phi'' low dt, int phi dt, and
    the window's centre time; phi = sin^2(pi (t - t_a)/W)."""
    k0 = _windows(d.t.size, window)
    M = k0.size
    out = np.zeros((M, sig.shape[1]))
    acc, ip, tc = np.zeros(M), np.zeros(M), np.zeros(M)
    for r, a in enumerate(k0):
        t = d.t[a:a + window + 1]
        W = t[-1] - t[0]
        s = (t - t[0]) / W
        phi = np.sin(np.pi * s) ** 2
        phi2 = 2.0 * (np.pi / W) ** 2 * np.cos(2 * np.pi * s)  # phi''
        ip[r] = np.trapezoid(phi, t)
        out[r] = np.trapezoid(phi[:, None] * sig[a:a + window + 1], t, axis=0)
        acc[r] = np.trapezoid(phi2 * low[a:a + window + 1], t)
        tc[r] = 0.5 * (t[0] + t[-1])
    return out, acc, ip, tc


def heave_rows(d: RunData, geo: Mapping[str, float], window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The heave balance under the modulating function phi: A (M, 5), b (M,) [N s], and int phi dt (M,) [s]."""
    q = (d.current / _deltas(d.gap, geo)) ** 2
    dbar = 0.5 * (d.gap[:, 0] + d.gap[:, 1])
    iq, acc, ip, _ = _modulated(d, window, q, dbar)
    A = np.zeros((ip.size, 5))
    A[:, 2], A[:, 3] = iq[:, 0], iq[:, 1]
    A[:, 4] = -(geo["g"] * ip - acc)
    return A, (geo["N1"] + geo["N2"]) * ip, ip


def pitch_rows(d: RunData, geo: Mapping[str, float], window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pitch balance under phi: K1 int phi q1 - K2 int phi q2 = (L/l)(N1 - N2) int phi - (I/(L l)) int phi''
    Delta, Delta = (d1 - d2)/2: A (M, 5) (columns K1, K2), b (M,) [N s], and int phi dt (M,) [s]."""
    q = (d.current / _deltas(d.gap, geo)) ** 2
    half = 0.5 * (d.gap[:, 0] - d.gap[:, 1])
    iq, acc, ip, _ = _modulated(d, window, q, half)
    A = np.zeros((ip.size, 5))
    A[:, 2], A[:, 3] = iq[:, 0], -iq[:, 1]
    rhs = geo["L"] / geo["l"] * (geo["N1"] - geo["N2"]) * ip - geo["I"] / (geo["L"] * geo["l"]) * acc
    return A, rhs, ip


def _window_times(d: RunData, window: int) -> np.ndarray:
    k0 = _windows(d.t.size, window)
    return np.asarray(0.5 * (d.t[k0] + d.t[k0 + window]))


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


def simulate_coils(d: RunData, geo: Mapping[str, float], R1: float, R2: float, K1: float,
                   K2: float | None = None) -> np.ndarray:
    """Coil currents (N, 2) [A] simulated from the held voltages and the measured gaps, from the measured i(t_0);
    coil j with R_j and its magnet's K_j (K2 None: K1 for both).

    The flux linkage lambda = 2K i/delta obeys lambda' = u - R delta lambda/(2K): integrated exactly over each
    period with u held and delta at the period's mean.
    """
    de = np.ascontiguousarray(_deltas(d.gap, geo))
    t = np.ascontiguousarray(d.t, dtype=float)
    K = (K1, K1 if K2 is None else K2)
    return np.stack([_coil_sim(t, np.ascontiguousarray(de[:, j]), np.ascontiguousarray(d.voltage[:, j], dtype=float),
                               float(d.current[0, j]), R, K[j]) for j, R in ((0, R1), (1, R2))], axis=1)


# -- estimation ---------------------------------------------------------------------------------------------------
#: a time block of the sandwich is at least this many of the residuals' correlation lengths (tau - 1 rows)
BLOCK_TAUS = 10.0
#: and the data spans at least this many blocks
MIN_BLOCKS = 8


def _block_length(block: float, groups: Sequence[np.ndarray], times: Sequence[np.ndarray]) -> float:
    """``block`` [s], or ``BLOCK_TAUS`` correlation lengths of the most correlated residual group if longer (batch
    means underestimate the variance by about (tau - 1)/block, tau the integrated autocorrelation time in rows: 1
    for white residuals), at most 1/``MIN_BLOCKS`` of the span."""
    span = max(float(t.max() - t.min()) for t in times if t.size)
    for r, t in zip(groups, times, strict=True):
        if r.size > 3:
            block = max(block, BLOCK_TAUS * (_tau(r) - 1.0) * float(np.median(np.diff(np.sort(t)))))
    return min(block, span / MIN_BLOCKS)


def _block_sums(scores: np.ndarray, t: np.ndarray, block: float) -> np.ndarray:
    """Sums of the rows of ``scores`` (n, p) over time blocks of ``block`` s (rows at times ``t``): (B, p), the
    non-empty blocks only."""
    idx = np.floor((t - t.min()) / block).astype(int)
    S = np.zeros((int(idx.max()) + 1, scores.shape[1]))
    np.add.at(S, idx, scores)
    return S[np.bincount(idx, minlength=S.shape[0]) > 0]


@dataclass
class _Fit:
    """One fit (all five parameters, or one K): theta = T @ value.

    ``contrib`` (B, p): each time block's share of the scaled estimate's error, H^-1 (its summed scores): the
    sandwich covariance is contrib^T contrib B/(B - 1) (scaled by ``scale``)."""

    names: tuple[str, ...]
    T: np.ndarray
    value: np.ndarray
    scale: np.ndarray
    contrib: np.ndarray
    J: np.ndarray
    refined: bool

    @property
    def full(self) -> np.ndarray:
        th: np.ndarray = self.T @ self.value
        return th

    def combo(self, g: np.ndarray) -> tuple[float, float]:
        """(variance, degrees of freedom) of g . value (g in physical units): the sandwich's, with the
        Satterthwaite degrees of freedom of its blocks' contributions (3 (sum c^2)^2 / sum c^4, at most B - 1:
        few blocks carrying the information give few)."""
        c = self.contrib @ (g * self.scale)
        B = c.size
        c2 = float(c @ c)
        var = c2 * B / max(B - 1, 1)
        c4 = float(np.sum(c ** 4))
        dof = min(3.0 * c2 * c2 / c4, B - 1.0) if c4 > 0 else B - 1.0
        return var, max(dof, 1.0)

    def unit(self, name: str) -> np.ndarray:
        g = np.zeros(len(self.names))
        g[self.names.index(name)] = 1.0
        return g


def _t95(dof: float) -> float:
    """Two-sided 95 % quantile of Student's t with ``dof`` degrees of freedom."""
    from scipy.stats import t

    return float(t.ppf(0.975, dof)) if math.isfinite(dof) else Z95


def _stage1(A: np.ndarray, b: np.ndarray, groups: Sequence[slice], scale: np.ndarray, noise: np.ndarray,
            t_rows: np.ndarray, block: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group-weighted least squares in scaled parameters: (theta, block contributions (see :class:`_Fit`), the
    weighted scaled Jacobian).

    ``noise`` (same shape as A): variances of the regressors' own noise (errors in variables); their
    weighted sum is taken off the normal matrix (bias-compensated least squares), so a noisy regressor does
    not pull its parameter towards zero. The estimating equations' score of row i is
    w_i^2 (a_i r_i - n_i theta) (they sum to zero at the estimate), summed per time block for the sandwich.
    """
    As = A * scale
    Ns = noise * scale ** 2
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
    r = As @ theta_s - b
    dof = max(b.size - A.shape[1], 1)
    s2 = float(np.sum((r * w) ** 2) / dof)
    Nm = Aw.T @ Aw - np.diag((Ns * w[:, None] ** 2).sum(axis=0))
    scores = (w ** 2)[:, None] * (As * r[:, None] - Ns * theta_s)
    block = _block_length(block, [r[g] for g in groups], [t_rows[g] for g in groups])
    contrib = _block_sums(scores, t_rows, block) @ np.linalg.pinv(Nm)
    return theta_s * scale, contrib, Aw * math.sqrt(1.0 / s2)


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
    if name in ("K", "K1", "K2"):
        return (f"{base}: {name} enters the coil equation only through changes of the flux i/delta, and the run's "
                f"fluxes barely change (relative change per window {flux:.2g}; hover alone holds them constant, "
                f"because the magnet forces at any equilibrium are the same); the heave balance fixes only "
                f"K1 q1 + K2 q2 - m g"
                + (f" (the weakest direction mixes {', '.join([name, *mixed])})" if mixed else ""))
    if name == "m":
        return (f"{base}: the heave balance m (g - a) = K1 q1 + K2 q2 - (N1 + N2) gives m only with K known, and "
                f"the heave accelerations are small (RMS {exc['heave_accel_rms_m_s2']:.2g} m/s^2)"
                + (f"; the weakest direction mixes {', '.join([name, *mixed])}" if mixed else ""))
    return f"{base}" + (f"; the weakest direction mixes {', '.join([name, *mixed])}" if mixed else "")


def _why_flux(name: str, exc: dict[str, float], limit: float) -> str:
    share = exc["flux_noise_share"]
    flux = max(exc["flux_change_rel_1"], exc["flux_change_rel_2"])
    head = ("K enters the coil equation only through changes of the flux i/delta" if name == "K" else
            "m follows from the heave balance m (g - a) = K1 q1 + K2 q2 - (N1 + N2) only once K is known, and K")
    tail = "" if name == "K" else " is not determined"
    return (f"{head}{tail}: the run's flux changes are at the sensors' noise level ({share * 100:.3g} % of their "
            f"energy is noise, limit {limit * 100:.3g} %; relative change per window {flux:.2g}). Hover and slow "
            f"references hold the fluxes constant (every equilibrium needs the same magnet forces); record a run "
            f"with faster reference steps (docs/manual/hardware.md, bring-up step 5)")


def identify(d: RunData, geo: Mapping[str, float], nominal: Mapping[str, float], *, coil_window: float = 0.02,
             heave_window: float = 0.2, holdout: float = 0.3, refine: bool = True, max_rel_ci: float = 0.1,
             max_flux_noise: float = 0.4, rel_floor: float = 1e-4, block: float = 0.1) -> IdentResult:
    """Estimate (R1, R2, K1, K2, m), or (R1, R2, K, m) when the run does not separate the magnets (see the module
    docstring).

    Args:
        geo: L, l, I [m, m, kg m^2], N1, N2 [N], g [m/s^2].
        nominal: R1, R2, K, m (K1, K2: K when absent): the data sheet's values; they scale the problem and judge
            the intervals.
        coil_window, heave_window: window lengths [s] of the coil and heave equations.
        holdout: fraction of the run (its end) kept out of the fit and simulated with the estimates.
        refine: stage 2 (simulation error) after the linear stage.
        max_rel_ci: a parameter whose 95 % half-width exceeds this fraction of its nominal value is not determined.
        max_flux_noise: K (and with it m) is not determined when more than this share of the flux changes'
            energy (both coils) is the sensors' noise (the changes are too small to tell K); K1 and K2 are not
            separated when it is above this on either coil. On the emulated rig: 19-31 % in the excitation runs
            that identify K within 0.4 %, 50-100 % in S1 and hover runs (a hover run at 50 % gave K 21 % off with a
            5 % interval: closed-loop quantisation noise biases it).
        rel_floor: a relative standard deviation added to each statistical one (in quadrature): what the
            statistics cannot see (the trapezoid rule's error, the ADC's quantisation, unmodelled dynamics).
        block: the time blocks [s] over which the estimating equations' scores are summed for the intervals
            (longer than the residuals' correlation; see the module docstring).
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
    nom = {k: float(nominal[k] if k in nominal else nominal["K"]) for k in (*FIT, "K")}
    Ac, bc, Nc = coil_rows(fit, geo, wc)
    Ah, bh, _ = heave_rows(fit, geo, wh)
    tc, th = _window_times(fit, wc), _window_times(fit, wh)
    M = Ac.shape[0] // 2
    eq = (np.vstack([Ac, Ah]), np.concatenate([bc, bh]), np.vstack([Nc, np.zeros_like(Ah)]),
          np.concatenate([tc, tc, th]), [slice(0, M), slice(M, 2 * M), slice(2 * M, 2 * M + bh.size)])
    exc = _excitation(fit, geo, wc)
    # errors in variables: the share of the K_j column's energy that is the flux's own noise, per coil and both
    share = [float(Nc[M * j:M * (j + 1), 2 + j].sum() / max(float(np.sum(Ac[M * j:M * (j + 1), 2 + j] ** 2)), 1e-300))
             for j in (0, 1)]
    exc["flux_noise_share_1"], exc["flux_noise_share_2"] = share
    exc["flux_noise_share"] = float(Nc[:, 2:4].sum() / max(float(np.sum(Ac[:, 2:4] ** 2)), 1e-300))
    flux_ok = exc["flux_noise_share"] < max_flux_noise
    notes: list[str] = []
    stage2 = refine and flux_ok

    def run(T: np.ndarray, names: tuple[str, ...]) -> _Fit:
        return _fit(fit, geo, eq, T, names, np.array([nom[k] for k in names]), wh, th, block, stage2, notes)

    one = run(T_ONE, ONE)
    two = run(np.eye(5), FIT) if flux_ok and max(share) < max_flux_noise else None

    def judge(f: _Fit, name: str, g: np.ndarray | None = None) -> tuple[Estimate, float]:
        g = f.unit(name) if g is None else g
        value = float(g @ f.value)
        var, dof = f.combo(g)
        std = math.sqrt(var + (rel_floor * value) ** 2)
        q = _t95(dof)
        rel = q * std / nom[name]
        if rel < max_rel_ci and value > 0:
            return Estimate(name, UNITS[name], True, value, std, (value - q * std, value + q * std), dof=dof), rel
        return Estimate(name, UNITS[name], False, reason=""), rel

    est: dict[str, Estimate] = {}
    verdict = "not determined"
    sel = one
    coils_s = coils_ci = math.nan
    if two is not None:
        K1, K2 = two.value[2], two.value[3]
        e1, r1 = judge(two, "K1")
        e2, r2 = judge(two, "K2")
        gs = np.array([0.0, 0.0, 2 * K2, -2 * K1, 0.0]) / (K1 + K2) ** 2  # d s / d theta, s = (K1-K2)/(K1+K2)
        var_s, dof_s = two.combo(gs)
        var_s += 0.5 * rel_floor ** 2  # s = (K1 - K2)/(K1 + K2) with each K_j's relative floor
        coils_s, coils_ci = float((K1 - K2) / (K1 + K2)), _t95(dof_s) * math.sqrt(var_s)
        if e1.determined and e2.determined and abs(coils_s) > coils_ci:
            verdict, sel = "split", two
            est["K1"], est["K2"] = e1, e2
        elif e1.determined and e2.determined:
            verdict = "one K: agree"
            why = (f"K1 and K2 agree within their intervals (split (K1 - K2)/(K1 + K2) = {100 * coils_s:+.2g} % "
                   f"+- {100 * coils_ci:.2g} %, 95 %): one K is given")
            est["K1"] = est["K2"] = Estimate("K1", UNITS["K1"], False, reason=why)
        else:
            verdict = "one K: cannot separate"
            why = (f"the run cannot separate K1 from K2 (their 95 % intervals would be +-{100 * r1:.3g} / "
                   f"+-{100 * r2:.3g} % of the nominal value): one K is given")
            est["K1"] = est["K2"] = Estimate("K1", UNITS["K1"], False, reason=why)
    elif flux_ok:
        verdict = "one K: cannot separate"
        j = int(np.argmax(share)) + 1
        why = (f"coil {j}'s flux changes are at the sensors' noise level ({100 * max(share):.3g} % of their energy "
               f"is noise, limit {100 * max_flux_noise:.3g} %): the run cannot separate K1 from K2; one K is given")
        est["K1"] = est["K2"] = Estimate("K1", UNITS["K1"], False, reason=why)
    else:
        why = "K is not determined (see K), nor is either magnet's"
        est["K1"] = est["K2"] = Estimate("K1", UNITS["K1"], False, reason=why)
    if "K2" in est and not est["K2"].determined:
        est["K2"] = Estimate("K2", UNITS["K2"], False, reason=est["K1"].reason)
    F = sel.J.T @ sel.J
    evals, evecs = np.linalg.eigh(F)
    cond = float(evals[-1] / max(evals[0], 1e-300))
    lead = evecs[np.argmax(np.abs(evecs[:, 0])), 0]
    weak = {k: float(v) for k, v in zip(sel.names, evecs[:, 0] * np.sign(lead), strict=True)}
    for k in PARAMS:
        if k == "K" and verdict == "split":
            e, _ = judge(sel, "K", np.array([0.0, 0.0, 0.5, 0.5, 0.0]))
        elif k in ("K", "m") and not flux_ok:
            e = Estimate(k, UNITS[k], False, reason=_why_flux(k, exc, max_flux_noise))
        else:
            e, rel = judge(sel, k)
            if not e.determined:
                e = Estimate(k, UNITS[k], False, reason=_why(k, weak, exc, rel))
        est[k] = e
    check = SplitCheck(verdict, coils_s, coils_ci)
    if flux_ok and est["K"].determined:
        check = _moment_check(fit, geo, wh, sel, check, block, notes)
    val = _validate(d, geo, n_fit, sel.full, wh) if n_fit < n else None
    return IdentResult({k: est[k] for k in NAMES}, exc, cond, weak, val, sel.refined, n, float(d.t[-1] - d.t[0]),
                       notes, check)


def _fit(fit: RunData, geo: Mapping[str, float], eq: tuple[Any, ...], T: np.ndarray, names: tuple[str, ...],
         scale: np.ndarray, wh: int, th: np.ndarray, block: float, stage2: bool, notes: list[str]) -> _Fit:
    """Stage 1 on the reduced parameters (theta = T @ reduced), then stage 2 when ``stage2``."""
    A, b, noise, t_rows, groups = eq
    value, contrib, J = _stage1(A @ T, b, groups, scale, noise @ T, t_rows, block)
    refined = False
    if stage2:
        start = np.where(value > 0, value, scale)
        r = _refine(fit, geo, T, start, scale, wh, th, block, notes, len(names) == len(FIT))
        if r is not None:
            value, contrib, J = r
            refined = True
    return _Fit(names, T, value, scale, contrib, J, refined)


def _refine(fit: RunData, geo: Mapping[str, float], T: np.ndarray, v0: np.ndarray, scale: np.ndarray, wh: int,
            th: np.ndarray, block: float, notes: list[str], note: bool
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Stage 2: least squares on the coils' simulation error and the heave equations over the reduced parameters;
    (value, block contributions, weighted scaled Jacobian), None when it did not converge (a note says so)."""
    from scipy.optimize import least_squares

    Ah, bh, _ = heave_rows(fit, geo, wh)

    def groups(th_: np.ndarray) -> list[np.ndarray]:
        with np.errstate(over="ignore", invalid="ignore"):  # the solver's trial steps may leave the physical range
            i_sim = simulate_coils(fit, geo, th_[0], th_[1], th_[2], th_[3])
            e = i_sim - fit.current
            return [e[:, 0], e[:, 1], Ah @ th_ - bh]

    g0 = groups(T @ v0)
    w = [1.0 / max(float(np.sqrt(np.mean(g ** 2))), 1e-12) for g in g0]

    def resid(v: np.ndarray, w: list[float]) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):
            return np.concatenate([g * wi for g, wi in zip(groups(T @ (v * scale)), w, strict=True)])

    sol = least_squares(resid, v0 / scale, args=(w,), method="lm")
    gs = groups(T @ (sol.x * scale))
    taus = [_tau(g) for g in gs]
    w = [1.0 / (max(float(np.sqrt(np.mean(g ** 2))), 1e-12) * math.sqrt(t)) for g, t in zip(gs, taus, strict=True)]
    sol = least_squares(resid, sol.x, args=(w,), method="lm")
    if not sol.success or not np.all(np.isfinite(sol.x)):
        notes.append(f"refinement did not converge ({sol.message}); stage-1 estimates kept")
        return None
    J = sol.jac
    r = resid(sol.x, w)
    scores = J * r[:, None]
    gs = groups(T @ (sol.x * scale))
    block = _block_length(block, gs, [fit.t, fit.t, th])
    contrib = _block_sums(scores, np.concatenate([fit.t, fit.t, th]), block) @ np.linalg.pinv(J.T @ J)
    if note:
        notes.append("autocorrelation times of the refined residuals (samples; heave: windows): coil 1 {:.3g}, "
                     "coil 2 {:.3g}, heave {:.3g}; intervals from time blocks of {:.3g} s"
                     .format(*(_tau(g) for g in gs), block))
    return sol.x * scale, contrib, J


def _moment_check(fit: RunData, geo: Mapping[str, float], wh: int, sel: _Fit, check: SplitCheck, block: float,
                  notes: list[str]) -> SplitCheck:
    """The split s = (K1 - K2)/(K1 + K2) the pitch balance needs, per window: K ((1 + s) A1 - (1 - s) A2) = b
    with K = (K1 + K2)/2 of the fit, least squares over the windows, its interval from the same time blocks;
    compared with the coils' split (``check``)."""
    Ap, bp, _ = pitch_rows(fit, geo, wh)
    th = _window_times(fit, wh)
    K = 0.5 * float(sel.full[2] + sel.full[3])
    c = Ap[:, 2] - Ap[:, 3]  # int phi (q1 + q2)
    y = bp / K - (Ap[:, 2] + Ap[:, 3])  # b/K - int phi (q1 - q2)
    cc = float(c @ c)
    s = float(c @ y) / cc
    cb = _block_sums((c * (y - c * s))[:, None], th, block)[:, 0] / cc
    B = cb.size
    c2, c4 = float(cb @ cb), float(np.sum(cb ** 4))
    var = c2 * B / max(B - 1, 1)
    dof = max(min(3.0 * c2 * c2 / c4, B - 1.0) if c4 > 0 else B - 1.0, 1.0)
    var_k, _ = sel.combo(np.array([0.0, 0.0, 0.5, 0.5, 0.0]) if len(sel.names) == 5 else sel.unit("K"))
    var += (float(c @ bp) / cc / K ** 2) ** 2 * var_k  # through the fit's K (nil when N1 = N2 and level)
    ci = _t95(dof) * math.sqrt(var)
    consistent = None
    if math.isfinite(check.coils):
        consistent = bool(abs(s - check.coils) <= math.hypot(ci, check.coils_ci))
        if not consistent:
            notes.append(f"the moment balance needs a K split (K1 - K2)/(K1 + K2) of {100 * s:+.3g} % +- "
                         f"{100 * ci:.2g} %, the coils give {100 * check.coils:+.3g} % +- "
                         f"{100 * check.coils_ci:.2g} %: the loads' moment (N1, N2, the centre of mass), a current "
                         f"sensor's gain or the split is off")
    return SplitCheck(check.verdict, check.coils, check.coils_ci, s, ci, consistent)


def _validate(d: RunData, geo: Mapping[str, float], n_fit: int, theta: np.ndarray, wh: int) -> Validation:
    hold = d.slice(n_fit, d.t.size)
    i_sim = simulate_coils(hold, geo, theta[0], theta[1], theta[2], theta[3])
    e = i_sim - hold.current
    skip = min(50, hold.t.size // 10)  # the simulation starts from the measured current: its first transient
    e, ic = e[skip:], hold.current[skip:]
    rms = np.sqrt(np.mean(e ** 2, axis=0))
    spread = np.linalg.norm(ic - ic.mean(axis=0), axis=0)
    fitp = 100.0 * (1.0 - np.linalg.norm(e, axis=0) / np.maximum(spread, 1e-300))
    Ah, bh, wphi = heave_rows(hold, geo, wh)
    hr = (Ah @ theta - bh) / wphi
    rel = [float(rms[j] / max(abs(ic[:, j].mean()), 1e-300)) for j in (0, 1)]
    return Validation(float(hold.t[0]), float(hold.t[-1]), (float(rms[0]), float(rms[1])),
                      (float(fitp[0]), float(fitp[1])), (rel[0], rel[1]), float(np.sqrt(np.mean(hr ** 2))))
