"""The board that drives the coils: its limits, held commands, stopping-distance trip, landing observer and law,
gap plausibility check, and the rig's sensor and actuator models (docs/manual/board.md).

One file per job, the order a port follows (``firmware/``):

* ``modes``: the modes (the device link's mode byte) and the configuration error;
* ``config``: the schema values the board reads, its tuning constants, the kernels' parameter vector;
* ``observer``: the landing observer (gap, rate, missed acceleration per load point);
* ``landing``: the landing law (reference, gap loop, current loop);
* ``braking``: the stopping-distance bound and the brake;
* ``gapcheck``: the gap sensors' plausibility against the coils' fluxes;
* ``coil``: the coil model and the gaps from the coils' fluxes (lost sensors);
* ``sensor_loss``: what the board does with lost and implausible sensors;
* ``supervisor``: the mode machine that composes them (:class:`Supervisor`);
* ``rig_io``: the rig's sensor (ADC) and actuator (bus, PWM bridge) models, for the rig emulator.

Pure Python + numba, no middleware.
"""

from __future__ import annotations

from .config import (
    BIAS_BANDWIDTH,
    BOUND_MARGIN,
    CURRENT_BANDWIDTH,
    INNOVATION_LIMIT,
    LANDING_OVERSHOOT,
    OBS_BANDWIDTH,
    OUTER_BANDWIDTH,
    PLANT_KEYS,
    REF_ACCEL,
    SAFETY_KEYS,
    SENSOR_BLIND_SAMPLES,
    SPEED_FRACTION,
)
from .modes import Mode, SafetyError
from .observer import observer_gains
from .supervisor import Supervisor

__all__ = [
    "BIAS_BANDWIDTH",
    "BOUND_MARGIN",
    "CURRENT_BANDWIDTH",
    "INNOVATION_LIMIT",
    "LANDING_OVERSHOOT",
    "OBS_BANDWIDTH",
    "OUTER_BANDWIDTH",
    "PLANT_KEYS",
    "REF_ACCEL",
    "SAFETY_KEYS",
    "SENSOR_BLIND_SAMPLES",
    "SPEED_FRACTION",
    "Mode",
    "SafetyError",
    "Supervisor",
    "observer_gains",
]
