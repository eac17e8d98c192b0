"""The board's modes (the device link's mode byte) and its configuration error (docs/manual/board.md, "Modes")."""

from __future__ import annotations

import enum

__all__ = ["Mode", "SafetyError"]


class Mode(enum.IntEnum):
    """Board mode; the values are the device link's mode byte (``dem_ros.hardware.link`` imports this)."""

    OFF = 0  # no current in the coils (plate resting on its support, or not started)
    RUN = 1  # applying the commanded voltages, clipped to u_max
    HOLD = 2  # a command is late: the last one is held, at most hold_timeout
    LAND = 3  # the landing law lowers the plate away from the rail at <= landing_speed (also after a trip or e-stop)
    LANDED = 4  # on the support at landing_gap, current removed
    FAULT = 5  # a non-finite gap or current: nothing left to control with, 0 V (latched)


class SafetyError(ValueError):
    """An invalid supervisor configuration; the message names the field."""
