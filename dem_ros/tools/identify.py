"""``dem-ros identify BAG``: R1, R2, K (each magnet's K1, K2 when the run separates them) and m of a rig from a
recorded run (dem_ros.core.identify), and ``dem-ros identify --rigs N``: the method measured on N seeded emulated
rigs (truths drawn away from the defaults).

Reads ``/dem/measurement`` (gaps, currents) and ``/dem/applied_voltage`` (the voltages the board held) of the
run, from its start (t = 0) to its end (a landing onto the support is not levitation and is left out), the
geometry and loads from the recorded configuration (the controller's model), and the data sheet's values
(``controller.{R,K,m}_nominal``) to scale the problem and judge the intervals.

Outputs: a table (printed), ``--json FILE``, ``--plot DIR`` (held-out currents: measured and simulated, and
the estimates with their intervals) and ``--params OUT.yaml`` (a ROS 2 params file with the estimates in the
project's parameter names: the controller's start and model, the estimator's model, the board's model).
A parameter the run cannot determine gets its reason and no number, and the exit status is 1. The laws, the
estimator and the board's safety model take one K: with a split the file gives them K = (K1 + K2)/2, which
centres the board's +-25 % model band on both magnets, and the emulator's plant K1, K2.

``--rigs N`` runs N emulated rigs in process, one board tick at a time (the rig emulator's board, the link's
frames through the hardware driver, the graph's estimator, controller and reference model: no clock, so the
outcome does not depend on the machine's load), identifies each and prints the table of errors and
interval coverage.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract
from ..core.identify import NAMES, PARAMS, SPLIT, IdentError, IdentResult, RunData, identify

__all__ = ["EXCITATION", "IdentifyOptions", "add_arguments", "cmd_identify", "emulated_run", "load_run_data",
           "params_yaml", "rig_truth"]

MS = 1_000_000
#: the excitation run the bring-up guide records: S1's steps through a faster reference model,
#: M(s) = 1000/(s + 10)^3 (instead of 0.25/((s + 1)(s + 0.5)^2)); the controller accepts its speed
EXCITATION = {"reference": {"b0": 1000.0, "a2": 30.0, "a1": 300.0, "a0": 1000.0},
              "controller": {"reference_max_speed": 0.05}}
#: the acceptance's tolerances: |error| / truth
TOLERANCE = {"R1": 0.03, "R2": 0.03, "K1": 0.03, "K2": 0.03, "K": 0.03, "m": 0.05}
#: --rigs: the largest max(K1, K2)/min(K1, K2) - 1 of the emulated rigs. The laws take one K, and the adaptive
#: law's lift-off from the hover it initialises with one K has a pitch transient that grows with the split
#: (offline S1: 0.57 mm at 3 %, 2.0 mm at 10 %, 3.5 mm at 20 %). With K1, K2 drawn independently within +-20 %,
#: 40 emulated rigs: splits up to 12 % levitated in 20 of 20, 17-21 % in 4 of 8, 26-48 % in none of 12 (the
#: board's braking bound landed the plate, or it came to rest on its support)
MAX_SPLIT = 0.10


@dataclass(frozen=True)
class IdentifyOptions:
    bag: Path | None
    json: Path | None
    plot: Path | None
    params: Path | None
    holdout: float
    coil_window: float
    heave_window: float
    rigs: int
    seed: int
    duration: float
    excite: bool

    @classmethod
    def from_args(cls, a: argparse.Namespace) -> IdentifyOptions:
        return cls(Path(a.bag) if a.bag else None, a.json, a.plot, a.params, a.holdout, a.coil_window,
                   a.heave_window, a.rigs, a.seed, a.duration, a.excite)


# -- the data --------------------------------------------------------------------------------------------------
def _geometry(cfg: Mapping[str, Mapping[str, Any]]) -> dict[str, float]:
    c = cfg["controller"]
    return {k: float(c[k]) for k in ("L", "l", "I", "N1", "N2", "g")}


def _nominal(cfg: Mapping[str, Mapping[str, Any]]) -> dict[str, float]:
    c = cfg["controller"]
    return {"R1": c["R_nominal"], "R2": c["R_nominal"], "K": c["K_nominal"], "m": c["m_nominal"]}


def load_run_data(bag: Path) -> tuple[RunData, dict[str, dict[str, Any]]]:
    """(data, configuration) of a recorded run: the samples that carry both a measurement and the applied
    voltage, from t = 0 (the end of the pre-roll) while the plate levitates (not resting on its support).

    Raises:
        BagError: not a bag, or missing the topics or the configuration.
    """
    from ..bag import BagError, BagReader
    from ..core.params import SCHEMA, apply_overrides, default_config
    from .runmetrics import LoopStats

    r = BagReader(bag)
    for t in (contract.MEASUREMENT, contract.APPLIED):
        if t.name not in r.topics or r.topics[t.name].count == 0:
            raise BagError(f"{bag}: no {t.name} (identify needs the measured gaps and currents and the applied "
                           f"voltages: a rig or graph run's bag); it has {', '.join(sorted(r.topics)) or 'no topics'}")
    run = r.run_metadata() or {}
    rec = run.get("config")
    if not rec:
        raise BagError(f"{bag}: no recorded configuration (run_info): the geometry and loads are unknown")
    known = {g: {p.name for p in specs} for g, specs in SCHEMA.groups.items()}
    cfg = apply_overrides(default_config(), {g: {n: v for n, v in vals.items() if n in known[g]}
                                             for g, vals in rec.items() if g in SCHEMA.groups}, "recorded config")
    meas = r.joint_state_arrays(contract.MEASUREMENT.name)
    app = r.joint_state_arrays(contract.APPLIED.name)
    epoch = None
    diags = [contract.DIAGNOSTICS.name] if contract.DIAGNOSTICS.name in r.topics else []
    for _, _, msg in r.messages(diags) if diags else ():
        for s in msg.status:
            if s.name in (contract.LOOP_STATUS, contract.HW_LOOP_STATUS):
                ls = LoopStats.from_status({kv.key: kv.value for kv in s.values})
                if ls.epoch_ns is not None:
                    epoch = ls.epoch_ns
    ts, i_m, i_a = np.intersect1d(meas["stamp_ns"], app["stamp_ns"], return_indices=True)
    keep = np.ones(ts.size, bool) if epoch is None else ts >= epoch
    if run.get("duration_s") and epoch is not None:
        keep &= ts <= epoch + round(float(run["duration_s"]) * 1e9)
    gap = meas["position"][i_m, :2]
    rest = cfg["hw_driver"]["landing_gap"] - 2e-4  # resting on the support: the force balance does not hold
    lev = np.all(gap < rest, axis=1) & np.all(np.isfinite(gap), axis=1)
    keep &= lev
    idx = np.nonzero(keep)[0]
    if idx.size:  # the first levitating stretch from t = 0: a landing ends the data
        stop = np.nonzero(np.diff(idx) != 1)[0]
        idx = idx[: stop[0] + 1] if stop.size else idx
    if idx.size < 100:
        raise BagError(f"{bag}: only {idx.size} levitating samples with a measurement and an applied voltage")
    t = (ts[idx] - ts[idx[0]]) * 1e-9
    data = RunData(t, gap[idx], meas["effort"][i_m[idx], :2], app["effort"][i_a[idx], :2])
    return data, cfg


def rig_truth(seed: int) -> dict[str, float]:
    """A rig's true R1, R2 [ohm] in [15, 26], each magnet's K1, K2 and m within +-20 % of the defaults (seeded;
    K2 within ``MAX_SPLIT`` of K1), and K = (K1 + K2)/2 (the board's model)."""
    from ..core.params import TABLE2

    rng = np.random.default_rng([25, seed])
    K = TABLE2["K"]
    t = {"R1": float(rng.uniform(15.0, 26.0)), "R2": float(rng.uniform(15.0, 26.0)),
         "K1": float(K * rng.uniform(0.8, 1.2)), "m": float(TABLE2["m"] * rng.uniform(0.8, 1.2))}
    # drawn last: R1, R2, K1 (the K of the single-K study) and m as before the split
    t["K2"] = float(rng.uniform(max(0.8 * K, t["K1"] / (1 + MAX_SPLIT)), min(1.2 * K, t["K1"] * (1 + MAX_SPLIT))))
    t["K"] = 0.5 * (t["K1"] + t["K2"])
    return {k: t[k] for k in ("R1", "R2", "K1", "K2", "K", "m")}


def rig_config(truth: Mapping[str, float], excite: bool, rig_seed: int = 7) -> dict[str, dict[str, Any]]:
    """S1 on an emulated rig whose plant is ``truth`` (the controller and estimator keep the defaults): R1, R2, m,
    and K or each magnet's K1, K2 (the board's model K: ``truth["K"]``, else their mean)."""
    from ..core.params import apply_overrides, default_config

    K1, K2 = truth.get("K1", truth["K"]), truth.get("K2", truth["K"])
    ps = {"R1": truth["R1"], "R2": truth["R2"], "R": truth["R1"], "K": truth.get("K", 0.5 * (K1 + K2)), "K1": K1,
          "K2": K2, "m": truth["m"], "measure_velocity": False}
    over: dict[str, dict[str, Any]] = {"plant_sim": ps, "rig": {"seed": rig_seed}}
    if excite:
        for g, v in EXCITATION.items():
            over.setdefault(g, {}).update(v)
    return apply_overrides(default_config(), over, "emulated rig")


def emulated_run(cfg: Mapping[str, Mapping[str, Any]], duration: float, preroll: float = 1.0,
                 driver: Mapping[str, Any] | None = None) -> tuple[RunData, np.ndarray]:
    """S1 (the ``reference`` group's steps) on the rig emulator's board, closed through the link's frames, the
    hardware driver and the graph's estimator, controller and reference model, one board tick at a time.

    ``driver``: the driver's parameters when they differ from the board's ``hw_driver`` group (which is the
    sensors' data sheet for the emulator), e.g. a calibration from ``dem-ros calibrate gaps``.
    Returns the run from t = 0 (after ``preroll`` s of hover) as the driver publishes it, and the tracking
    errors of the true gaps (n, 2) [m]. Raises IdentError if the plate did not levitate to the end.
    """
    from ..core.controllers import make_controller
    from ..core.estimator import make_estimator
    from ..core.reference import ReferenceModel
    from ..hardware.driver import HwDriver
    from ..hardware.link import HELLO_REQUEST, Mode, encode
    from ..hardware.rig import Board

    board = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], preroll=0.0)
    board.receive(encode(HELLO_REQUEST))
    drv = HwDriver(dict(driver or cfg["hw_driver"]) | {"clock_sync_frames": 1, "arm_samples": 1})
    drv.arm()
    est = make_estimator(cfg["estimator"], None, False)
    ctrl = make_controller(cfg["controller"])
    ref = ReferenceModel(cfg["reference"])
    dt = cfg["plant_sim"]["dt"]
    n_pre, n_run = round(preroll / dt), round(duration / dt)
    rows: list[np.ndarray] = []
    errors: list[tuple[float, float]] = []
    started = False
    for _ in range(n_pre + n_run + 100):
        data = board.tick()
        if data is None:
            continue
        s, reply = drv.on_bytes(data, 10**18 + board.n * MS, board.n * MS)
        if reply is not None:
            answer = board.receive(reply)  # a command, or the run's configuration (answered)
            if answer is not None:
                drv.on_bytes(answer, 10**18 + board.n * MS, board.n * MS)
        if s is None:
            continue
        z = np.array([s.gap[0], 0.0, s.gap[1], 0.0, s.current[0], s.current[1]])
        xh = est.step(z, s.applied)
        if not started:
            ctrl.reset(xh.copy(), s.applied)
            ref.reset(np.array([s.gap[0], s.gap[1]]))
            started = True
        k = len(rows) - n_pre
        r = ref.step_hold() if k < 0 else ref.step_at(k * dt)
        if k >= 0:
            errors.append((board.plant.x[0] - r[0], board.plant.x[2] - r[1]))
        rows.append(np.concatenate([[k * dt], s.gap, s.current, s.applied]))
        cmd = drv.command(s.stamp_ns, ctrl.step(xh, r).copy(), board.n * MS)
        if cmd is not None:
            board.receive(cmd)
        if board.failed or Mode(board.sup.mode) not in (Mode.RUN, Mode.OFF):
            raise IdentError(f"the emulated rig did not levitate to the end: board {Mode(board.sup.mode).name} "
                             f"({board.failed or board.sup.reason}) at t = {k * dt:.3f} s")
        if len(rows) >= n_pre + n_run:
            break
    a = np.array(rows[n_pre:])
    rest = cfg["hw_driver"]["landing_gap"] - 2e-4  # the rule of load_run_data: resting on the support
    on = np.nonzero(np.any(a[:, 1:3] >= rest, axis=1))[0]
    if on.size:
        raise IdentError(f"the emulated rig did not levitate to the end: a gap at or above {rest * 1e3:.3g} mm (the "
                         f"plate on its support) at t = {a[on[0], 0]:.3f} s")
    return RunData(a[:, 0], a[:, 1:3], a[:, 3:5], a[:, 5:7]), np.array(errors)


