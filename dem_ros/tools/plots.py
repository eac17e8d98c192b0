"""Figures of a run (PNG, matplotlib Agg): tracking, error, inputs, estimates, mass."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

__all__ = ["MASS_NOTE", "caption", "figure", "mark_failure", "plot_run", "save"]


def figure(rows: int = 1, cols: int = 1, h: float = 3.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # plain tick labels: no "1e-8+3.2079e-4" offsets on nearly constant signals
    plt.rcParams["axes.formatter.useoffset"] = False
    fig, axes = plt.subplots(rows, cols, figsize=(8, h * rows), squeeze=False, sharex=True)
    return fig, axes[:, 0] if cols == 1 else axes


def caption(fig, text: str) -> None:
    """A note under the axes, for what a figure cannot say by itself."""
    lines = text.count("\n") + 1
    fig.set_figheight(fig.get_figheight() + 0.16 * lines)
    fig.text(0.01, 0.005, text, fontsize=7.5, va="bottom", ha="left")
    fig.tight_layout(rect=(0, 0.16 * lines / fig.get_figheight() + 0.01, 1, 1))


def mark_failure(axes, fail_time: float | None) -> None:
    """A labelled vertical line where the run failed (gap out of range or non-finite)."""
    if fail_time is None:
        return
    for a in axes:
        a.axvline(fail_time, color="r", lw=0.8, label=f"failure at t = {fail_time:.3f} s")


# what a steady hover does and does not determine; printed where m_hat is drawn
MASS_NOTE = ("m_hat is not identifiable from a steady hover: the hover fixes only the force balance\n"
             "K_hat i^2/delta^2 = N + m_hat g/2 per magnet. m_hat moves towards m only while the\n"
             "reference excites the plate (steps, load changes); tracking does not need it to.")


def save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    if not fig.texts:  # a caption has laid the figure out already
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _finite(a: np.ndarray) -> bool:
    return a.size > 0 and bool(np.isfinite(a).any())


def plot_signals(t, x, ref, u, diag, mass, out: Path, title: str, fail_time=None) -> list[Path]:
    """The standard set of figures from plain arrays (used for runs and for bags)."""
    files = []
    fig, ax = figure(2, 1)
    for j in range(2):
        ax[j].plot(t, x[:, 2 * j] * 1e3, label=f"gap d{j + 1}")
        ax[j].plot(t, ref[:, j] * 1e3, "--", label=f"reference y_m{j + 1}")
        ax[j].set_ylabel(f"gap d{j + 1} [mm]")
    mark_failure(ax, fail_time)
    for a in ax:
        a.legend(loc="upper right")
    ax[0].set_title(f"{title}: tracking")
    ax[-1].set_xlabel("t [s]")
    files.append(save(fig, out / "tracking.png"))

    fig, ax = figure(1, 1)
    e = (x[:, [0, 2]] - ref[:, :2]) * 1e6
    ax[0].plot(t, e[:, 0], label="e1")
    ax[0].plot(t, e[:, 1], label="e2")
    ax[0].set_ylabel("e = d - y_m [um]")
    ax[0].set_xlabel("t [s]")
    mark_failure(ax, fail_time)
    ax[0].set_title(f"{title}: tracking error")
    ax[0].legend()
    files.append(save(fig, out / "error.png"))

    fig, ax = figure(2, 1)
    ax[0].plot(t, u)
    ax[0].set_ylabel("u [V]")
    ax[0].legend(["u1", "u2"])
    ax[1].plot(t, x[:, 4:6])
    ax[1].set_ylabel("i [A]")
    ax[1].legend(["i1", "i2"])
    ax[1].set_xlabel("t [s]")
    mark_failure(ax, fail_time)
    ax[0].set_title(f"{title}: coil voltages and currents")
    files.append(save(fig, out / "inputs.png"))

    if diag is not None and _finite(diag[:, :3]):
        fig, ax = figure(3, 1, 2.2)
        labels = ["m_hat [kg]", "R_hat [ohm]", "K_hat [1e-4 N m^2/A^2]"]
        ax[1].plot(t, diag[:, 1])
        ax[2].plot(t, diag[:, 2] * 1e4)
        for j in range(3):
            ax[j].set_ylabel(labels[j])
        ax[0].plot(t, diag[:, 0], label="m_hat")
        if mass is not None:
            ax[0].plot(t, mass, "--", label="true m")
        ax[0].legend(loc="upper right", fontsize=8)
        mark_failure(ax, fail_time)
        ax[0].set_title(f"{title}: parameter estimates")
        ax[-1].set_xlabel("t [s]")
        caption(fig, MASS_NOTE)
        files.append(save(fig, out / "estimates.png"))
    if mass is not None and np.ptp(mass) > 0:
        fig, ax = figure(1, 1)
        ax[0].plot(t, mass)
        ax[0].set_ylabel("m [kg]")
        ax[0].set_xlabel("t [s]")
        ax[0].set_title(f"{title}: mass of the plate")
        files.append(save(fig, out / "mass.png"))
    return files


def plot_run(res, out: Path) -> list[Path]:
    """All standard figures of a :class:`~dem_ros.core.simulate.SimResult` into ``out``."""
    title = f"{res.scenario} / {res.controller} / estimator {res.estimator}"
    return plot_signals(res.t, res.x, res.ref, res.u, res.diag, res.mass, Path(out), title, res.fail_time)


def overlay(ax, t: np.ndarray, series: Iterable[tuple[str, np.ndarray]], scale: float = 1.0) -> None:
    for label, y in series:
        ax.plot(t[: len(y)], y * scale, label=label)
    ax.legend(loc="upper right", fontsize=8)
