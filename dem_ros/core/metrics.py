"""Tracking metrics of a run: the numbers the report, the CLI and the tests compare.

All errors are e = true gap - reference-model output y_m (docs/manual/scenarios.md), reported in
micrometres; voltages in V, currents in A.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

__all__ = ["Run", "error_metrics", "tracking_metrics"]


class Run(Protocol):
    """What :func:`tracking_metrics` reads of a run: a :class:`~dem_ros.core.simulate.SimResult`."""

    @property
    def scenario(self) -> str: ...
    @property
    def controller(self) -> str: ...
    @property
    def estimator(self) -> str: ...
    @property
    def failed(self) -> bool: ...
    @property
    def fail_time(self) -> float | None: ...  # s
    @property
    def t(self) -> np.ndarray: ...  # (N,) s
    @property
    def error(self) -> np.ndarray: ...  # (N, 2) m
    @property
    def u(self) -> np.ndarray: ...  # (N, 2) V
    @property
    def x(self) -> np.ndarray: ...  # (N, 6) m, m/s, A
    @property
    def extra(self) -> dict[str, Any]: ...
    @property
    def wall_time(self) -> float: ...  # s


def error_metrics(t: np.ndarray, e: np.ndarray, after: float = 40.0) -> dict[str, list[float]]:
    """RMS and max |e| per output over the run, and RMS over t >= ``after`` (um)."""
    e = np.asarray(e, float)
    if e.size == 0:
        nan = [float("nan")] * 2
        return {"rms_error_um": nan, "max_error_um": nan, "rms_error_after_40s_um": nan}
    late = t >= after
    rms = np.sqrt(np.mean(e**2, axis=0)) * 1e6
    mx = np.max(np.abs(e), axis=0) * 1e6
    rms_late = np.sqrt(np.mean(e[late] ** 2, axis=0)) * 1e6 if late.any() else np.full(2, np.nan)
    return {
        "rms_error_um": [float(v) for v in rms],
        "max_error_um": [float(v) for v in mx],
        "rms_error_after_40s_um": [float(v) for v in rms_late],
    }


def tracking_metrics(res: Run) -> dict[str, Any]:
    """The metrics dict of a :class:`~dem_ros.core.simulate.SimResult` (keys of ``dem-ros sim --json``)."""
    out: dict[str, Any] = {
        "scenario": res.scenario,
        "controller": res.controller,
        "estimator": res.estimator,
        "failed": bool(res.failed),
        "fail_time_s": res.fail_time,
    }
    out.update(error_metrics(res.t, res.error))
    out["peak_voltage_v"] = float(np.max(np.abs(res.u))) if res.u.size else float("nan")
    out["peak_current_a"] = float(np.max(np.abs(res.x[:, 4:6]))) if res.x.size else float("nan")
    out["final_estimates"] = res.extra.get("final_estimates")
    out["duration_s"] = float(res.t[-1] + (res.t[1] - res.t[0])) if res.t.size > 1 else 0.0
    out["wall_time_s"] = float(res.wall_time)
    return out
