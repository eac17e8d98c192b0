"""One row of ``dem-ros faults``: :class:`FaultSpec` (what the catalogue, the injector and the judges share)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["FaultSpec"]


@dataclass(frozen=True)
class FaultSpec:
    """One row of the catalogue: a message injection (``act``, ``n`` samples) or a SIGKILL of ``kill``
    (restarted after ``restart_after`` s; None: not restarted). ``allowed``: outcomes that pass."""

    name: str
    description: str
    act: Callable[[Any], None] | None = None  # called with the row's inject.Injector (this module imports none)
    n: int = 1
    kill: str | None = None
    restart_after: float | None = None
    allowed: tuple[str, ...] = ("levitating",)
    composed: bool = True  # also run composed (a kill needs a process per node)
    min_duration: float = 0.0  # s: a restarted node needs seconds to start (imports, kernels, discovery)
    disk_kib: int = 0  # record onto a tmpfs of this size (KiB; root), the logs elsewhere: the disk fills mid-run
    # hardware rows (RIG_CATALOGUE: hw_driver and the emulated board, `dem-ros launch --hardware rig`)
    hardware: bool = False
    rig_fault: str | None = None  # a `dem-ros rig --fault` spec; {t}: the fault's time on the board's clock
    reports: tuple[str, ...] = ()  # one of these words in a WARN/ERROR status or log line after the fault
    counts: tuple[tuple[str, str, int], ...] = ()  # (driver | board | estimator, counter, at least): who counted it
    descent_bounded: bool = True  # a landing must stay within landing_speed (the emulator's truth)
