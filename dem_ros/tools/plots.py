"""Figures of a run (PNG, matplotlib Agg): the one plotting module of ``sim``, ``replay`` and ``report``.

A run's figures are drawn from one :class:`RunSignals` (what the figures need, each signal on its
own time base, all on the experiment clock: t = 0 where the scenario starts, after the closed-loop
pre-roll), built from an offline :class:`~dem_ros.core.simulate.SimResult` (:func:`plot_run`) or
from a recorded bag (``dem-ros replay``, :func:`dem_ros.tools.replay.plot_replay`). So a simulated
and a recorded run give the same figures with the same axes:

* ``tracking.png``: gaps d_j and reference-model outputs y_mj [mm];
* ``error.png``: tracking error e_j = d_j - y_mj [µm];
* ``inputs.png``: coil voltages u_j [V] and currents i_j [A];
* ``estimates.png``: m̂ [kg], R̂ [Ω], K̂ [1e-4 N m²/A²], with why m̂ need not meet m (:data:`MASS_NOTE`);
* ``mass.png``: the plate's true mass [kg], when it changes;
* ``loop.png`` (recorded runs): command latency [µs] and the plant's waits / deadline misses.

Every axis has its unit, tick labels are plain numbers (no offset notation), every figure's time
axes share one zero, and events (failure, landing) are labelled lines. The helpers
:func:`figure`, :func:`save`, :func:`caption` and :func:`overlay` serve the report's figures too.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "MASS_NOTE",
    "RunSignals",
    "caption",
    "figure",
    "mark_events",
    "mark_failure",
    "overlay",
    "plant_truth",
    "plot_run",
    "plot_signals",
    "run_signals",
    "save",
]

#: what a steady hover does and does not determine; printed under the figure that draws m_hat
MASS_NOTE = ("m_hat is not identifiable from a steady hover: the hover fixes only the force balance "
             "K_hat i^2/delta^2 = N + m_hat g/2 per magnet, a combination of m_hat and K_hat (dashed, where the truth "
             "is known: K_hat stays on it). m_hat moves towards m only while the reference excites the plate "
             "(steps, load changes); tracking does not need it to.")

#: the experiment clock, said under figures drawn from a recording
CLOCK_NOTE = "t = 0: start of the scenario, after the 1 s closed-loop pre-roll (the clock of the run's metrics)."


@dataclass
class RunSignals:
    """What the figures of one run draw. Times in s on the experiment clock (t = 0: scenario start).

    Attributes:
        title: names the run (``"S1 / adaptive / estimator kf"``).
        t: (N,) s, the time base of ``gaps``, ``ref``, ``current`` and ``mass``.
        gaps: (N, 2) gaps d1, d2 [m]: the true gaps, or the measured ones (``gap_source``).
        ref: (N, 2) reference-model outputs y_m1, y_m2 [m].
        gap_source: ``"true"`` or ``"measured"`` (a rig has no truth).
        u_t, u: (K,) s and (K, 2) coil voltages u1, u2 [V] (commanded).
        current: (N, 2) coil currents i1, i2 [A], or None.
        est_t, est: (L,) s and (L, 3) estimates m_hat [kg], R_hat [ohm], K_hat [N m^2/A^2], or None.
        mass: (N,) true mass of the plate [kg], or None.
        latency_t, latency_us: (K,) s and (K,) measurement recorded -> command recorded [µs], or None.
        loop_t, loop_misses: (P,) s and (P,) cumulative samples the plant waited for (lockstep) or
            missed (free-running), or None.
        lockstep: the plant waited for late commands (``loop_misses`` are waits, not misses).
        events: (t [s], label) drawn as labelled vertical lines on every figure (failure, landing).
        notes: extra caption lines under every figure (e.g. :data:`CLOCK_NOTE`).
        truth: the plant's true ``R`` [ohm], ``K`` [N m^2/A^2], load ``N`` [N] per magnet and ``g``
            [m/s^2] (a simulation), or None (a rig): drawn beside the estimates.
    """

    title: str
    t: np.ndarray
    gaps: np.ndarray
    ref: np.ndarray
    gap_source: str = "true"
    u_t: np.ndarray | None = None
    u: np.ndarray | None = None
    current: np.ndarray | None = None
    est_t: np.ndarray | None = None
    est: np.ndarray | None = None
    mass: np.ndarray | None = None
    latency_t: np.ndarray | None = None
    latency_us: np.ndarray | None = None
    loop_t: np.ndarray | None = None
    loop_misses: np.ndarray | None = None
    lockstep: bool = False
    events: list[tuple[float, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    truth: dict[str, float] | None = None


# -- helpers ---------------------------------------------------------------------------------------------------

def figure(rows: int = 1, cols: int = 1, h: float = 3.0) -> tuple[Any, Any]:
    """A figure of ``rows`` x ``cols`` axes sharing their time axis; plain tick labels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # plain tick labels: no "1e-8+3.2079e-4" offsets on nearly constant signals
    plt.rcParams["axes.formatter.useoffset"] = False
    fig, axes = plt.subplots(rows, cols, figsize=(8, h * rows), squeeze=False, sharex=True)
    return fig, axes[:, 0] if cols == 1 else axes