# -- outputs --------------------------------------------------------------------------------------------------
def _fmt(v: float) -> str:
    return f"{v:.6g}"


def _pct(v: float) -> str:
    return f"{100 * v:+.3g} %"


def split_text(res: IdentResult) -> str:
    """One line: whether the run separates K1 from K2, and the moment balance's check."""
    c = res.k_split
    words = {"split": "K1 and K2 differ (two K)", "one K: agree": "K1 and K2 agree within their intervals (one K)",
             "one K: cannot separate": "the run cannot separate K1 from K2 (one K)",
             "not determined": "not determined"}
    line = f"  K split (K1 - K2)/(K1 + K2): {words[c.verdict]}"
    if math.isfinite(c.coils):
        line += f"; coils {_pct(c.coils)} +- {100 * c.coils_ci:.2g} %"
    if math.isfinite(c.moment):
        line += f", moment balance {_pct(c.moment)} +- {100 * c.moment_ci:.2g} %"
        if c.consistent is not None:
            line += " (consistent)" if c.consistent else " (INCONSISTENT: see the note)"
    return line


def result_text(res: IdentResult, truth: Mapping[str, float] | None = None) -> str:
    lines = [f"identify: {res.samples} samples ({res.duration_s:.3g} s), condition of the scaled information "
             f"matrix {res.condition:.3g}{', refined on the simulation error' if res.refined else ''}"]
    for k, e in res.estimates.items():
        if e.determined:
            line = (f"  {k:<3} = {_fmt(e.value)} {e.unit}   95 %: [{_fmt(e.ci95[0])}, {_fmt(e.ci95[1])}]"
                    f" (+-{100 * (e.ci95[1] - e.value) / e.value:.2g} %)")
            if k == "K" and res.k_split.split:
                line += "  (K1 + K2)/2: the one K of the laws and the board"
            if truth is not None and k in truth:
                line += f"   truth {_fmt(truth[k])} ({100 * (e.value / truth[k] - 1):+.3g} %)"
        elif k in SPLIT and res.estimates["K"].determined:
            if k == "K2":
                continue  # the reason is K1's
            line = f"  K1, K2: not given: {e.reason}"
        else:
            line = f"  {k:<3}: not determined: {e.reason}"
        lines.append(line)
    lines.append(split_text(res))
    x = res.excitation
    lines.append(f"  excitation: flux change per window {x['flux_change_rel_1']:.2g} / {x['flux_change_rel_2']:.2g} "
                 f"(relative), of it noise {100 * x['flux_noise_share_1']:.3g} / {100 * x['flux_noise_share_2']:.3g} %;"
                 f" gap span {x['gap_span_mm']:.3g} mm")
    v = res.validation
    if v is not None:
        lines.append(f"  held out {v.t_from:.3g}-{v.t_to:.3g} s, simulated with the estimates: coil current RMS "
                     f"error {v.current_rms[0] * 1e3:.3g} / {v.current_rms[1] * 1e3:.3g} mA "
                     f"({100 * v.current_rel[0]:.2g} / {100 * v.current_rel[1]:.2g} % of the mean), fit "
                     f"{v.current_fit[0]:.3g} / {v.current_fit[1]:.3g} %; heave balance RMS {v.heave_rms:.3g} N")
    lines += [f"  note: {n}" for n in res.notes]
    return "\n".join(lines)


