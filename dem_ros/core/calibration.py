r"""Gap-sensor calibration from a shim session: ADC counts measured with the plate resting on shims of known
thickness, fitted per sensor in the form ``hw_driver`` reads (dem_ros/hardware/driver.py, ``Calibration``).

* ``poly``: gap_j(n) = sum_p c_{j,p} n^p, p = 0..3 (``hw_driver.gap{j}_c0..c3``), least squares on the
  shim points, solved in n / 2^16 for conditioning and scaled back (c_p = a_p / 2^(16 p)).
* ``table``: a monotone piecewise-cubic (PCHIP) through the points, tabulated on a grid of counts for
  ``hw_driver.gap_table`` (CSV rows ``counts, gap1_m, gap2_m``; the driver interpolates linearly), with the
  end slopes carried on to the ADC's ends (the driver's np.interp would otherwise hold the end value: a gap
  beyond the session's range must still read beyond it).

Checks: the residuals at the shim points (RMS, largest) and monotonicity: d gap / d n > 0 across the
session's range of counts (a sensor whose fit turns back reads two gaps as one). A fit needs at least
``degree + 2`` distinct shims (one spare point, so a residual exists).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["CalibrationError", "SensorFit", "ShimPoint", "fit_sensor", "points_from_rows", "table_rows"]

SCALE = 65536.0  # counts are fitted as n / SCALE


class CalibrationError(ValueError):
    """The session cannot be fitted (too few shims, counts not increasing with the gap); the message says why."""


@dataclass(frozen=True)
class ShimPoint:
    """One shim placement: thickness [m], the mean counts of each sensor and their standard deviations."""

    gap: float
    counts: tuple[float, float]
    std: tuple[float, float] = (0.0, 0.0)
    samples: int = 0


@dataclass(frozen=True)
class SensorFit:
    """Sensor j's fit: ``kind`` poly (coefficients c0..c3) or table (its points), residuals at the shims.

    Attributes:
        coeffs (4,): c_0..c_3 [m, m/count, m/count^2, m/count^3] (poly; zeros for a table).
        knots, values: the table's counts and gaps [m] (table; empty for a poly).
        counts, gaps: the session's points; residuals: fit(counts) - gaps [m].
        monotonic: d gap/d n > 0 over [min counts, max counts]; min_slope [m/count] there.
    """

    sensor: int
    kind: str
    coeffs: np.ndarray
    knots: np.ndarray
    values: np.ndarray
    counts: np.ndarray
    gaps: np.ndarray
    residuals: np.ndarray
    monotonic: bool
    min_slope: float

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals ** 2)))

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.residuals)))

    def gap(self, n: np.ndarray | float) -> np.ndarray:
        """The fitted gap [m] at counts n (the driver's arithmetic)."""
        n = np.asarray(n, dtype=float)
        if self.kind == "poly":
            c = self.coeffs
            return np.asarray(c[0] + n * (c[1] + n * (c[2] + n * c[3])))
        return np.asarray(np.interp(n, self.knots, self.values))


def points_from_rows(rows: Sequence[Sequence[float]]) -> list[ShimPoint]:
    """``(shim_m, counts1, counts2)`` rows -> points, repeated shims kept as separate points."""
    out = []
    for r in rows:
        if len(r) < 3 or not all(np.isfinite(r[:3])):
            raise CalibrationError(f"row {list(r)}: expected finite shim_m, counts1, counts2")
        if not 0 < r[0] < 0.1:
            raise CalibrationError(f"row {list(r)}: shim thickness {r[0]:g} m is not in (0, 0.1) m (metres, not mm?)")
        out.append(ShimPoint(float(r[0]), (float(r[1]), float(r[2]))))
    return out


def fit_sensor(points: Sequence[ShimPoint], sensor: int, kind: str = "poly", degree: int = 3,
               adc_full: int = 65535, table_step: int = 256) -> SensorFit:
    """Fit sensor ``sensor`` (1 or 2) from the points (see the module docstring).

    Raises:
        CalibrationError: fewer than degree + 2 distinct shims, or counts that do not increase with the gap.
    """
    if kind not in ("poly", "table"):
        raise CalibrationError(f"kind {kind!r}: expected poly or table")
    g = np.array([p.gap for p in points], float)
    n = np.array([p.counts[sensor - 1] for p in points], float)
    distinct = np.unique(g).size
    need = degree + 2 if kind == "poly" else 3
    if distinct < need:
        raise CalibrationError(f"sensor {sensor}: {distinct} distinct shim thicknesses; a {kind} fit needs at least "
                               f"{need} (e.g. 4, 6, 8, 10, 12 mm)")
    order = np.argsort(g)
    g, n = g[order], n[order]
    # the counts must rise with the gap: averaged per shim, strictly
    ug = np.unique(g)
    un = np.array([n[g == x].mean() for x in ug])
    if not np.all(np.diff(un) > 0):
        k = int(np.nonzero(np.diff(un) <= 0)[0][0])
        raise CalibrationError(f"sensor {sensor}: the counts do not increase with the gap ({ug[k] * 1e3:g} mm: "
                               f"{un[k]:.1f}, {ug[k + 1] * 1e3:g} mm: {un[k + 1]:.1f}); a swapped or reversed "
                               f"sensor, or a shim placed wrongly")
    lo, hi = float(un[0]), float(un[-1])
    grid = np.linspace(lo, hi, 2001)
    if kind == "poly":
        a = np.polynomial.polynomial.polyfit(n / SCALE, g, degree)
        coeffs = np.zeros(4)
        coeffs[: degree + 1] = a / SCALE ** np.arange(degree + 1)
        fit = SensorFit(sensor, kind, coeffs, np.zeros(0), np.zeros(0), n, g, np.zeros_like(g), True, 0.0)
        slope = coeffs[1] + grid * (2 * coeffs[2] + grid * 3 * coeffs[3])
    else:
        from scipy.interpolate import PchipInterpolator

        f = PchipInterpolator(un, ug)
        inner = np.unique(np.concatenate([np.arange(np.ceil(lo / table_step) * table_step, hi, table_step), [lo, hi]]))
        s0, s1 = float(f.derivative()(lo)), float(f.derivative()(hi))
        knots = np.concatenate([[0.0], inner, [float(adc_full)]]) if lo > 0 and hi < adc_full else inner
        values = f(np.clip(knots, lo, hi)) + np.where(knots < lo, (knots - lo) * s0, 0.0) + \
            np.where(knots > hi, (knots - hi) * s1, 0.0)
        fit = SensorFit(sensor, kind, np.zeros(4), knots, values, n, g, np.zeros_like(g), True, 0.0)
        slope = np.diff(fit.gap(grid)) / np.diff(grid)
    res = fit.gap(n) - g
    ms = float(np.min(slope))
    return SensorFit(sensor, kind, fit.coeffs, fit.knots, fit.values, n, g, res, bool(ms > 0), ms)


def table_rows(fits: Sequence[SensorFit], adc_full: int = 65535) -> np.ndarray:
    """The ``gap_table`` CSV rows (counts, gap1_m, gap2_m) of two fits on one grid of counts (every knot of
    either), each sensor's gap interpolated as the driver will."""
    knots = np.unique(np.concatenate([f.knots for f in fits] + [[0.0, float(adc_full)]]))
    return np.column_stack([knots, fits[0].gap(knots), fits[1].gap(knots)])
