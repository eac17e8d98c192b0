"""The rig's sensor and actuator models (dem_ros.board.rig_io): ADC counts, calibration, bus sag, PWM, limit."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.board import SafetyError
from dem_ros.board.rig_io import CoilDrivers, CurrentSensors, GapSensors
from dem_ros.core.params import SCHEMA

HW = SCHEMA.defaults("hw_driver")


def test_gap_counts_round_trip_within_half_a_count():
    s = GapSensors(HW, 16)
    for d in np.linspace(0.001, 0.012, 23):
        c0 = s.count(0, d)
        back = s.gaps((c0, c0))[0]
        step = s.gap_of_counts[0][c0 + 1] - s.gap_of_counts[0][c0]
        assert abs(back - d) <= 0.5 * step + 1e-15


def test_gap_counts_clip_at_the_ends_of_the_range():
    s = GapSensors(HW, 12)
    assert s.full == 4095
    assert s.count(1, -1.0) == 0 and s.out_of_range(0)
    assert s.count(1, 1.0) == 4095 and s.out_of_range(4095)
    assert not s.out_of_range(s.count(1, 0.0005))


def test_gain_and_offset_errors_are_applied_before_the_adc():
    s = GapSensors(HW, 16, gain_error=0.1, offset_error=1e-4)
    assert s.sensed(0, 0.008) == pytest.approx(1.1 * 0.008 + 1e-4)


def test_a_calibration_that_is_not_increasing_is_refused():
    hw = {**HW, "gap2_c1": -2.5e-7}
    with pytest.raises(SafetyError, match="gap2_c"):
        GapSensors(hw, 16)


def test_current_counts_and_back():
    s = CurrentSensors(HW, 16)
    i = np.array([4.0, -2.5])
    back = s.currents(s.counts(i))
    np.testing.assert_allclose(back, i, atol=0.5 * HW["current1_gain"])
    assert s.counts(np.array([1e3, -1e3])) == (65535, 0)


def test_bus_sags_with_the_coil_currents():
    d = CoilDrivers(200.0, 0.5, 16, 9.0)
    assert d.bus(4.0, -4.0) == 196.0
    assert d.bus(4.0, 4.0, supply=60.0) == 56.0
    assert d.bus(400.0, 0.0) == 0.0


def test_pwm_quantises_clips_to_the_bus_and_limits_the_current():
    d = CoilDrivers(200.0, 0.0, 4, 9.0)  # 3 bits of duty magnitude: steps of bus / 8
    u = d.apply(np.array([80.0, 300.0]), 200.0, np.array([4.0, 4.0]))
    np.testing.assert_array_equal(u, [75.0, 200.0])  # 80 V -> 3/8 of 200 V; 300 V clipped at the bus
    u = d.apply(np.array([80.0, -80.0]), 200.0, np.array([9.5, 9.5]))
    np.testing.assert_array_equal(u, [0.0, -75.0])  # above the current limit: no positive voltage
    u = d.apply(np.array([80.0, 80.0]), 200.0, np.array([4.0, 4.0]), failed=(False, True))
    np.testing.assert_array_equal(u, [75.0, 0.0])  # an open bridge applies nothing
    np.testing.assert_array_equal(d.apply(np.array([80.0, 80.0]), 0.0, np.zeros(2)), [0.0, 0.0])