def params_yaml(res: IdentResult) -> str:
    """A ROS 2 params file with the determined estimates in the project's names (none for the others).

    The laws, the estimator and the board's safety model take one K: with a split, K = (K1 + K2)/2 (it centres
    the board's +-25 % model band, docs/manual/board.md, on both magnets; the heave force at a level hover
    needs the harmonic mean, lower by about s^2 K for a split s); the emulator's plant gets K1, K2."""
    from ..board.config import BOUND_MARGIN

    v = res.values()
    lines = ["# dem-ros identify: the plant's parameters from a recorded run (95 % intervals in the comments)."]

    def ci(k: str) -> str:
        e = res.estimates[k]
        return f"  # 95 %: [{_fmt(e.ci95[0])}, {_fmt(e.ci95[1])}] {e.unit}"

    R = 0.5 * (v["R1"] + v["R2"]) if "R1" in v and "R2" in v else None
    groups: dict[str, list[str]] = {"controller": [], "estimator": [], "hw_driver": [], "plant_sim": []}
    if R is not None:
        groups["controller"] += [f"R_init: {_fmt(R)}  # (R1 + R2)/2", f"R_nominal: {_fmt(R)}"]
        groups["estimator"].append(f"R: {_fmt(R)}")
        groups["hw_driver"].append(f"R: {_fmt(R)}")
        groups["plant_sim"] += [f"R: {_fmt(R)}", f"R1: {_fmt(v['R1'])}" + ci("R1"), f"R2: {_fmt(v['R2'])}" + ci("R2")]
    split = res.k_split.split and all(k in v for k in SPLIT)
    for k in ("K", "m"):
        if k in v:
            why = "  # (K1 + K2)/2" if k == "K" and split else ""
            groups["controller"] += [f"{k}_init: {_fmt(v[k])}" + ci(k), f"{k}_nominal: {_fmt(v[k])}{why}"]
            groups["estimator"].append(f"{k}: {_fmt(v[k])}{why}")
            groups["hw_driver"].append(f"{k}: {_fmt(v[k])}{why}")
            groups["plant_sim"].append(f"{k}: {_fmt(v[k])}{why}")
    if split:
        groups["plant_sim"] += [f"{k}: {_fmt(v[k])}" + ci(k) for k in SPLIT]
        lines.append("# K1 and K2 differ: the laws, the estimator and the board's model take one K, (K1 + K2)/2 (it "
                     f"centres the board's +-{100 * BOUND_MARGIN:.3g} % model band on both magnets); the emulator's "
                     "plant_sim takes K1, K2")
        worst = max(abs(v[k] / v["K"] - 1) for k in SPLIT)
        if worst > BOUND_MARGIN:
            lines.append(f"# WARNING: a magnet's K is {100 * worst:.3g} % off (K1 + K2)/2, outside the board's "
                         f"+-{100 * BOUND_MARGIN:.3g} % model band: its braking bound does not cover this rig")
    elif "K" in v:
        lines.append(f"# one K: {res.estimates['K1'].reason}")
    lines.append("# hw_driver: the board's model (its safety supervisor's m, R, K), sent to the board at the handshake")
    lines.append("# plant_sim: the emulator's plant (and its board's defaults)")
    for g, entries in groups.items():
        if entries:
            lines += [f"{g}:", "  ros__parameters:"] + [f"    {e}" for e in entries]
    missing = [k for k in PARAMS if k not in v]
    if missing:
        lines.append(f"# not determined by this run (no value written): {', '.join(missing)}")
    return "\n".join(lines) + "\n"


