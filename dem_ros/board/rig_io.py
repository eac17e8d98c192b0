"""The rig's sensor and actuator models: what the emulated board's ADC reads and what its bridges apply
(``dem-ros rig``, :mod:`dem_ros.hardware.rig`; docs/manual/board.md).

Sensor models (counts n from a gap d [m] or a current i [A]):
    gap:     n = c^-1((1 + gain_error) d + offset_error + a c_j(x) + noise),  c: the driver's calibration
             polynomial (``hw_driver.gap{j}_c{p}``: the sensor's data sheet), rounded, clipped
             to [0, 2^adc_bits - 1] (at either end: out of range); a c_j(x): the sensor's curve
             (:func:`curve_deviation`, ``rig.gap_curve`` = a; the shape: dem_ros/hardware/sensors.py)
    current: n = (i + noise) / gain + offset (``hw_driver.current{j}_*``), rounded and clipped
Actuator models (per coil):
    bus      V_bus = bus_voltage - bus_resistance (|i1| + |i2|)     (sag; a fault may lower bus_voltage)
    PWM      u = V_bus round(duty 2^(pwm_bits-1)) / 2^(pwm_bits-1),  duty = u_cmd / V_bus in [-1, 1]
    limit    a coil above current_limit gets no positive voltage (the bridge's cycle-by-cycle limit)
The noise is drawn by the caller (the rig, with its seeded generator) and passed in.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .modes import SafetyError

__all__ = ["HALF", "MID", "CoilDrivers", "CurrentSensors", "GapSensors", "curve_deviation"]

MID = 0.008  # m, centre of the sensor curves' span
HALF = 0.004  # m, half their span (4-12 mm)


def curve_deviation(j: int, d: float | np.ndarray, a: float) -> float | np.ndarray:
    """a c_j(x) [m], x = (d - MID) / HALF: sensor j's (1 or 2) deviation from a linear response at the true gap
    d [m] (c_1 = (1 - x^2)(1 + 0.3 x), c_2 = sin(pi x / 2) - 0.4 x^2; a float for a float: the board's 1 kHz path
    takes no numpy call per sample)."""
    if isinstance(d, float):
        if a == 0.0:
            return 0.0
        x = (d - MID) / HALF
        return a * ((1.0 - x * x) * (1.0 + 0.3 * x) if j == 1 else math.sin(0.5 * math.pi * x) - 0.4 * x * x)
    xa = (np.asarray(d, dtype=float) - MID) / HALF
    c = (1.0 - xa * xa) * (1.0 + 0.3 * xa) if j == 1 else np.sin(0.5 * math.pi * xa) - 0.4 * xa * xa
    return a * c


class GapSensors:
    """The two gap sensors behind the board's ADC, and the board's conversion back with the nominal calibration.

    Args:
        hw: the ``hw_driver`` group (``gap{j}_c{p}``: the calibration polynomials, m per count^p).
        adc_bits: ADC resolution.
        gain_error: relative gain error of the sensors against their calibration.
        offset_error: their offset error [m].
        curve: the amplitude a [m] of their nonlinear curves (:func:`curve_deviation`; 0: linear).
    """

    def __init__(self, hw: Mapping[str, Any], adc_bits: int, gain_error: float = 0.0, offset_error: float = 0.0,
                 curve: float = 0.0):
        self.full = (1 << adc_bits) - 1
        self.gain_error, self.offset_error, self.curve = gain_error, offset_error, float(curve)
        n = np.arange(self.full + 1, dtype=float)
        self.gap_of_counts: list[np.ndarray] = []
        for j in (1, 2):
            c = [hw[f"gap{j}_c{p}"] for p in range(4)]
            g = c[0] + n * (c[1] + n * (c[2] + n * c[3]))
            if not np.all(np.diff(g) > 0):
                raise SafetyError(f"hw_driver.gap{j}_c*: the calibration polynomial is not increasing over "
                                  f"0..{self.full} counts")
            self.gap_of_counts.append(g)
        self.gap_list = [g.tolist() for g in self.gap_of_counts]

    def sensed(self, j: int, gap: float) -> float:
        """The gap [m] sensor j (0, 1) reports for the true gap [m], before noise:
        (1 + gain_error) d + offset_error + a c_j(x)."""
        return (1 + self.gain_error) * gap + self.offset_error + float(curve_deviation(j + 1, gap, self.curve))

    def count(self, j: int, d: float) -> int:
        """The count of sensor j (0, 1) whose calibrated gap is nearest to d [m] (binary search of the monotonic
        table), clipped to [0, full]."""
        g = self.gap_list[j]
        k = bisect.bisect_left(g, d)
        if k <= 0:
            return 0
        if k > self.full:
            return self.full
        return k if g[k] - d < d - g[k - 1] else k - 1

    def out_of_range(self, count: int) -> bool:
        """A count at either end of the ADC's range: dead or saturated (GAPj_RANGE)."""
        return count in (0, self.full)

    def gaps(self, counts: Sequence[int]) -> np.ndarray:
        """The board's gaps (2,) [m] of the counts, with the nominal calibration."""
        return np.array([self.gap_of_counts[0][counts[0]], self.gap_of_counts[1][counts[1]]])


