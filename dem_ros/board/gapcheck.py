"""The gap plausibility (flux) check (docs/manual/board.md, "A plausible but wrong gap reading"): each gap sensor
against the gap the coils' fluxes give."""

from __future__ import annotations

import math

import numpy as np

from .config import (
    _K,
    _P,
    _Q,
    BOUND_MARGIN,
    FLUX_CHECK_ARM,
    FLUX_CHECK_FILTER,
    FLUX_CHECK_MIN,
    FLUX_CHECK_NOISE_TIME,
    FLUX_CHECK_R_TIME,
    FLUX_CHECK_SAMPLES,
    FLUX_CHECK_SETTLE,
    FLUX_CHECK_SIGMAS,
    FLUX_CHECK_TIME,
    FLUX_GAP_MIN_CURRENT,
)

__all__ = ["GapCheck"]


class GapCheck:
    """The gap sensors' plausibility against the coils' fluxes (docs/manual/board.md, "A plausible but
    wrong gap reading"). Per coil j a flux estimate integrated from the voltage applied,
    lam_j += T (u_j - R_j i_j), pulled toward the measured flux 2K i_j / delta_j (delta from the two gap readings)
    with FLUX_CHECK_TIME; per gap
    sensor the difference between its reading and the gap the two flux estimates give, low-passed, against a
    tolerance: FLUX_CHECK_MIN, plus what a magnet BOUND_MARGIN off its datasheet K explains of the recent flux
    change, plus FLUX_CHECK_SIGMAS times the difference's own noise level (learned while within tolerance)."""

    def __init__(self, p: np.ndarray, dt: float):
        # plain floats: the 1 kHz path does 2 x 2 arithmetic, where numpy's per-call overhead is most of the cost
        self.dt, self.K2, self.P, self.Q = float(dt), 2.0 * float(p[_K]), float(p[_P]), float(p[_Q])
        inv = np.linalg.inv(np.array([[self.P, self.Q], [self.Q, self.P]]))  # magnet gaps -> sensor gaps
        self.m_inv = ((float(inv[0, 0]), float(inv[0, 1])), (float(inv[1, 0]), float(inv[1, 1])))
        self.k_margin = BOUND_MARGIN / (1.0 - BOUND_MARGIN)  # flux change a magnet off by BOUND_MARGIN hides
        self.n_arm = round(FLUX_CHECK_ARM / dt)
        self.reset()

    def reset(self) -> None:
        self.n = [0, 0]  # samples each coil's flux estimate has been corrected (0: not started)
        # per coil / per sensor, plain lists of floats (the 1 kHz path: numpy's per-element overhead is not worth it)
        self.lam = [0.0, 0.0]  # flux estimates [V s]
        self.lam_lp = [0.0, 0.0]  # the measured flux, low-passed like the estimate's correction [V s]
        self.r = [0.0, 0.0]  # the resistance the estimate integrates with [ohm]
        self.i_prev = [0.0, 0.0]
        self.dy = [0.0, 0.0]  # sensor reading - flux gap, low-passed [m]
        self.var = [0.0, 0.0]  # its noise level [m^2]
        self.tol = [math.inf, math.inf]  # the last tolerance [m]
        self.over = [0, 0]  # samples in a row beyond it
        self.armed = False  # settled: FLUX_CHECK_ARM of samples, then both differences within FLUX_CHECK_MIN / 3
        self.settled = 0  # for this many samples in a row (arming takes FLUX_CHECK_SETTLE of them)
        self.sum_sq = [0.0, 0.0]  # their squares meanwhile: the first noise level [m^2]
        self.calm = True  # both differences within half their tolerance at the last sample
        self.y_flux = [math.nan, math.nan]  # the gaps the flux estimates give [m]
        self.v_flux = [0.0, 0.0]  # their rates, low-passed [m/s]

    def restart_sensor(self, n: int) -> None:
        """Sensor n was given up (its gap now comes from coil n's flux): its difference starts again at zero,
        the other sensor stays checked against both coils' fluxes."""
        self.dy[n] = 0.0
        self.over = [0, 0]

    def step(self, y0: float, y1: float, i: tuple[float, float], i_ok: tuple[bool, bool], u: np.ndarray,
             r_model: np.ndarray, given_up: tuple[bool, bool] = (False, False)) -> int:
        """One sample: gaps (NaN: none), currents i (2,) [A] (the coil model's where i_ok is False), the voltages
        applied over the last period u (2,) [V], the coil model's resistances; ``given_up``: sensors whose gap
        is already their coil's flux gap (never declared again). Returns the gap sensor newly found implausible
        (0, 1), 2 for both at once, -1 for none."""
        T, K2, P, Q = self.dt, self.K2, self.P, self.Q
        gaps = math.isfinite(y0) and math.isfinite(y1)
        de = (P * y0 + Q * y1, Q * y0 + P * y1) if gaps else (math.nan, math.nan)
        lam_m = [math.nan, math.nan]
        for j in (0, 1):
            measured = gaps and i_ok[j] and abs(i[j]) > FLUX_GAP_MIN_CURRENT and de[j] > 0.0
            if measured:
                lam_m[j] = K2 * i[j] / de[j]
            if self.n[j] == 0:
                if measured:
                    self.lam[j] = self.lam_lp[j] = lam_m[j]
                    self.r[j] = float(r_model[j])
                    self.i_prev[j] = i[j]
                    self.n[j] = 1
                continue
            self.lam[j] += T * (float(u[j]) - self.r[j] * 0.5 * (self.i_prev[j] + i[j]))
            self.i_prev[j] = i[j]
            if measured:
                a = T / FLUX_CHECK_TIME
                self.lam[j] += a * (lam_m[j] - self.lam[j])
                self.lam_lp[j] += a * (lam_m[j] - self.lam_lp[j])
                self.n[j] += 1
            if not self.armed:
                self.r[j] = float(r_model[j])  # settling: follow the coil model's resistance
            elif self.calm:
                self.r[j] += T / FLUX_CHECK_R_TIME * (float(r_model[j]) - self.r[j])
        if not (math.isfinite(self.lam[0]) and math.isfinite(self.lam[1])) or min(self.lam[0], self.lam[1]) <= 0.0:
            self.reset()  # a non-finite voltage or current, or a flux through zero: start again
            return -1
        if not (math.isfinite(lam_m[0]) and math.isfinite(lam_m[1])) or min(self.n) == 0:
            return -1  # no sample to compare: the counts of samples beyond the tolerance wait for the next
        d0, d1 = K2 * i[0] / self.lam[0], K2 * i[1] / self.lam[1]  # the fluxes' magnet gaps
        (m00, m01), (m10, m11) = self.m_inv
        y_flux = (m00 * d0 + m01 * d1, m10 * d0 + m11 * d1)
        b = T / FLUX_CHECK_FILTER
        for s in (0, 1):
            if math.isfinite(self.y_flux[s]):
                self.v_flux[s] += b * ((y_flux[s] - self.y_flux[s]) / T - self.v_flux[s])
            self.y_flux[s] = y_flux[s]
        allow = [self.k_margin * abs((lam_m[j] - self.lam_lp[j]) / lam_m[j]) * de[j] for j in (0, 1)]
        armed = self.armed
        v = T / FLUX_CHECK_NOISE_TIME
        for s, ys in ((0, y0), (1, y1)):
            self.dy[s] += b * ((ys - self.y_flux[s]) - self.dy[s])
        if not armed:
            if min(self.n) > self.n_arm and max(abs(self.dy[0]), abs(self.dy[1])) < FLUX_CHECK_MIN / 3.0:
                self.settled += 1
                self.sum_sq = [self.sum_sq[0] + self.dy[0] ** 2, self.sum_sq[1] + self.dy[1] ** 2]
                if self.settled >= FLUX_CHECK_SETTLE:
                    self.armed = True
                    self.var = [self.sum_sq[0] / self.settled, self.sum_sq[1] / self.settled]
            else:
                self.settled = 0
                self.sum_sq = [0.0, 0.0]
            return -1
        calm = True
        for s in (0, 1):
            if given_up[s]:
                self.over[s] = 0
                continue
            row = self.m_inv[s]
            self.tol[s] = (FLUX_CHECK_MIN + abs(row[0]) * allow[0] + abs(row[1]) * allow[1]
                           + FLUX_CHECK_SIGMAS * math.sqrt(self.var[s]))
            if abs(self.dy[s]) > self.tol[s]:
                self.over[s] += 1
                calm = False
                continue
            self.over[s] = 0
            if abs(self.dy[s]) < 0.5 * self.tol[s]:  # the noise level, not a growing difference
                self.var[s] += v * (self.dy[s] ** 2 - self.var[s])
            else:
                calm = False
        self.calm = calm
        bad = [s for s in (0, 1) if self.over[s] >= FLUX_CHECK_SAMPLES]
        if not bad:
            return -1
        if len(bad) == 2 or self.over[1 - bad[0]] > 0:
            return 2
        return bad[0]
