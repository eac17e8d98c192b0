r"""The study's robustness table and maps, and its section of ``dem-ros report``.

A run *survives* when the plate never leaves (0.1 mm, 30 mm) (the simulator's
failure test); it *passes* when it survives with RMS error < ``--rms-limit``
on both outputs (default 100 um, the report's noise criterion).

Files (``--out DIR``)
---------------------
``map_<controller>.png``  robustness map (:func:`draw_maps`): worst RMS tracking
                 error over the axes not drawn, failed cells marked, axes in their units.
``summary.md``   the robustness table (:func:`robustness_table`; also in
                 ``dem-ros report``, :func:`report_section`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .run import load_results
from .spec import StudySpec, plan_runs

__all__ = ["draw_maps", "report_section", "robustness_rows", "robustness_table"]


def _f(x: str) -> float:
    return float(x) if x not in ("", None) else float("nan")


def _g(x: float) -> str:
    return "-" if x != x else f"{x:.3g}"


def _worst_rms(r: Mapping[str, str]) -> float:
    return max(_f(r["rms_e1_um"]), _f(r["rms_e2_um"]))


def robustness_rows(rows: Iterable[Mapping[str, str]], controllers: Sequence[str],
                    rms_limit: float) -> list[dict[str, Any]]:
    """Per controller: runs, survived, passed, worst / median RMS (um), worst max |e| (um), failing cells."""
    rows = list(rows)
    out = []
    for c in controllers:
        rs = [r for r in rows if r["controller"] == c]
        if not rs:
            continue
        surv = [r for r in rs if r["failed"] == "0"]
        passed = [r for r in surv if _worst_rms(r) < rms_limit]
        rms = np.array([_worst_rms(r) for r in surv]) if surv else np.array([])
        mx = max((max(_f(r["max_e1_um"]), _f(r["max_e2_um"])) for r in surv), default=float("nan"))
        out.append({"controller": c, "runs": len(rs), "survived": len(surv), "passed": len(passed),
                    "worst_rms_um": float(np.max(rms)) if rms.size else float("nan"),
                    "median_rms_um": float(np.median(rms)) if rms.size else float("nan"),
                    "worst_max_um": mx, "failures": [r for r in rs if r["failed"] != "0"]})
    return out


def robustness_table(out: Path, rms_limit: float | None = None, run_ids: set[str] | None = None) -> str:
    """Markdown robustness table of the study in ``out`` (study.json + results.csv).

    The rows counted are ``run_ids``, by default those of the last command run in ``out``
    (``study.json``; rows of earlier settings or code stay in results.csv but are not shown).
    """
    doc = json.loads((out / "study.json").read_text())
    limit = rms_limit if rms_limit is not None else doc.get("rms_limit_um", 100.0)
    rows = list(load_results(out / "results.csv").values())
    axes = [a["name"] for a in doc["axes"]]
    if run_ids is None and "run_ids" in doc:
        run_ids = set(doc["run_ids"])
    rows = [r for r in rows if all(a in r for a in axes) and (run_ids is None or r["run_id"] in run_ids)]
    lines = [
        f"| controller | runs | survived | pass (RMS < {limit:g} um) | worst RMS [um] | median RMS [um]"
        " | worst max [um] |",
        "|---|---|---|---|---|---|---|",
    ]
    fails = []
    for s in robustness_rows(rows, doc["controllers"], limit):
        lines.append(f"| `{s['controller']}` | {s['runs']} | {s['survived']} | {s['passed']} | "
                     f"{_g(s['worst_rms_um'])} | {_g(s['median_rms_um'])} | {_g(s['worst_max_um'])} |")
        for r in s["failures"][:8]:
            cell = ", ".join(f"{a} = {r[a]}" for a in axes)
            fails.append(f"- `{s['controller']}` fails at t = {_f(r['fail_time_s']):.2f} s in cell {cell}")
        if len(s["failures"]) > 8:
            fails.append(f"- `{s['controller']}`: {len(s['failures']) - 8} more failing cells in results.csv")
    def vals(v: list[Any]) -> str:
        return ", ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in v)

    ax_text = "; ".join(
        f"{a['name']} in {{{vals(a['values'])}}} {a['unit']}" if a["values"] is not None
        else f"{a['name']} ~ U[{vals(a['range'])}] {a['unit']}" for a in doc["axes"])
    head = (f"{doc['mode'].replace('_', ' ')} over {ax_text}; scenario {doc['scenario']}, "
            f"estimator {doc['estimator']}, "
            f"{doc['duration_s']:g} s runs, seed {doc['seed']}. Survived: the plate never left (0.1 mm, 30 mm).")
    return "\n".join([head, "", *lines, *(["", *fails] if fails else [])])


def report_section(study_dir: Path) -> list[str]:
    """Markdown lines of the report's robustness section, from the study in ``study_dir``.

    ``dem-ros report --out DIR`` reads ``DIR/study`` (written by
    ``dem-ros study --out DIR/study ...``; resumable, so regenerating both is cheap).
    """
    head = ["## Robustness over plant truth (`dem-ros study`)", ""]
    if not ((study_dir / "study.json").is_file() and (study_dir / "results.csv").is_file()):
        return [*head, f"No study in `{study_dir.name}/` beside this report. Run "
                       "`dem-ros study --preset acceptance --controllers adaptive,nonlinear_decoupling "
                       f"--out <report dir>/{study_dir.name}`, "
                       "then `dem-ros report` again.", ""]
    maps = sorted(study_dir.glob("map_*.png"))
    return [*head, robustness_table(study_dir), "",
            *(f"![robustness map, {m.stem[4:]}]({study_dir.name}/{m.name})\n" for m in maps)]


_DISPLAY = {"m": (1e3, "mm")}


def _label(name: str, unit: str) -> tuple[float, str]:
    k, u = _DISPLAY.get(unit, (1.0, unit))
    return k, f"{name} [{u}]" if u else name


def draw_maps(spec: StudySpec, out: Path, rms_limit: float, map_axes: Sequence[str] | None = None) -> list[Path]:
    """One robustness map per controller (PNG); see the module docstring."""
    import matplotlib

    from ..plots import save

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    rows = load_results(out / "results.csv")
    wanted = {j["run_id"] for j in plan_runs(spec)}
    rows = {k: r for k, r in rows.items() if k in wanted}
    axes = list(spec.axes)
    if map_axes:
        pick = [next(a for a in axes if a.name == n) for n in map_axes]
    else:
        multi = [a for a in axes if a.values is None or len(a.values) > 1]
        pick = (multi or axes)[:2]
    files = []
    for ctl in spec.controllers:
        rs = [r for r in rows.values() if r["controller"] == ctl]
        if not rs:
            continue
        fig, ax = plt.subplots(figsize=(7.5, 5.5))
        kx, lx = _label(pick[0].name, pick[0].unit)
        n_fail = sum(r["failed"] != "0" for r in rs)
        rest = [a.name for a in axes if a not in pick]
        title = f"{ctl}: {len(rs)} runs, {n_fail} failed; pass = survived and RMS < {rms_limit:g} um"
        scatter = spec.samples is not None or any(a.values is None for a in pick)
        if scatter:
            x = np.array([_f(r[pick[0].name]) for r in rs]) * kx
            y = (np.array([_f(r[pick[1].name]) for r in rs]) * _label(pick[1].name, pick[1].unit)[0]
                 if len(pick) > 1 else np.array([_worst_rms(r) for r in rs]))
            ok = np.array([r["failed"] == "0" for r in rs])
            c = np.array([_worst_rms(r) for r in rs])
            if ok.any():
                sc = ax.scatter(x[ok], y[ok], c=np.clip(c[ok], 1e-3, None), norm=LogNorm(), cmap="viridis", s=18)
                fig.colorbar(sc, ax=ax, label="RMS error, worst output [um]")
            ax.scatter(x[~ok], y[~ok], marker="x", color="red", s=40, label="failed")
            ax.set_ylabel(_label(pick[1].name, pick[1].unit)[1] if len(pick) > 1 else "RMS error [um]")
            if (~ok).any():
                ax.legend(loc="best")
        else:
            xs = list(pick[0].values or ())
            ys = list(pick[1].values or ()) if len(pick) > 1 else [None]
            grid = np.full((len(ys), len(xs)), np.nan)
            nf = np.zeros((len(ys), len(xs)), int)
            nt = np.zeros((len(ys), len(xs)), int)
            xs_s = [str(v) for v in xs]
            ys_s = [str(v) for v in ys]
            for r in rs:
                ix = xs_s.index(r[pick[0].name])
                iy = ys_s.index(r[pick[1].name]) if len(pick) > 1 else 0
                nt[iy, ix] += 1
                if r["failed"] != "0":
                    nf[iy, ix] += 1
                else:
                    grid[iy, ix] = np.fmax(grid[iy, ix], _worst_rms(r))
            finite = grid[np.isfinite(grid)]
            vmin = max(float(finite.min()), 1e-3) if finite.size else 1e-3
            vmax = max(float(finite.max()), vmin * 10) if finite.size else 1.0
            im = ax.imshow(np.where(np.isfinite(grid), np.clip(grid, vmin, None), np.nan), origin="lower",
                           aspect="auto", cmap="viridis", norm=LogNorm(vmin=vmin, vmax=vmax))
            fig.colorbar(im, ax=ax,
                         label="RMS error, worst output and cell [um]" if rest else "RMS error, worst output [um]")
            for iy in range(len(ys)):
                for ix in range(len(xs)):
                    if nf[iy, ix]:
                        ax.add_patch(plt.Rectangle((ix - 0.5, iy - 0.5), 1, 1, color="red", alpha=0.85))
                        ax.text(ix, iy, f"FAIL\n{nf[iy, ix]}/{nt[iy, ix]}", ha="center", va="center", fontsize=7,
                                color="white")
                    elif nt[iy, ix] and len(xs) * len(ys) <= 400:
                        v = grid[iy, ix]
                        mark = "" if v < rms_limit else "\n> limit"
                        ax.text(ix, iy, f"{v:.3g}{mark}", ha="center", va="center", fontsize=7,
                                color="white" if v < math.sqrt(vmin * vmax) else "black")
            ax.set_xticks(range(len(xs)), [f"{v * kx:.4g}" if pick[0].type is not str else v for v in xs])
            if len(pick) > 1:
                ky, ly = _label(pick[1].name, pick[1].unit)
                ax.set_yticks(range(len(ys)), [f"{v * ky:.4g}" if pick[1].type is not str else v
                                               for v in pick[1].values or ()])
                ax.set_ylabel(ly)
            else:
                ax.set_yticks([])
        ax.set_xlabel(lx)
        if rest:
            title += f"\n{'one point per run; not drawn' if scatter else 'worst case over'}: {', '.join(rest)}"
        ax.set_title(title, fontsize=9)
        files.append(save(fig, out / f"map_{ctl}.png"))
    return files
