r"""Plausibility of the controller's inputs: reference range and rate, sample stamps.

The controller acts on two streams it does not produce: ``/dem/reference`` (y_d and its
derivatives, :mod:`dem_ros.core.reference`) and ``/dem/state_estimate``. Before the law sees
them, :class:`InputChecks` refuses what no healthy graph can send. Pure Python, no middleware.

**Range.** A reference gap must lie in [``reference_gap_min``, ``reference_gap_max``] (m), by
default the board's trip band [trip_gap_min, trip_gap_max] (:mod:`dem_ros.board`): a
reference outside it asks for a gap at which the board lands the plate.

**Rate.** The reference model M(s) = b0 / (s^3 + a2 s^2 + a1 s + a0) (Eq. 46) filters a command
r(t) held in the range [lo, hi] (and starts at rest inside it). With h the impulse response of
M and unit DC gain, y_d^(n)(t) = int h^(n)(tau) (r(t - tau) - c) dtau for any constant c (the
integrals of h', h'' vanish: relative degree 3), so with c the middle of the range

    |y_d'(t)| <= (hi - lo) / 2 * ||h'||_1  =: v_max                              (1)

for every reference the model can produce, however the schedule steps. :func:`reference_speed_bound`
computes (1) (||h'||_1 by quadrature of the exact impulse response); the default model
0.25/((s+1)(s+0.5)^2) has ||h'||_1 = 0.3238 s^-1, so over the default band [1.5, 11] mm
(the board's trip_gap_min to its landing_gap, where the plate rests on its support)
v_max = 1.54 mm/s (``reference_max_speed`` 1.55 mm/s; a 3 mm step of the schedule peaks at 0.49 mm/s).
A received reference is accepted when |y_d'| <= v_max and its gaps moved no more than the
bound allows since the last accepted sample:

    |y_k - y_j| <= v_max (t_k - t_j) + tol,   tol = 1 nm                           (2)

so a 20 mm step (or a 1 mm one) is refused, and a reference stream that resumes after an
outage is accepted as soon as it is where the bound says it could be. y_d'' and y_d''' are
checked for being finite (their bounds depend on the model's coefficients, which the
controller is not given).

**Stamps, on the experiment clock.** Every stamp of the graph is a plant sample time
(``dem_ros.contract``). The controller's clock for ages is the newest stamp of
``/dem/applied_voltage``, which comes straight from the plant (or the hardware driver):
wall time would be wrong in a lockstep simulation, whose clock waits for the controller,
and on a rig whose board clock drifts from the PC's. The age of an estimate stamped t is

    age = t_plant - t

The plant holds the command computed from sample k over [t_k+d, t_k+d+1) (d =
``command_delay``) and integrates that period when it publishes sample k+d+1: once the
controller has seen t_plant >= t_k + (d + 1) T the command is too late to be applied. In
lockstep the plant cannot publish beyond k + d before it has the command of k, so an
on-time estimate has age <= d T. Hence ``max_age`` = (d + 1) T = 2 ms by default: the
largest age at which acting can still matter, with one period of slack for the order in
which the two topics are taken. A stamp more than ``max_age`` *ahead* of t_plant cannot be
a sample of this plant (a rogue or broken clock) and is refused as from the future; a
reference, published one period ahead, may lead by ``max_age`` + T.

The clock itself is guarded the same way: a plant stamp more than ``max_age`` (at least 2 T) away
from t_plant, either way, is not taken on its own. One corrupt or foreign ``/dem/applied_voltage``
stamped ahead would otherwise move the clock there, every estimate would be "stale" until the
plant caught up, and the controller would command nothing (measured, ``dem-ros faults`` row
``future-applied``: one sample stamped +1 h landed the plate). A second stamp in a row within
``max_age`` after the first confirms a real jump (samples lost on a stalled host, a re-anchored
plant): the clock then moves one sample late, which only makes estimates look younger for that
sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["InputChecks", "ReferenceVerdict", "reference_speed_bound"]

TOL_M = 1e-9  # m: rounding allowance of the step bound (2)


def reference_speed_bound(a: tuple[float, float, float], b0: float, lo: float, hi: float,
                          horizon_s: float | None = None, n: int = 200_001) -> float:
    """v_max of Eq. (1) [m/s]: (hi - lo)/2 * ||h'||_1 for M(s) = b0/(s^3 + a2 s^2 + a1 s + a0).

    ``a`` = (a0, a1, a2) (s^-3, s^-2, s^-1), ``b0`` (s^-3), ``lo`` < ``hi`` (m). h' is
    integrated over ``horizon_s`` (default 40 / slowest pole rate: e^-40 of it is left).
    """
    import scipy.signal as ss  # only to derive the default: not on the 1 kHz path

    a0, a1, a2 = a
    poles = np.roots([1.0, a2, a1, a0])
    if np.any(poles.real >= 0):
        raise ValueError(f"reference model s^3+{a2:g}s^2+{a1:g}s+{a0:g} is not Hurwitz")
    horizon = horizon_s if horizon_s is not None else 40.0 / float(np.min(-poles.real))
    t = np.linspace(0.0, horizon, n)
    _, dh = ss.impulse(ss.lti([b0, 0.0], [1.0, a2, a1, a0]), T=t)  # s M(s): impulse response h'
    dc = b0 / a0
    return 0.5 * (hi - lo) * float(np.trapezoid(np.abs(dh), t)) / dc


@dataclass(frozen=True)
class ReferenceVerdict:
    """The outcome of :meth:`InputChecks.reference`: ``ok``, else ``key`` (a counter name) and ``why``."""

    ok: bool
    key: str = ""
    why: str = ""


_OK = ReferenceVerdict(True)


class InputChecks:
    """Range, rate and stamp checks of the controller's inputs (see the module docstring).

    Args:
        cfg: the ``controller`` group: ``dt`` [s], ``max_age`` [s] (0: no stamp checks),
            ``reference_gap_min``, ``reference_gap_max`` [m], ``reference_max_speed`` [m/s].

    Attributes:
        t_plant: newest plant stamp seen [ns] (None before the first).
        last_ref (8,): the last accepted reference [y1, y2, y1', y2', y1'', y2'', y1''', y2'''].
        last_ref_t: its stamp [ns] (None before the first).
    """

    def __init__(self, cfg: Mapping[str, Any]):
        self.t_plant: int | None = None
        self._jump: int | None = None  # a plant stamp far from t_plant, waiting for the next to confirm it
        self.stamps_refused = 0  # plant stamps not taken (a lone jump of the clock)
        self.last_ref = np.zeros(8)
        self.last_ref_t: int | None = None
        self.configure(cfg)

    def configure(self, cfg: Mapping[str, Any]) -> None:
        """Take (validated) settings; acts from the next call."""
        self.dt_ns = round(cfg["dt"] * 1e9)
        self.max_age_ns = round(cfg["max_age"] * 1e9)
        self.lo = float(cfg["reference_gap_min"])
        self.hi = float(cfg["reference_gap_max"])
        self.v_max = float(cfg["reference_max_speed"])

    def plant_stamp(self, t_ns: int) -> bool:
        """A stamp straight from the plant (``/dem/applied_voltage``): advances the experiment clock.
        False when it is a lone jump, not taken (module docstring; counted in ``stamps_refused``)."""
        t = self.t_plant
        jump = max(self.max_age_ns, 2 * self.dt_ns)
        if t is None or self.max_age_ns <= 0 or 0 < t_ns - t <= jump:
            if t is None or t_ns > t:
                self.t_plant = t_ns
            self._jump = None
            return True
        if abs(t_ns - t) <= jump:
            return True  # an older sample taken late: the clock stays
        c = self._jump
        if c is not None and 0 < t_ns - c <= jump:  # two in a row agree: the plant's clock did move
            self.t_plant = t_ns
            self._jump = None
            return True
        self._jump = t_ns
        self.stamps_refused += 1
        return False

    def age_ns(self, t_ns: int) -> int | None:
        """Age of a sample stamped ``t_ns`` on the experiment clock [ns] (None before any plant stamp)."""
        return None if self.t_plant is None else self.t_plant - t_ns

    def estimate(self, t_ns: int) -> str:
        """'' when an estimate stamped ``t_ns`` may be acted on, else 'stale' or 'future'."""
        age = self.age_ns(t_ns)
        if age is None or self.max_age_ns <= 0:
            return ""
        if age > self.max_age_ns:
            return "stale"
        if -age > self.max_age_ns:
            return "future"
        return ""

    def reference(self, t_ns: int, ref: np.ndarray) -> ReferenceVerdict:
        """Check a received reference (8+ values) stamped ``t_ns``; accepted ones become ``last_ref``."""
        # Python floats (one conversion; no numpy scalars): the controller checks every sample
        vals = ref[:8].tolist() if isinstance(ref, np.ndarray) else list(ref[:8])
        y1, y2, d1, d2 = vals[0], vals[1], vals[2], vals[3]
        if not all(map(math.isfinite, vals)):
            return ReferenceVerdict(False, "reference_invalid", "non-finite values")
        age = self.age_ns(t_ns)
        if age is not None and self.max_age_ns > 0 and -age > self.max_age_ns + self.dt_ns:
            return ReferenceVerdict(False, "reference_future",
                                    f"stamped {-age * 1e-6:.3g} ms ahead of the plant's newest sample")
        lo, hi = self.lo, self.hi
        if not (lo <= y1 <= hi and lo <= y2 <= hi):
            return ReferenceVerdict(False, "reference_range",
                                    f"gaps {y1 * 1e3:.3f} / {y2 * 1e3:.3f} mm outside [{lo * 1e3:g}, {hi * 1e3:g}] mm")
        v = self.v_max
        if abs(d1) > v or abs(d2) > v:
            return ReferenceVerdict(False, "reference_rate",
                                    f"speed {max(abs(d1), abs(d2)) * 1e3:.3g} mm/s above {v * 1e3:.3g} mm/s")
        if self.last_ref_t is not None:
            allowed = v * abs(t_ns - self.last_ref_t) * 1e-9 + TOL_M
            step = max(abs(y1 - self.last_ref[0]), abs(y2 - self.last_ref[1]))
            if step > allowed:
                return ReferenceVerdict(False, "reference_rate",
                                        f"gap moved {step * 1e3:.3g} mm in {abs(t_ns - self.last_ref_t) * 1e-6:.3g} ms"
                                        f" (at most {allowed * 1e3:.3g} mm at {v * 1e3:.3g} mm/s)")
        if self.last_ref_t is None or t_ns >= self.last_ref_t:
            self.last_ref[:] = vals
            self.last_ref_t = t_ns
        return _OK

    def held_reference(self) -> np.ndarray:
        """The last accepted reference held at rest: its gaps, zero derivatives (8,)."""
        out = np.zeros(8)
        out[:2] = self.last_ref[:2]
        return out