class CurrentSensors:
    """The two coil-current sensors: i = gain (n - offset) (``hw_driver.current{j}_gain``, ``_offset``)."""

    def __init__(self, hw: Mapping[str, Any], adc_bits: int):
        self.full = (1 << adc_bits) - 1
        self.gain = np.array([hw["current1_gain"], hw["current2_gain"]])
        self.offset = np.array([hw["current1_offset"], hw["current2_offset"]])

    def counts(self, currents: np.ndarray) -> tuple[int, int]:
        """The counts of the currents (2,) [A] (noise included), rounded and clipped to the ADC's range."""
        n = np.clip(np.round(currents / self.gain + self.offset), 0, self.full)
        return int(n[0]), int(n[1])

    def currents(self, counts: Sequence[int]) -> np.ndarray:
        """The board's currents (2,) [A] of the counts."""
        return np.asarray(self.gain * (np.asarray(counts, float) - self.offset))


class CoilDrivers:
    """The two coil drivers (H-bridges) on one DC bus.

    Args:
        bus_voltage: the bus without load [V].
        bus_resistance: its source resistance [ohm].
        pwm_bits: PWM resolution (signed duty in steps of 2^-(bits-1)).
        current_limit: above this current [A] a coil gets no positive voltage.
    """

    def __init__(self, bus_voltage: float, bus_resistance: float, pwm_bits: int, current_limit: float):
        self.bus_voltage, self.bus_resistance = bus_voltage, bus_resistance
        self.pwm = float(1 << (pwm_bits - 1))
        self.current_limit = current_limit

    def bus(self, i1: float, i2: float, supply: float | None = None) -> float:
        """The bus voltage [V] under the coil currents [A]; ``supply``: a sagged supply in place of bus_voltage."""
        v = self.bus_voltage if supply is None else supply
        return max(v - self.bus_resistance * (abs(i1) + abs(i2)), 0.0)

    def apply(self, u: np.ndarray, bus: float, currents: np.ndarray,
              failed: tuple[bool, bool] = (False, False)) -> np.ndarray:
        """The voltages (2,) [V] the bridges apply for the commanded u (2,) [V] at the bus [V] and the coil
        currents (2,) [A]; a failed bridge (open) applies none."""
        out = np.zeros(2)
        for j in (0, 1):
            if failed[j] or bus <= 0:
                continue
            duty = min(max(u[j] / bus, -1.0), 1.0)
            v = bus * round(duty * self.pwm) / self.pwm
            if currents[j] > self.current_limit and v > 0:
                v = 0.0
            out[j] = v
        return out
