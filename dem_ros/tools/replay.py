"""``dem-ros replay`` and ``dem-ros bag``: offline analysis of recorded runs.

* ``replay BAG``: the run's metrics and figures from the recording alone
  (tracking error e = true gap - y_m matched by stamp, voltages, currents,
  estimates, loop latency and deadline misses over time).
* ``replay BAG --controller NAME [--set k1=60 ...]``: what-if. Re-runs a control
  law on the recorded controller inputs (state estimate, reference, applied
  voltage) sample by sample, as the node did, and compares its commands with the
  recorded ones. With the recorded law and parameters it reproduces them.
* ``replay BAG --publish``: plays the recording back onto the DDS graph at its
  recorded rate (like ``ros2 bag play``), without ROS.
* ``bag check BAG`` / ``bag info BAG``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import contract
from .common import write_json
from .progress import Progress
from .runmetrics import RunMetrics, load_run
from .verdict import OK

if TYPE_CHECKING:
    from .plots import RunSignals

__all__ = ["analyse", "cmd_bag", "cmd_replay", "what_if"]


def analyse(bag: Path) -> tuple[RunMetrics, dict[str, Any]]:
    """(metrics, series) of a recorded run; series feed the figures (see :func:`.runmetrics.load_run`)."""
    return load_run(bag)


def _arrays(reader: Any, topic: str) -> dict[str, Any] | None:
    if topic not in reader.topics or reader.topics[topic].count == 0:
        return None
    return reader.joint_state_arrays(topic)


def replay_signals(series: dict[str, Any], m: RunMetrics) -> RunSignals:
    """The figures' signals of a recorded run (``series`` of :func:`.runmetrics.load_run`), experiment clock.

    Command, latency and estimate samples of the pre-roll (t < 0) are left out: every figure
    starts where the metrics start, at the scenario's t = 0.
    """
    from .plots import CLOCK_NOTE, RunSignals, plant_truth

    def after0(tk: str, *keys: str) -> tuple[np.ndarray | None, ...]:
        if tk not in series:
            return (None,) * (1 + len(keys))
        tt = np.asarray(series[tk], float)
        keep = tt >= 0.0
        return (tt[keep], *(np.asarray(series[k])[keep] if series.get(k) is not None else None for k in keys))

    u_t, u = after0("cmd_t", "cmd")
    lat_t, lat = after0("cmd_latency_t", "cmd_latency_us")
    est_t, est = after0("est_t", "est")
    events = []
    if m.failed and m.fail_time_s is not None:
        events.append((m.fail_time_s, f"failure at t = {m.fail_time_s:.3f} s"))
    if "landing" in series:
        t_land, why = series["landing"]
        events.append((t_land, f"board landing the plate by t = {t_land:.0f} s" + (f" ({why})" if why else "")))
    loop = series.get("loop") or []
    lockstep = m.loop.lockstep if m.loop is not None else False
    title = " / ".join(x for x in (m.scenario, m.controller, f"estimator {m.estimator}" if m.estimator else None) if x)
    return RunSignals(
        title=f"{title or 'run'} (recorded)", t=series["t"], gaps=series["gaps"], ref=series["ref"],
        gap_source="measured" if m.error_source == "measurement" else "true",
        u_t=u_t, u=u, current=series.get("current"), est_t=est_t, est=est, mass=series.get("mass"),
        latency_t=lat_t, latency_us=lat,
        loop_t=np.array([x[0] for x in loop], float) if loop else None,
        loop_misses=np.array([x[1] for x in loop], float) if loop else None,
        lockstep=lockstep, events=events, notes=[CLOCK_NOTE],
        truth=plant_truth(m_cfg["plant_sim"]) if (m_cfg := series.get("config")) and "plant_sim" in m_cfg
        and m.error_source == "truth" else None,
    )


def plot_replay(series: dict[str, Any], m: RunMetrics, out: Path) -> list[Path]:
    """The run's figures (:func:`.plots.plot_signals`, the same as ``dem-ros sim --plot``) into ``out``."""
    from .plots import plot_signals

    return plot_signals(replay_signals(series, m), out, "dem-ros replay")