def caption(fig: Any, text: str) -> None:
    """A note under the axes, for what a figure cannot say by itself (wrapped to the figure's width)."""
    import textwrap

    width = int(16 * fig.get_figwidth())  # characters of 7.5 pt text per line
    text = "\n".join(textwrap.fill(par, width) for par in text.split("\n"))
    lines = text.count("\n") + 1
    fig.set_figheight(fig.get_figheight() + 0.16 * lines)
    fig.text(0.01, 0.005, text, fontsize=7.5, va="bottom", ha="left")
    fig.tight_layout(rect=(0, 0.16 * lines / fig.get_figheight() + 0.01, 1, 1))


def mark_events(axes: Iterable[Any], events: Sequence[tuple[float, str]]) -> None:
    """A labelled vertical line at each (t [s], label) on every axis; the label is drawn once, on the first."""
    colours = ("r", "darkorange", "purple", "k")
    for n, a in enumerate(axes):
        for k, (t, label) in enumerate(events):
            a.axvline(t, color=colours[k % len(colours)], lw=0.9, ls="-" if k == 0 else "--")
            if n == 0:
                a.annotate(label, xy=(t, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -3),
                           textcoords="offset points", va="top", ha="left", fontsize=7.5,
                           color=colours[k % len(colours)])


def mark_failure(axes: Iterable[Any], fail_time: float | None) -> None:
    """A labelled vertical line where the run failed (gap out of range or non-finite)."""
    if fail_time is not None:
        mark_events(axes, [(fail_time, f"failure at t = {fail_time:.3f} s")])


def save(fig: Any, path: Path) -> Path:
    """Write ``fig`` as PNG (creating the directory) and close it."""
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    if not fig.texts:  # a caption has laid the figure out already
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def overlay(ax: Any, t: np.ndarray, series: Iterable[tuple[str, np.ndarray]], scale: float = 1.0) -> None:
    """Several labelled signals on one axis, each scaled by ``scale`` (e.g. 1e3: m -> mm)."""
    for label, y in series:
        ax.plot(t[: len(y)], y * scale, label=label)
    ax.legend(loc="upper right", fontsize=8)


def _finite(a: np.ndarray | None) -> bool:
    return a is not None and a.size > 0 and bool(np.isfinite(a).any())


def _min_span(ax: Any, rel: float) -> None:
    """Widen the y-axis to at least ``rel`` of its centre value: a constant estimate is drawn as the flat line it is,
    not as a curve over its last digits."""
    lo, hi = ax.get_ylim()
    mid, half = (lo + hi) / 2, abs(lo + hi) / 2 * rel / 2
    if hi - lo < 2 * half:
        ax.set_ylim(mid - half, mid + half)