def plot_result(res: IdentResult, d: RunData, geo: Mapping[str, float], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..core.identify import simulate_coils

    out.mkdir(parents=True, exist_ok=True)
    files = []
    v = res.validation
    est = res.estimates
    if v is not None and all(est[k].determined for k in ("R1", "R2", "K")):
        K1, K2 = (est["K1"].value, est["K2"].value) if res.k_split.split else (est["K"].value, est["K"].value)
        k0 = int(np.searchsorted(d.t, v.t_from))
        hold = d.slice(k0, d.t.size)
        i_sim = simulate_coils(hold, geo, est["R1"].value, est["R2"].value, K1, K2)
        fig, ax = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
        for j in (0, 1):
            ax[j].plot(hold.t, hold.current[:, j], lw=0.8, label="measured")
            ax[j].plot(hold.t, i_sim[:, j], lw=0.8, ls="--", label="simulated with the estimates")
            ax[j].set_ylabel(f"i{j + 1} [A]")
        ax[0].legend()
        ax[1].set_xlabel("t [s]")
        ax[0].set_title("held-out part of the run")
        fig.tight_layout()
        p = out / "identify_validation.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        files.append(p)
    fig, ax = plt.subplots(1, len(NAMES), figsize=(13, 3))
    for a, (k, e) in zip(ax, res.estimates.items(), strict=True):
        if e.determined:
            a.errorbar([0], [e.value], yerr=[[e.value - e.ci95[0]], [e.ci95[1] - e.value]], fmt="o", capsize=4)
        else:
            a.text(0.5, 0.5, "one K" if k in SPLIT and est["K"].determined else "not\ndetermined", ha="center",
                   va="center", transform=a.transAxes)
        a.set_title(f"{k} [{e.unit}]")
        a.set_xticks([])
    fig.tight_layout()
    p = out / "identify_estimates.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)
    return files


# -- the study over emulated rigs ----------------------------------------------------------------------------------
def judge_rig(res: dict[str, Any], truth: Mapping[str, float]) -> dict[str, Any]:
    """Each reported parameter against the truth: {name: (error, inside its 95 % interval, within tolerance)} and
    ok: R1, R2, K, m and, with a split, K1 and K2 within tolerance and inside their intervals; with one K, K within
    tolerance of both magnets' truths and (K1 + K2)/2 inside its interval."""
    est = res["estimates"]
    out: dict[str, Any] = {}
    ok = res["complete"]
    for k in NAMES:
        e = est[k]
        if not e["determined"]:
            continue
        err = e["value"] / truth[k] - 1
        inside = e["ci95"][0] <= truth[k] <= e["ci95"][1]
        within = abs(err) <= TOLERANCE[k]
        if k == "K" and not res["k_split"]["split"]:  # one K for both magnets
            within = all(abs(e["value"] / truth[j] - 1) <= TOLERANCE[j] for j in SPLIT)
        out[k] = {"error": err, "inside": inside, "within": within,
                  "half_width": (e["ci95"][1] - e["value"]) / e["value"]}
        ok = ok and inside and within
    return {"params": out, "ok": bool(ok)}


def _one_rig(args: tuple[int, float, bool, float, float]) -> dict[str, Any]:
    seed, duration, excite, cw, hw = args
    truth = rig_truth(seed)
    cfg = rig_config(truth, excite, rig_seed=seed)
    try:
        d, err = emulated_run(cfg, duration)
    except IdentError as exc:
        return {"seed": seed, "truth": truth, "error": str(exc), "ok": False}
    res = identify(d, _geometry(cfg), _nominal(cfg), coil_window=cw, heave_window=hw).to_dict()
    row: dict[str, Any] = {"seed": seed, "truth": truth, "max_tracking_error_um": float(np.abs(err).max() * 1e6),
                           "result": res}
    return row | judge_rig(res, truth)


def _row_text(row: dict[str, Any]) -> str:
    if "error" in row:
        return "run failed: " + row["error"]
    parts = []
    for k in NAMES:
        p = row["params"].get(k)
        if p is None:
            if k in SPLIT:
                continue
            parts.append(f"{k} not determined")
            continue
        parts.append(f"{k} {100 * p['error']:+.3f} % ({'in' if p['inside'] else 'OUTSIDE'} 95 %)")
    parts.append(row["result"]["k_split"]["verdict"])
    return ("ok: " if row["ok"] else "NOT ok: ") + ", ".join(parts)


def study_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: one row per rig, per parameter its truth, estimate, error and 95 % half-width [%], inside."""
    head = ["seed"] + [f"{k} {c}" for k in NAMES for c in ("truth", "estimate", "error % (95 % +-)", "in")]
    head += ["split: coils / moment balance %", "all within"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [str(r["seed"])]
        res: dict[str, Any] = r.get("result") or {}
        for k in NAMES:
            cells.append(f"{r['truth'][k]:.5g}")
            e = res["estimates"][k] if res else None
            p = r.get("params", {}).get(k)
            if e is None:
                cells += ["run failed", "-", "-"]
            elif p is None:
                cells += ["one K" if k in SPLIT and res["estimates"]["K"]["determined"] else "not determined", "-", "-"]
            else:
                cells += [f"{e['value']:.5g}", f"{100 * p['error']:+.3f} (+-{100 * p['half_width']:.2g})",
                          "yes" if p["inside"] else "NO"]
        c = res.get("k_split", {})
        cells.append(f"{100 * c['coils']:+.2f} +-{100 * c['coils_ci95']:.2g} / {100 * c['moment']:+.3f}"
                     if "coils" in c and "moment" in c else (c.get("verdict", "-")))
        cells.append("yes" if r.get("ok") else "NO")
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def study_summary(rows: list[dict[str, Any]]) -> list[str]:
    """Per parameter: how many rigs gave it within tolerance, the worst error, the coverage of its intervals."""
    lines = []
    ran = [r for r in rows if "result" in r]
    for k in NAMES:
        ps = [r["params"][k] for r in ran if k in r["params"]]
        if not ps:
            continue
        worst = max(ps, key=lambda p: abs(p["error"]))
        lines.append(f"  {k}: given by {len(ps)} of {len(rows)} rigs, within tolerance {sum(p['within'] for p in ps)}, "
                     f"worst error {100 * worst['error']:+.3f} %, truth inside its 95 % interval "
                     f"{sum(p['inside'] for p in ps)} of {len(ps)}")
    verdicts: dict[str, int] = {}
    for r in ran:
        v = r["result"]["k_split"]["verdict"]
        verdicts[v] = verdicts.get(v, 0) + 1
    checked = [r["result"]["k_split"].get("consistent") for r in ran]
    lines.append("  K split: " + ", ".join(f"{v} {n}" for v, n in sorted(verdicts.items()))
                 + f"; moment balance consistent with the coils in {sum(c is True for c in checked)} of "
                 f"{sum(c is not None for c in checked)}")
    return lines


def run_study(o: IdentifyOptions) -> int:
    import os
    from concurrent.futures import ProcessPoolExecutor

    jobs = [(o.seed + i, o.duration, o.excite, o.coil_window, o.heave_window) for i in range(o.rigs)]
    what = "S1 with the excitation reference (--excite)" if o.excite else "S1"
    print(f"dem-ros identify: {o.rigs} emulated rigs (seeds {o.seed}..{o.seed + o.rigs - 1}), {what}, "
          f"{o.duration:g} s each", flush=True)
    workers = max(1, min(o.rigs, len(os.sched_getaffinity(0))))
    rows = []
    with ProcessPoolExecutor(workers) as ex:
        for row in ex.map(_one_rig, jobs):
            rows.append(row)
            print(f"  rig {row['seed']}: {_row_text(row)}", flush=True)
    print(study_table(rows))
    print("\n".join(study_summary(rows)))
    n_ok = sum(1 for r in rows if r.get("ok"))
    print(f"{n_ok} of {len(rows)} rigs: R1, R2, K (K1, K2) within 3 %, m within 5 %, each truth inside its 95 % "
          f"interval")
    if o.json:
        from .common import write_json

        write_json(o.json, {"rigs": rows, "ok": n_ok, "excite": o.excite, "duration_s": o.duration})
    return 0 if n_ok == len(rows) else 1


# -- the command ----------------------------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    from .common import out_dir, out_file, seed

    p.add_argument("bag", nargs="?", default=None, help="a recorded run (bag directory or .mcap): hover and reference "
                   "steps with the measured gaps and currents and the applied voltages")
    p.add_argument("--json", type=out_file, default=None, help="write the result as JSON")
    p.add_argument("--plot", type=out_dir, default=None, metavar="DIR", help="write figures (PNG) to DIR")
    p.add_argument("--params", type=out_file, default=None, metavar="OUT.yaml",
                   help="write the estimates as a ROS 2 params file (controller, estimator, board model)")
    p.add_argument("--holdout", type=float, default=0.3, help="fraction of the run (its end) held out and simulated "
                   "with the estimates (default 0.3; 0: none)")
    p.add_argument("--coil-window", type=float, default=0.02, help="window of the integrated coil equations [s]")
    p.add_argument("--heave-window", type=float, default=0.2, help="window of the heave balance [s]")
    p.add_argument("--rigs", type=int, default=0, metavar="N", help="instead of a bag: N seeded emulated rigs, "
                   "a table of errors and interval coverage")
    p.add_argument("--seed", type=seed, default=0, help="--rigs: the first rig's seed (default 0)")
    p.add_argument("--duration", type=float, default=30.0, help="--rigs: seconds of S1 per rig (default 30)")
    p.add_argument("--excite", action="store_true", help="--rigs: record S1's steps through the excitation "
                   "reference model 1000/(s + 10)^3 (the bring-up guide's identification run)")


def cmd_identify(args: argparse.Namespace) -> int:
    from .common import UsageError, write_json

    o = IdentifyOptions.from_args(args)
    if not 0.0 <= o.holdout < 0.9:
        raise UsageError(f"--holdout {o.holdout:g}: expected a fraction in [0, 0.9)")
    if o.coil_window <= 0 or o.heave_window <= 0:
        raise UsageError("--coil-window and --heave-window must be > 0 s")
    if (o.bag is None) == (o.rigs <= 0):
        raise UsageError("give a BAG, or --rigs N (N >= 1) for the emulated rigs' table")
    if o.rigs > 0:
        if o.duration <= 2.0:
            raise UsageError(f"--duration {o.duration:g}: expected more than 2 s")
        return run_study(o)
    assert o.bag is not None
    d, cfg = load_run_data(o.bag)
    geo = _geometry(cfg)
    try:
        res = identify(d, geo, _nominal(cfg), coil_window=o.coil_window, heave_window=o.heave_window,
                       holdout=o.holdout)
    except IdentError as exc:
        raise UsageError(f"{o.bag}: {exc}") from None
    print(result_text(res))
    if o.json:
        write_json(o.json, res.to_dict())
        print(f"  result written to {o.json}")
    if o.params:
        o.params.write_text(params_yaml(res))
        print(f"  parameters written to {o.params}" + ("" if res.complete else " (the determined ones only)"))
    if o.plot:
        files = plot_result(res, d, geo, o.plot)
        print(f"  {len(files)} figures written to {o.plot}")
    return 0 if res.complete else 1


