"""Lost and implausible sensors (docs/manual/board.md, "Lost sensor samples" and "A plausible but wrong gap
reading"): what the supervisor does with a channel that gives nothing, or a gap sensor the coils' fluxes
contradict: ride on, land on the coil model or a coil's flux, or FAULT (0 V). A part of :class:`Supervisor`."""

from __future__ import annotations

import numpy as np

from .coil import CoilModel
from .config import _K, _P, _Q, FLUX_CHECK_SAMPLES, FLUX_GAP_MIN_CURRENT, SENSOR_BLIND_SAMPLES, SENSOR_NAMES
from .gapcheck import GapCheck
from .modes import Mode
from .observer import _deltas

__all__ = ["SensorLosses"]


class SensorLosses:
    """The supervisor's decisions on lost and implausible sensors (its state is the supervisor's, declared here)."""

    _p: np.ndarray
    _i_last: tuple[float, float]
    _blind: list[int]
    _loss_counted: list[bool]
    _gated: np.ndarray
    _check: GapCheck
    _obs_ready: bool
    coil: CoilModel
    estimate: np.ndarray
    mode: Mode
    reason: str
    fault: str
    counters: dict[str, int]
    implausible: list[bool]
    u: np.ndarray

    def _trip(self, reason: str) -> None:
        raise NotImplementedError  # the supervisor's: latch the fault and land

    def _lost_channels(self, ok: tuple[bool, ...]) -> str:
        """Channels without a finite sample for more than SENSOR_BLIND_SAMPLES (RUN, HOLD, LAND): land on the
        coil model (a current), on the coil's flux (a gap), wait for the flux landing's inputs (at most
        2 x SENSOR_BLIND_SAMPLES in all), or return the reason for FAULT ("" when none; docs/manual/board.md)."""
        B = SENSOR_BLIND_SAMPLES
        blind = self._blind
        for j in (0, 1):  # a gap from its coil's flux must keep coming: else that end is blind, open loop
            if self.coil.flux_gap[j] and blind[j] > B and self.mode != Mode.LANDED:
                if blind[2 + j] > B:
                    self._count_loss(2 + j)
                    cause = f"{SENSOR_NAMES[2 + j]} lost too (no finite sample for {blind[2 + j]} samples)"
                elif blind[1 - j] > 0:
                    cause = f"{SENSOR_NAMES[1 - j]} without a finite sample for {blind[1 - j]} samples"
                else:
                    cause = (f"coil {j + 1}'s current {self._i_last[j]:.2f} A at or under FLUX_GAP_MIN_CURRENT = "
                             f"{FLUX_GAP_MIN_CURRENT:g} A")
                return (f"{SENSOR_NAMES[j]} lost, gap {j + 1} from coil {j + 1}'s flux: none for {blind[j]} "
                        f"samples (> {B}): {cause}; "
                        f"no landing without gap {j + 1}: 0 V, the plate drops onto its support")
        for n in (0, 1):
            if self.coil.flux_gap[n] or blind[n] <= B:
                continue
            k = 1 - n
            lost = f"{SENSOR_NAMES[n]} lost: no finite sample for {blind[n]} samples (> {B})"
            drop = "no landing without it: 0 V, the plate drops onto its support"
            if self.coil.flux_gap[k]:
                why = f"gap {k + 1} already from coil {k + 1}'s flux"
            elif blind[k] > B:
                why = f"{SENSOR_NAMES[k]} lost too"
            elif blind[2 + n] > B:
                why = f"{SENSOR_NAMES[2 + n]} lost too: no flux for gap {n + 1}"
            elif ok[2 + n] and abs(self._i_last[n]) <= FLUX_GAP_MIN_CURRENT:
                why = (f"coil {n + 1}'s current {self._i_last[n]:.2f} A at or under FLUX_GAP_MIN_CURRENT = "
                       f"{FLUX_GAP_MIN_CURRENT:g} A: its flux tells too little of gap {n + 1}")
            elif blind[k] == 0 and ok[2 + n]:
                # the other gap and this coil's current measured: land on the coil's flux
                # its flux starts at this sample's current and the observer's gaps (which rode the blind samples)
                de = _deltas(self._p, self.estimate[0, 0], self.estimate[0, 1])
                self.coil.start_flux(n, 2.0 * self._p[_K] * self._i_last[n] / de[n], self._i_last[n])
                blind[n] = 0
                self._count_loss(n)
                why = f"{lost}: landing on gap {n + 1} from coil {n + 1}'s flux"
                if self.mode == Mode.LAND:
                    self.fault = self.fault or why
                else:
                    self._trip(why)
                continue
            elif blind[n] > 2 * B:
                why = (f"no sample of {SENSOR_NAMES[k]} and {SENSOR_NAMES[2 + n]} together within "
                       f"{blind[n]} samples (> {2 * B}) to start the flux landing from")
            else:
                continue  # the other gap or this current only briefly blind: ride on the observer, decide again
            self._count_loss(n)
            return f"{lost}; {why}; {drop}"
        for n in (2, 3):
            if blind[n] > B and not self._loss_counted[n]:  # a current sensor: land on the coil model
                self._count_loss(n)
                if self.mode in (Mode.RUN, Mode.HOLD):
                    self._trip(f"{SENSOR_NAMES[n]} lost: no finite sample for {blind[n]} samples "
                               f"(> {B}): landing on the board's coil model")
        return ""

    def _implausible(self, n: int, y0: float, y1: float, i0: float, i1: float) -> tuple[float, float]:
        """Gap sensor n reads what the coils' fluxes contradict (GapCheck): ignored from now on, and the
        plate lands with gap n from coil n's flux, which starts at the check's flux estimate (the measured
        flux followed the wrong reading). Returns the gaps of this sample, gap n from that flux."""
        c = self._check
        y = [y0, y1]
        read, flux, tol = y[n], float(c.y_flux[n]), float(c.tol[n])
        i_n = i0 if n == 0 else i1
        self.implausible[n] = True
        self.coil.start_flux(n, c.lam[n], i_n)
        self.coil.r_est[n] = c.r[n]  # the check's slow resistance: the coil model's has begun to follow the wrong gap
        self._count_loss(n)
        self.counters["implausible"] += 1
        y[n] = (2.0 * self._p[_K] * i_n / c.lam[n] - self._p[_Q] * y[1 - n]) / self._p[_P]
        # the observer followed the wrong reading: end n restarts from the flux (the landing starts from it)
        self.estimate[0, n] = y[n]
        self.estimate[1, n] = c.v_flux[n]
        self._gated[n] = 0.0
        c.restart_sensor(n)
        why = (f"{SENSOR_NAMES[n]} implausible: reads {read * 1e3:.3f} mm, the coil fluxes say {flux * 1e3:.3f} mm "
               f"(off by more than {tol * 1e3:.3f} mm for {FLUX_CHECK_SAMPLES} samples): landing on gap {n + 1} "
               f"from coil {n + 1}'s flux")
        if self.mode == Mode.LAND:
            self.fault = self.fault or why
        else:
            self._trip(why)
        return y[0], y[1]

    def _both_implausible(self, bad: int, y0: float, y1: float) -> np.ndarray:
        """Both gap sensors contradict the coils' fluxes, at once (bad = 2) or one after the other (the first
        already a flux gap): no gap left to land with (docs/manual/board.md): FAULT, 0 V (the plate falls away from
        the rail onto its support, whatever the sensors read)."""
        c = self._check
        new = (0, 1) if bad == 2 else (bad,)
        what = "at once" if bad == 2 else f"after gap sensor {2 - bad}"
        why = (f"gap sensors 1 and 2 implausible ({what}): read {y0 * 1e3:.3f}, {y1 * 1e3:.3f} mm, the coil fluxes "
               f"say {c.y_flux[0] * 1e3:.3f}, {c.y_flux[1] * 1e3:.3f} mm; no landing without a gap: 0 V, the plate "
               f"drops onto its support")
        for n in new:
            self.implausible[n] = True
            self._count_loss(n)
            self.counters["implausible"] += 1
        self.counters["trips"] += 1
        self.fault = self.reason = why
        self.mode = Mode.FAULT
        self.u = np.zeros(2)
        return self.u

    def _count_loss(self, n: int) -> None:
        """``sensor_losses`` counts each channel given up once (until it gives a finite sample again)."""
        if not self._loss_counted[n]:
            self._loss_counted[n] = True
            self.counters["sensor_losses"] += 1

    def _sensor_gap(self, t_ns: int, ok: tuple[bool, ...], raw: tuple[float, ...]) -> bool:
        """A non-finite or missing sample on some channel: counted; True when the board can do nothing but
        FAULT with 0 V (the plate on its support, or no estimate yet); False: carry on with the observer /
        coil model for that channel (``step`` faults after SENSOR_BLIND_SAMPLES in a row)."""
        self.counters["sensor_gaps"] += 1
        if self._blind[0] == 0 and self._blind[1] == 0 and self._blind[2] == 0 and self._blind[3] == 0:
            self.counters["sensor_gap_events"] += 1
        resting = self.mode in (Mode.OFF, Mode.LANDED, Mode.FAULT)
        if not (resting or not self._obs_ready):
            return False
        if self.mode != Mode.FAULT:
            why = ("the plate is on its support" if resting else "no estimate possible")
            self.fault = self.fault or (f"non-finite sensor reading (gaps {raw[0]!r}, {raw[1]!r}; currents "
                                        f"{raw[2]!r}, {raw[3]!r}): {why}")
            self.reason = self.fault
            self.counters["trips"] += 1
        self.mode = Mode.FAULT
        self.u = np.zeros(2)
        return True