def _finish(fig: Any, ax: Sequence[Any], sig: RunSignals, what: str, path: Path, note: str = "") -> Path:
    """Title, time label, events, caption, save: the same for every figure of a run."""
    ax[0].set_title(f"{sig.title}: {what}")
    ax[-1].set_xlabel("t [s]")
    mark_events(ax, sig.events)
    text = "\n".join(x for x in [note, *sig.notes] if x)
    if text:
        caption(fig, text)
    return save(fig, path)


# -- the figures of a run --------------------------------------------------------------------------------------

def plot_signals(sig: RunSignals, out: Path, prefix: str = "dem-ros") -> list[Path]:
    """Every figure ``sig`` has the signals for, into ``out``; returns the files written.

    Drawing takes seconds per figure on a busy machine: progress goes to stderr as ``prefix: ...``.
    """
    from .progress import Progress

    with Progress(prefix, None) as bar:
        bar.stage(f"drawing the figures into {out}")
        return _plot_signals(sig, Path(out))


def _plot_signals(sig: RunSignals, out: Path) -> list[Path]:
    files = []
    src = "measured" if sig.gap_source == "measured" else "true"
    fig, ax = figure(2, 1)
    for j in range(2):
        ax[j].plot(sig.t, sig.gaps[:, j] * 1e3, label=f"{src} gap d{j + 1}")
        ax[j].plot(sig.t, sig.ref[:, j] * 1e3, "--", label=f"reference y_m{j + 1}")
        ax[j].set_ylabel(f"gap d{j + 1} [mm]")
        ax[j].legend(loc="lower right", fontsize=8)
    files.append(_finish(fig, ax, sig, "tracking (larger gap = further from the rail)", out / "tracking.png"))

    fig, ax = figure(1, 1)
    e = (sig.gaps - sig.ref) * 1e6
    ax[0].plot(sig.t, e[:, 0], lw=0.8, label="e1")
    ax[0].plot(sig.t, e[:, 1], lw=0.8, label="e2")
    ax[0].set_ylabel(f"e = d - y_m [µm] ({src} gap)")
    ax[0].legend(loc="upper right", fontsize=8)
    files.append(_finish(fig, ax, sig, "tracking error", out / "error.png"))

    if sig.u is not None and sig.u_t is not None:
        fig, ax = figure(2, 1)
        ax[0].plot(sig.u_t, sig.u[:, 0], lw=0.8, label="u1")
        ax[0].plot(sig.u_t, sig.u[:, 1], lw=0.8, label="u2")
        ax[0].set_ylabel("coil voltage u [V]")
        ax[0].legend(loc="upper right", fontsize=8)
        if sig.current is not None:
            ax[1].plot(sig.t, sig.current[:, 0], lw=0.8, label="i1")
            ax[1].plot(sig.t, sig.current[:, 1], lw=0.8, label="i2")
            ax[1].legend(loc="upper right", fontsize=8)
        else:
            ax[1].text(0.5, 0.5, "no current recorded", transform=ax[1].transAxes, ha="center", va="center")
        ax[1].set_ylabel("coil current i [A]")
        files.append(_finish(fig, ax, sig, "coil voltages (commanded) and currents", out / "inputs.png"))

    if sig.est is not None and sig.est_t is not None and _finite(sig.est[:, :3]):
        fig, ax = figure(3, 1, 2.2)
        ax[0].plot(sig.est_t, sig.est[:, 0], label="m_hat")
        if sig.mass is not None:
            ax[0].plot(sig.t, sig.mass, "k:", label="true m")
        ax[0].legend(loc="upper right", fontsize=8)
        ax[1].plot(sig.est_t, sig.est[:, 1], label="R_hat")
        ax[2].plot(sig.est_t, sig.est[:, 2] * 1e4, label="K_hat")
        tr = sig.truth
        if tr is not None:
            ax[1].axhline(tr["R"], color="k", ls=":", label="true R")
            ax[2].axhline(tr["K"] * 1e4, color="k", ls=":", label="true K")
            if sig.mass is not None:  # the combination a hover determines: K_hat / K = (N + m_hat g/2) / (N + m g/2)
                m_true = np.interp(sig.est_t, sig.t, sig.mass)
                k_bal = tr["K"] * (tr["N"] + sig.est[:, 0] * tr["g"] / 2) / (tr["N"] + m_true * tr["g"] / 2)
                ax[2].plot(sig.est_t, k_bal * 1e4, "k--", lw=0.8, label="K (N + m_hat g/2) / (N + m g/2)")
        for a, label in zip(ax, ["m_hat [kg]", "R_hat [Ω]", "K_hat [1e-4 N m²/A²]"], strict=True):
            a.set_ylabel(label)
            _min_span(a, 0.02)
            a.legend(loc="best", fontsize=8)
        files.append(_finish(fig, ax, sig, "parameter estimates of the controller", out / "estimates.png", MASS_NOTE))

    if sig.mass is not None and _finite(sig.mass) and np.nanmax(sig.mass) > np.nanmin(sig.mass):
        fig, ax = figure(1, 1)
        ax[0].plot(sig.t, sig.mass)
        ax[0].set_ylabel("m [kg]")
        files.append(_finish(fig, ax, sig, "true mass of the plate", out / "mass.png"))

    if sig.latency_us is not None and sig.latency_t is not None and _finite(sig.latency_us):
        fig, ax = figure(2, 1)
        ax[0].plot(sig.latency_t, sig.latency_us, ".", ms=1)
        ax[0].set_ylabel("latency [µs]")
        if np.nanmin(sig.latency_us) > 0:
            ax[0].set_yscale("log")
        what = "waits for a late command (cum.)" if sig.lockstep else "deadline misses (cum.)"
        if sig.loop_t is not None and sig.loop_misses is not None and sig.loop_t.size:
            ax[1].step(sig.loop_t, sig.loop_misses, where="post")
        else:
            ax[1].text(0.5, 0.5, "no loop status recorded", transform=ax[1].transAxes, ha="center", va="center")
        ax[1].set_ylabel(f"plant {what}" if sig.lockstep else what)
        note = ("latency: the recorder had the sample's measurement -> its command (the recorder's clock). "
                + ("Lockstep: the plant waits for each late command, so waits cost time, not samples."
                   if sig.lockstep else "Free-running: a missed command is held by the board (at most hold_timeout)."))
        files.append(_finish(fig, ax, sig, "loop timing", out / "loop.png", note))
    return files