def plot_what_if(res: dict[str, Any], out: Path) -> Path:
    """``what_if.png``: the recorded commands and the re-run law's, per coil [V]."""
    from .plots import figure, save

    fig, ax = figure(3, 1, 2.4)
    t = np.array(res["t"])
    old, new = np.array(res["u_recorded"]), np.array(res["u_replayed"])
    for j in range(2):
        ax[j].plot(t, old[:, j], lw=0.8, label=f"recorded ({res['recorded_law']})")
        ax[j].plot(t, new[:, j], "--", lw=0.8, label=f"re-run: {res['law']}")
        ax[j].set_ylabel(f"u{j + 1} [V]")
        ax[j].legend(loc="upper right", fontsize=8)
    for j in range(2):  # the difference: often millivolts on a scale of 80 V
        ax[2].plot(t, (new[:, j] - old[:, j]) * 1e3, lw=0.8, label=f"u{j + 1}")
    ax[2].set_ylabel("re-run - recorded [mV]")
    ax[2].legend(loc="upper right", fontsize=8)
    ax[-1].set_xlabel("t [s] (0: start of the scenario; t < 0: the closed-loop pre-roll)")
    changes = ", ".join(res["changes"]) or "no parameter changes"
    ax[0].set_title(f"what-if replay: {res['law']} ({changes}) on the recorded inputs")
    return save(fig, out / "what_if.png")


def _epoch_ns(reader: Any) -> int | None:
    """t = 0 of the recorded experiment (the plant's loop status ``epoch_ns``), or None (no status recorded)."""
    for _, _, msg in reader.messages([contract.DIAGNOSTICS.name]):
        for st in msg.status:
            if st.name in (contract.LOOP_STATUS, contract.HW_LOOP_STATUS):
                epoch = next((kv.value for kv in st.values if kv.key == "epoch_ns"), None)
                if epoch:
                    return int(epoch)
    return None


def what_if(bag: Path, controller: str | None = None, sets: list[str] | None = None,
            progress: bool = False) -> dict:
    """Re-run a law on the recorded controller inputs; compare with the recorded commands.

    Returns the comparison (``max_abs_diff_v``, ``rms_diff_v`` [V], ``reproduces_recording``) and the
    series ``t`` [s] (experiment clock: t = 0 at the scenario's start, negative in the pre-roll),
    ``u_replayed``, ``u_recorded`` (K, 2) [V]. ``progress``: report on stderr (a long bag takes a while).
    """
    bar = Progress("dem-ros replay", None, "samples", stage=f"reading the recorded inputs of {bag}", enabled=progress)
    try:
        return _what_if(bag, controller, sets, bar)
    finally:
        bar.close()


