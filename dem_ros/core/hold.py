"""Which command drives the coils over a sample period: the one rule the simulators and the boards share.

The command computed from sample j (the measurement of t_j) is held over [t_{j+d}, t_{j+d+1}) (zero-order
hold), d = ``command_delay`` samples; so over [t_k, t_{k+1}) the command of sample k - d applies. d = 1
gives the graph a full period to deliver it, d = 0 is the paper's (instantaneous) loop. The offline loop
(``simulate``), the simulated board (``plant_sim``) and the rig emulator's board (``dem-ros rig``) all ask
:func:`command_sample`; the command itself still passes the board (clipped, held or replaced by a landing).
"""

from __future__ import annotations

from numba import njit

__all__ = ["command_sample"]


@njit(cache=True)
def command_sample(k: int, delay: int) -> int:
    """The sample whose command is held over [t_k, t_{k+1}): k - delay (negative: before the first sample)."""
    return k - delay