def plant_truth(plant: dict[str, Any]) -> dict[str, float] | None:
    """``truth`` of :class:`RunSignals` from a ``plant_sim`` configuration (None if the coils' R changes in the run)."""
    try:
        if plant.get("R1_rise") or plant.get("R2_rise"):
            return None
        r = [plant.get(k) or plant["R"] for k in ("R1", "R2")]
        return {"R": float(np.mean(r)), "K": float(plant["K"]), "N": (plant["N1"] + plant["N2"]) / 2,
                "g": float(plant["g"])}
    except (KeyError, TypeError, ValueError):  # a bag of another version: draw no truth rather than a wrong one
        return None


def run_signals(res: Any) -> RunSignals:
    """The signals of an offline run (:class:`~dem_ros.core.simulate.SimResult`)."""
    events = [(res.fail_time, f"failure at t = {res.fail_time:.3f} s")] if res.fail_time is not None else []
    return RunSignals(
        title=f"{res.scenario} / {res.controller} / estimator {res.estimator}",
        t=res.t, gaps=res.x[:, [0, 2]], ref=res.ref[:, :2], u_t=res.t, u=res.u, current=res.x[:, 4:6],
        est_t=res.t, est=res.diag[:, :3], mass=res.mass, events=events, truth=plant_truth(res.config["plant_sim"]),
    )


def plot_run(res: Any, out: Path, prefix: str = "dem-ros sim") -> list[Path]:
    """All standard figures of a :class:`~dem_ros.core.simulate.SimResult` into ``out``."""
    return plot_signals(run_signals(res), Path(out), prefix)