def _what_if(bag: Path, controller: str | None, sets: list[str] | None, bar: Progress) -> dict:
    from ..bag import BagError, BagReader
    from ..core.controllers import make_controller
    from ..core.params import SCHEMA, apply_overrides, default_config, parse_assignment

    r = BagReader(bag)
    run = r.run_metadata() or {}
    cfg = run.get("config")
    if not cfg:
        raise BagError(f"{bag}: no recorded configuration (run_info); cannot re-run the controller")
    # a bag of an older version may carry parameters removed since (plant_sim.command_timeout): skip those
    known = {g: {p.name for p in specs} for g, specs in SCHEMA.groups.items()}
    recorded = {g: {n: x for n, x in v.items() if n in known[g]} for g, v in cfg.items() if g in SCHEMA.groups}
    # controller parameters added since the recording: the re-run takes their defaults, so the law is not the one
    # that ran, and need not reproduce it (said with the verdict)
    not_recorded = sorted(known["controller"] - set(cfg.get("controller", {})))
    cfg = apply_overrides(default_config(), recorded, "recorded config")
    recorded_law = cfg["controller"]["type"]
    ccfg = dict(cfg["controller"])
    for text in sets or []:
        g, n, v = parse_assignment(text, "controller")
        if g != "controller":
            raise BagError(f"{text!r}: only controller parameters can change in a what-if replay")
        ccfg[n] = v
    ccfg = SCHEMA.validate_group("controller", ccfg)
    name = controller or recorded_law
    est = _arrays(r, contract.ESTIMATE.name)
    ref = _arrays(r, contract.REFERENCE.name)
    app = _arrays(r, contract.APPLIED.name)
    cmd = _arrays(r, contract.COMMAND.name)
    st = _arrays(r, contract.CONTROLLER_STATE.name)
    if est is None or ref is None or cmd is None:
        raise BagError(f"{bag}: needs /dem/state_estimate, /dem/reference and /dem/command for a what-if replay")
    dt_ns = round(ccfg["dt"] * 1e9)
    ref_by = {int(s): i for i, s in enumerate(ref["stamp_ns"])}
    cmd_by = {int(s): i for i, s in enumerate(cmd["stamp_ns"])}
    lag_by = {}
    if st is not None:
        names = list(st["name"])
        if "ref_lag" in names:
            col = names.index("ref_lag")
            lag_by = {int(s): v for s, v in zip(st["stamp_ns"], st["position"][:, col], strict=True)}
    ctrl = make_controller(ccfg, name)
    started = False
    u_new, u_old, stamps = [], [], []
    bar.total = len(est["stamp_ns"])
    bar.stage(f"re-running {name}")
    for i, t in enumerate(est["stamp_ns"]):
        bar.step()
        t = int(t)
        if t not in cmd_by:  # the node did not act on this sample (stale / invalid): neither do we
            continue
        x = np.array([est["position"][i, 0], est["velocity"][i, 0], est["position"][i, 1], est["velocity"][i, 1],
                      est["effort"][i, 0], est["effort"][i, 1]], float)
        lag = lag_by.get(t, 0.0)
        j = ref_by.get(t - int(lag) * dt_ns) if np.isfinite(lag) else None
        # the node's fallback before any reference arrived: hold the measured hover
        rv = ref["position"][j, :8].astype(float) if j is not None else np.array([x[0], x[2], 0, 0, 0, 0, 0, 0.0])
        if not started:
            u0 = np.zeros(2)
            if app is not None:
                k = np.searchsorted(app["stamp_ns"], t, side="right") - 1
                if k >= 0:
                    u0 = app["effort"][k, :2].astype(float)
            ctrl.reset(x.copy(), u0)
            started = True
        u = ctrl.step(x, rv).copy()
        u_new.append(np.clip(u, -ccfg["voltage_limit"], ccfg["voltage_limit"]))
        u_old.append(cmd["effort"][cmd_by[t], :2])
        stamps.append(t)
    if not stamps:
        raise BagError(f"{bag}: no sample on which the controller acted")
    epoch = _epoch_ns(r)
    t0 = epoch if epoch is not None else stamps[0]
    new, old = np.array(u_new), np.array(u_old)
    d = np.abs(new - old)
    return {
        "law": name, "recorded_law": recorded_law, "changes": sets or [], "samples": len(stamps),
        "parameters_not_recorded": not_recorded,
        "max_abs_diff_v": float(d.max()), "rms_diff_v": float(np.sqrt(np.mean(d**2))),
        "reproduces_recording": bool(d.max() <= 1e-9 * max(1.0, float(np.abs(old).max()))),
        "t": ((np.array(stamps) - t0) * 1e-9).tolist(), "u_replayed": new.tolist(), "u_recorded": old.tolist(),
    }


def publish(bag: Path, rate: float = 1.0, progress: bool = True) -> dict:
    """Play the bag onto the DDS graph at its recorded timing (raw CDR, contract QoS).

    ``progress``: a line on stderr at least every 5 s (messages sent of the bag's total).
    """
    from ..bag import BagReader
    from ..transport import make_node

    r = BagReader(bag)
    topics = {t.name: t for t in contract.TOPICS}
    names = [n for n in r.topics if n in topics and n != contract.PARAMETER_EVENTS.name]
    total = sum(r.topics[n].count for n in names)
    node = make_node("dem_ros_player", transport="dds", args=[])
    pubs = {n: node.publisher(topics[n]) for n in names}
    bar = Progress("dem-ros replay --publish", total, "messages",
                   stage="waiting 1 s for subscribers to discover the player", enabled=progress, quiet=0.0)
    time.sleep(1.0)  # discovery
    bar.stage(f"playing {len(pubs)} topics at the recorded rate")
    sent = 0
    start = None
    t_wall0 = time.monotonic_ns()
    try:
        for topic, log_ns, _pub_ns, data in r.raw_messages(list(pubs)):
            if start is None:
                start = log_ns
            due = t_wall0 + int((log_ns - start) / rate)
            now = time.monotonic_ns()
            if due > now:
                time.sleep((due - now) * 1e-9)
            pubs[topic].publish_raw(bytes(data))
            sent += 1
            bar.step()
    finally:
        bar.close()
        node.shutdown()
    return {"published": sent, "topics": list(pubs)}


