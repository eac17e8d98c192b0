"""The board's configuration as the device link carries it (docs/hardware-link.md, "Configuration").

- :func:`config_frame` packs it from the schema's values: the ``hw_driver`` group holds every one (the board's
  safety specs, nominal plant and ``dt``, the sensors' calibration, ``command_delay``). It is the one packing: the
  driver sends it over the link, and ``python -m dem_ros.hardware.cboard`` compiles the same values into the
  firmware's defaults (``board_config.h``), so a board built from a launch's parameters reports the CRC the PC expects.
- :func:`config_crc` is the configuration's CRC-32: the CRC field of its CONFIG frame.
- :func:`check_config` is the board's verdict on a configuration it received while OFF or LANDED, in the order and
  with the result codes of the firmware (``board.c``: the sample period, the calibration, ``sup_init()``'s checks,
  the command delay); :func:`sup_config_result` computes ``sup_init()``'s verdict as the firmware does (float32).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from .link import CONFIG_KEYS, CONFIG_RESULTS, CONFIG_SIZE, CONFIG_SUP_KEYS, ConfigFrame, encode

__all__ = [
    "ARMS",
    "BUSY",
    "DELAY",
    "GAP_ORDER",
    "MAX_COMMAND_DELAY",
    "NONFINITE",
    "NOT_POSITIVE",
    "NO_BRAKING",
    "OK",
    "RATE",
    "RESULT_TEXT",
    "BoardConfigError",
    "check_config",
    "config_crc",
    "config_frame",
    "f32",
    "python_sup_result",
    "result_text",
    "sup_config_result",
]

OK, NOT_POSITIVE, GAP_ORDER, ARMS, NO_BRAKING, NONFINITE, DELAY, RATE, BUSY = range(len(CONFIG_RESULTS))
#: the largest command delay a board takes: its command ring (16 samples, firmware BOARD_CMD_RING, the emulator's
#: CMD_RING) holds the commands answering samples k - d .. k
MAX_COMMAND_DELAY = 15
_BOUND_MARGIN = np.float32(0.25)  # the braking bound's model margin (dem_ros.board.BOUND_MARGIN, firmware BOUND_MARGIN)
_POSITIVE = ("u_max", "i_max", "hold_timeout", "landing_gap", "landing_speed", "m", "R", "K", "L", "l", "I", "dt")

RESULT_TEXT = {
    "ok": "accepted",
    "not_positive": "u_max, i_max, hold_timeout, landing_gap, landing_speed, m, R, K, L, l, I and dt must be positive",
    "gap_order": "need 0 <= trip_gap_min < landing_gap <= trip_gap_max",
    "arms": "l must be smaller than L",
    "no_braking": "no braking away from the rail: with N1, N2 the pull away from the rail at an end is not > 0",
    "nonfinite": "a value is not a finite number (float32)",
    "delay": f"command_delay must be 1 to {MAX_COMMAND_DELAY} samples (the board's command ring)",
    "rate": "dt is not the board's sample period (a board does not change its clock over the link)",
    "busy": "the board is levitating or faulted: it takes a configuration only while OFF or LANDED",
}
"""What each :data:`~dem_ros.hardware.link.CONFIG_RESULTS` code means, in words."""


class BoardConfigError(ValueError):
    """The schema's values cannot be packed into the board's configuration; the message says why."""


def f32(x: float) -> float:
    """x rounded to the nearest float32 (what the board stores; inf and NaN stay)."""
    return float(np.float32(x))


def result_text(code: int) -> str:
    """``name: what it means`` of a result code."""
    name = CONFIG_RESULTS[code] if 0 <= code < len(CONFIG_RESULTS) else f"code {code}"
    return f"{name}: {RESULT_TEXT.get(name, 'unknown result')}"


def config_frame(values: Mapping[str, Any]) -> ConfigFrame:
    """The board's configuration from the schema's values (the one packing; module docstring).

    Args:
        values: :data:`~dem_ros.hardware.link.CONFIG_KEYS` and ``command_delay`` (the ``hw_driver`` group has them);
            extra keys are ignored but ``gap_table``, which must be empty.

    Returns:
        the CONFIG frame, its floats rounded to float32 as the board stores them.

    Raises:
        BoardConfigError: a value missing or not a number, one that does not fit a float32, or a gap table (the board
            converts gap counts with the polynomials ``gapJ_c0..c3`` only).
    """
    missing = [k for k in (*CONFIG_KEYS, "command_delay") if k not in values]
    if missing:
        raise BoardConfigError(f"the board's configuration lacks {', '.join(missing)}")
    if values.get("gap_table"):
        raise BoardConfigError("hw_driver.gap_table: the board converts gap counts with the polynomials gapJ_c0..c3 "
                               "only; fit one (dem-ros calibrate gaps --fit poly) for a run on a board")
    out = []
    for k in CONFIG_KEYS:
        v = values[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise BoardConfigError(f"the board's {k} = {v!r} is not a number")
        if math.isfinite(v) and abs(v) > float(np.finfo(np.float32).max):
            raise BoardConfigError(f"the board's {k} = {v!r} does not fit a float32")
        out.append(f32(v))
    delay = values["command_delay"]
    if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= 0xFF:
        raise BoardConfigError(f"the board's command_delay = {delay!r} is not an integer in [0, 255]")
    return ConfigFrame(tuple(out), delay)


def config_crc(frame: ConfigFrame) -> int:
    """The configuration's CRC-32: its CONFIG frame's CRC field (raises LinkError for a non-finite value)."""
    return int(struct.unpack_from("<I", encode(frame), CONFIG_SIZE - 4)[0])


def sup_config_result(sup: Sequence[float]) -> int:
    """The firmware's ``sup_init()`` verdict (0 or a ``sup_cfg_result`` code) on the 17 supervisor values
    (:data:`~dem_ros.hardware.link.CONFIG_SUP_KEYS`), its checks in its order in float32 arithmetic: non-finite,
    not positive, gap order, arms, then the braking bound's pull away from the rail at each end
    (``g + min(0, (1 + e) L L / I (N1 - N2))``, evaluated left to right as the C expression is)."""
    v = [np.float32(x) for x in sup]
    if len(v) != len(CONFIG_SUP_KEYS):
        raise ValueError(f"{len(v)} supervisor values, expected {len(CONFIG_SUP_KEYS)}")
    if not all(np.isfinite(x) for x in v):
        return NONFINITE
    c = dict(zip(CONFIG_SUP_KEYS, v, strict=True))
    if not all(c[k] > 0 for k in _POSITIVE):
        return NOT_POSITIVE
    if not 0 <= c["trip_gap_min"] < c["landing_gap"] <= c["trip_gap_max"]:
        return GAP_ORDER
    if not c["l"] < c["L"]:
        return ARMS
    k = (np.float32(1) + _BOUND_MARGIN) * c["L"] * c["L"] / c["I"]
    zero = np.float32(0)
    nb1 = c["g"] + min(zero, k * (c["N1"] - c["N2"]))
    nb2 = c["g"] + min(zero, k * (c["N2"] - c["N1"]))
    if not min(nb1, nb2) > 0:
        return NO_BRAKING
    return OK


def python_sup_result(sup: Sequence[float]) -> int:
    """The Python board's verdict on the 17 supervisor values: :func:`sup_config_result` (the firmware's checks),
    then the Python board's own validation (``dem_ros.board.config.kernel_vector``, float64), so it refuses what
    either refuses; a refusal of the latter alone (a value on a float32/float64 boundary) is given its rule's code."""
    r = sup_config_result(sup)
    if r != OK:
        return r
    from ..board import SafetyError
    from ..board.config import kernel_vector

    c = dict(zip(CONFIG_SUP_KEYS, sup, strict=True))
    try:
        kernel_vector(c, c["dt"])
    except SafetyError as exc:
        text = str(exc)
        for code, words in ((GAP_ORDER, "trip_gap_min"), (ARMS, "smaller than L"), (NO_BRAKING, "no braking")):
            if words in text:
                return code
        return NOT_POSITIVE
    return OK


def check_config(frame: ConfigFrame, board_dt: float,
                 sup_result: Callable[[Sequence[float]], int] = sup_config_result) -> int:
    """A board's verdict (a result code) on a configuration it received while OFF or LANDED, in the firmware's
    order: ``rate`` (dt is not ``board_dt``, the board's own sample period as it stores it), ``nonfinite`` (the
    calibration), the supervisor's (``sup_result``: ``sup_init()``'s code; the C board's own through the ctypes
    binding), ``delay`` (outside 1..:data:`MAX_COMMAND_DELAY`). 0: the board takes it."""
    v = frame.values
    dt = v[CONFIG_SUP_KEYS.index("dt")]
    if f32(dt) != f32(board_dt):  # (NaN: differs too)
        return RATE
    if not all(math.isfinite(x) for x in v[len(CONFIG_SUP_KEYS):]):
        return NONFINITE
    r = sup_result(v[:len(CONFIG_SUP_KEYS)])
    if r != OK:
        return r
    if not 1 <= frame.command_delay <= MAX_COMMAND_DELAY:
        return DELAY
    return OK

