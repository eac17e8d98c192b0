r"""The rig emulator's gap-sensor curves and shims: what ``dem-ros calibrate gaps`` has to find.

A gap sensor does not follow its data sheet. The emulator's sensor j reads, for a true gap d [m]::

    s_j(d) = (1 + gain_error) d + offset_error + a c_j(x),   x = (d - 8 mm) / 4 mm  (x in [-1, 1] over 4-12 mm)

    c_1(x) = (1 - x^2)(1 + 0.3 x)          a bow, zero at 4 and 12 mm
    c_2(x) = sin(pi x / 2) - 0.4 x^2       an S-curve with a tilt (not a polynomial)

with a = ``rig.gap_curve`` [m] (the curves are the board's sensor model: :func:`dem_ros.board.rig_io.curve_deviation`)
(0: the data sheet's linear errors only); the board's ADC then produces the count whose data-sheet gap
(``hw_driver.gap{j}_c*``) is nearest to s_j(d) (:class:`dem_ros.hardware.rig.Board`).
The curve is monotonic for a < 1.3 mm (ds/dd > 0).

Shims: ``Board.shims`` = (d1, d2) [m] rests the plate on shims of those thicknesses (coils off, gaps held);
``None``: the plate is free. :class:`ShimInput` sets them from lines on a stream (the emulator's stdin):
``shims 6`` (both ends, mm), ``shims 6,6.5``, ``shims off``: the operator's hands in an emulated session.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from typing import IO, Any

import numpy as np

from ..board.rig_io import HALF, MID, curve_deviation

__all__ = ["HALF", "MID", "ShimInput", "curve_deviation", "parse_shims", "sensed_gap"]


def sensed_gap(j: int, d: float | np.ndarray, rig: Mapping[str, Any]) -> float | np.ndarray:
    """s_j(d) [m]: what sensor j reports as a gap for the true gap d, before noise and the ADC."""
    if isinstance(d, float):
        return (1.0 + rig["gap_gain_error"]) * d + rig["gap_offset_error"] + curve_deviation(j, d, rig["gap_curve"])
    return (1.0 + rig["gap_gain_error"]) * np.asarray(d, float) + rig["gap_offset_error"] + \
        curve_deviation(j, d, rig["gap_curve"])


def parse_shims(text: str) -> tuple[float, float] | None:
    """``6`` | ``6,6.5`` (mm) -> (d1, d2) [m]; ``off`` -> None. ValueError with the accepted forms otherwise."""
    t = text.strip().lower()
    if t in ("off", "none", ""):
        return None
    try:
        v = [float(p) * 1e-3 for p in t.split(",")]
    except ValueError:
        v = []
    if len(v) == 1:
        v = v * 2
    if len(v) != 2 or not all(0.0 < x < 0.1 and math.isfinite(x) for x in v):
        raise ValueError(f"shims {text!r}: expected MM or MM1,MM2 (0 < mm < 100) or off")
    return v[0], v[1]


class ShimInput:
    """A daemon thread reading ``shims ...`` lines from ``stream`` and handing each to ``apply`` (None: off).

    Other lines are reported through ``say`` and ignored; it ends at the stream's end.
    """

    def __init__(self, stream: IO[str], apply: Callable[[tuple[float, float] | None], None],
                 say: Callable[[str], None]):
        self._stream, self._apply, self._say = stream, apply, say
        self.thread = threading.Thread(target=self._run, name="shims", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        for line in self._stream:
            head, _, rest = line.strip().partition(" ")
            if head != "shims":
                if line.strip():
                    self._say(f"ignored input {line.strip()!r}: expected 'shims MM[,MM]' or 'shims off'")
                continue
            try:
                self._apply(parse_shims(rest))
            except ValueError as exc:
                self._say(str(exc))
