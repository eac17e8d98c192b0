"""dem_ros.core.calibration: the shim-session fits, against exact polynomials and against the rig emulator's
nonlinear sensor curves (the board resting on shims, its frames decoded: no process, no clock)."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.core.calibration import CalibrationError, ShimPoint, fit_sensor, points_from_rows, table_rows
from dem_ros.core.params import default_config
from dem_ros.hardware.driver import Calibration
from dem_ros.hardware.link import HELLO_REQUEST, decode, encode
from dem_ros.hardware.rig import Board
from dem_ros.hardware.sensors import curve_deviation, parse_shims, sensed_gap

SHIMS_MM = (4, 5, 6, 7, 8, 9, 10, 11, 12)
#: the emulated rig's sensors: 300 um curves, 2 % gain and 40 um offset errors against their data sheet
RIG = {"start": "landed", "gap_curve": 3e-4, "gap_gain_error": 0.02, "gap_offset_error": 4e-5, "gap_noise": 2e-6}


def test_a_cubic_is_recovered_exactly_in_the_drivers_form():
    c = np.array([1e-4, 2.4e-7, 9e-13, -4e-18])
    n = np.linspace(15000, 50000, 9)
    g = c[0] + n * (c[1] + n * (c[2] + n * c[3]))
    pts = [ShimPoint(float(x), (float(k), float(k))) for x, k in zip(g, n, strict=True)]
    f = fit_sensor(pts, 1)
    assert f.coeffs == pytest.approx(c, rel=1e-6)
    assert f.rms < 1e-12 and f.monotonic
    cal = Calibration(default_config()["hw_driver"] | {f"gap1_c{p}": f.coeffs[p] for p in range(4)})
    assert cal.gap([30000, 30000])[0] == pytest.approx(f.gap(30000.0), rel=1e-12)  # the driver reads it alike


def shim_session(rig=RIG, samples=200):
    """The emulator's board resting on each shim (both ends), its sensor frames decoded and averaged."""
    cfg = default_config()
    cfg["rig"].update(rig)
    b = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"])
    b.receive(encode(HELLO_REQUEST))
    pts = []
    for mm in SHIMS_MM:
        b.shims = parse_shims(str(mm))
        c = np.array([decode(b.tick()).gap_counts for _ in range(samples)], float)
        assert b.plant.x[0] == b.plant.x[2] == pytest.approx(mm * 1e-3)  # resting on them, coils off
        pts.append(ShimPoint(mm * 1e-3, (float(c[:, 0].mean()), float(c[:, 1].mean()))))
    return b, cfg, pts


def true_counts(b: Board, j: int, d: np.ndarray) -> np.ndarray:
    """The counts sensor j produces at the true gaps d without noise (the board's ADC)."""
    return np.array([b.gap_sensors.count(j - 1, float(sensed_gap(j, float(x), b.rc))) for x in d], float)


@pytest.mark.parametrize("kind", ["poly", "table"])
def test_fits_recover_the_emulators_nonlinear_curves_within_10_um_rms_over_4_to_12_mm(kind):
    b, _cfg, pts = shim_session()
    d = np.linspace(4e-3, 12e-3, 801)
    for j in (1, 2):
        f = fit_sensor(pts, j, kind)
        n = true_counts(b, j, d)
        rms = float(np.sqrt(np.mean((f.gap(n) - d) ** 2)))
        sheet = float(np.sqrt(np.mean((b.gap_sensors.gap_of_counts[j - 1][n.astype(int)] - d) ** 2)))
        print(f"sensor {j} {kind}: {rms * 1e6:.2f} um RMS (data sheet: {sheet * 1e6:.0f} um)")
        assert rms <= 10e-6 and f.monotonic and f.rms <= 10e-6
        assert sheet > 100e-6  # the curve is there: the data sheet alone is far off


def test_the_two_sensors_have_different_curves():
    d = np.linspace(4e-3, 12e-3, 9)
    c1, c2 = curve_deviation(1, d, 1e-4), curve_deviation(2, d, 1e-4)
    assert np.max(np.abs(c1 - c2)) > 5e-5
    assert curve_deviation(1, 5e-3, 1e-4) == pytest.approx(float(curve_deviation(1, np.array([5e-3]), 1e-4)[0]))


def test_the_table_covers_the_adc_and_extends_beyond_the_session():
    _b, _cfg, pts = shim_session()
    fits = [fit_sensor(pts, j, "table") for j in (1, 2)]
    rows = table_rows(fits)
    assert rows[0, 0] == 0 and rows[-1, 0] == 65535 and np.all(np.diff(rows[:, 0]) > 0)
    assert np.all(np.diff(rows[:, 1]) > 0) and np.all(np.diff(rows[:, 2]) > 0)  # beyond 12 mm still rising


def test_counts_falling_with_the_gap_a_missing_shim_and_a_turning_fit_are_reported():
    pts = [ShimPoint(mm * 1e-3, (40000 - 1000 * mm, 20000 + 2000 * mm)) for mm in SHIMS_MM]
    with pytest.raises(CalibrationError, match="sensor 1: the counts do not increase"):
        fit_sensor(pts, 1)
    assert fit_sensor(pts, 2).monotonic
    with pytest.raises(CalibrationError, match="needs at least 5"):
        fit_sensor(pts[:4], 2)
    # steep, flat, steep (a misplaced shim, or a sensor a cubic cannot follow): the fit turns back in the range
    n = [20000, 21000, 22000, 50000, 51000, 52000]
    turning = [ShimPoint(mm * 1e-3, (float(k), float(k))) for mm, k in zip((4, 6, 8, 8.2, 10, 12), n, strict=True)]
    f = fit_sensor(turning, 1)
    assert not f.monotonic and f.min_slope < 0
    with pytest.raises(CalibrationError, match="metres, not mm"):
        points_from_rows([[6.0, 1.0, 2.0]])