def cmd_replay(args: Any) -> int:
    """``dem-ros replay``: metrics and figures of a bag, a what-if re-run, or a playback (``--publish``)."""
    bag = Path(args.bag)
    if args.publish:
        res = publish(bag)
        print(f"replay: published {res['published']} messages on {len(res['topics'])} topics")
        return 0
    if args.controller or args.set:
        res = what_if(bag, args.controller, args.set, progress=True)
        verdict = "reproduces the recorded commands" if res["reproduces_recording"] else "differs from the recording"
        print(f"what-if replay of {bag}: law {res['law']} (recorded: {res['recorded_law']}), "
              f"changes {res['changes'] or 'none'}")
        print(f"  {res['samples']} samples; max |u_replayed - u_recorded| = {res['max_abs_diff_v']:.3e} V,"
              f" RMS {res['rms_diff_v']:.3e} V: {verdict}")
        if res["parameters_not_recorded"]:
            print(f"  note: recorded by an earlier version, without controller parameter(s)"
                  f" {', '.join(res['parameters_not_recorded'])}: the re-run uses their defaults, so even the recorded"
                  " law need not reproduce the recording")
        if args.json:
            write_json(args.json, {k: v for k, v in res.items() if k not in ("t", "u_replayed", "u_recorded")})
            print(f"  comparison written to {args.json}")
        if args.plot:
            path = plot_what_if(res, Path(args.plot))
            print(f"  figure written to {path}")
        return 0
    with Progress("dem-ros replay", None) as bar:
        bar.stage(f"reading {bag}")
        m, series = analyse(bag)
    files = plot_replay(series, m, Path(args.plot)) if args.plot else []
    m.print(extra=[("bag", str(bag))])  # the verdict first (dem_ros.tools.verdict)
    if args.json:
        write_json(args.json, m.to_dict())
        print(f"  metrics written to {args.json}")
    if args.plot:
        print(f"  {len(files)} figures written to {args.plot}")
    if m.verdict != OK:
        print(f"replay: {m.verdict_line().replace('verdict  ', '', 1)}", file=sys.stderr)
    return m.exit_code


def cmd_bag(args) -> int:
    from ..bag import check

    if args.action == "check":
        from ..bag import main_check

        return main_check([args.bag])
    rep = check(Path(args.bag))
    print(_bag_info(rep))
    return 0 if rep.ok else 1


def _bag_info(rep: Any) -> str:
    """``dem-ros bag info``: what is in the bag, as ``ros2 bag info`` shows it, plus the run it recorded.

    ``dem-ros bag check`` is the integrity report (summary, chunks, gaps, rates, problems);
    this is the short inventory.
    """
    path = Path(rep.path)
    files = [path / f for f in rep.files] if path.is_dir() else [path]
    size = sum(f.stat().st_size for f in files if f.exists())
    lines = [f"Files:             {', '.join(rep.files) or '-'}", f"Bag size:          {size / 1e6:.1f} MB",
             "Storage id:        mcap"]
    if rep.start_ns is not None and rep.end_ns is not None:
        lines.append(f"Duration:          {(rep.end_ns - rep.start_ns) / 1e9:.3f} s")
    lines.append(f"Messages:          {rep.message_count}")
    run = rep.run_metadata or {}
    if run:
        what = ", ".join(f"{k} {run[k]}" for k in ("scenario", "controller", "estimator", "transport", "duration_s")
                         if k in run)
        lines.append(f"Run:               {what}")
    w = max([len(t.name) for t in rep.topics] + [5])
    lines.append("Topic information:")
    lines += [f"  {t.name:<{w}}  {t.type:<38} {t.count:>9} msgs" for t in rep.topics]
    if rep.truncation:  # what a killed writer left: recovered up to its last complete chunk
        lines.append(f"TRUNCATED:         {rep.truncation}")
    if not rep.ok:
        lines.append(f"({len(rep.problems)} problem(s): see dem-ros bag check)")
    return "\n".join(lines)
