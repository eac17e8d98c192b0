"""The judges of ``dem-ros faults``: a run's outcome, reports and losses, read from its bag (truth, reference,
``/diagnostics``, ``/rosout``), the launcher's run-state events and the emulated board's own figures (its
run-state events and summary).

Reports are structured records, never log text: ``/diagnostics`` statuses and ``/rosout`` records
(``rcl_interfaces/msg/Log``) at WARN or above, by their name and stamp.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ... import contract

if TYPE_CHECKING:
    from .spec import FaultSpec

__all__ = ["RosoutRecord", "rosout_counts", "rosout_heard", "rosout_record", "run_events"]

#: rcl_interfaces/msg/Log's WARN level: records at it or above count as a report
ROSOUT_WARN = 30


class RosoutRecord(NamedTuple):
    """One ``/rosout`` record at WARN or above: its stamp (the logger's clock, ns), logger name, level, text."""

    stamp_ns: int
    name: str
    level: int
    msg: str


def rosout_record(log: Any) -> RosoutRecord | None:
    """An ``rcl_interfaces/msg/Log`` as a :class:`RosoutRecord`; None below WARN. Its ``uint8`` level as an int,
    whichever way the decoder gave it (an int, or one byte)."""
    level = log.level[0] if isinstance(log.level, (bytes, bytearray)) else int(log.level)
    if level < ROSOUT_WARN:
        return None
    return RosoutRecord(int(log.stamp.sec) * 1_000_000_000 + int(log.stamp.nanosec), str(log.name), level,
                        str(log.msg))


def rosout_counts(records: Iterable[RosoutRecord]) -> dict[str, int]:
    """Records per logger name."""
    out: dict[str, int] = {}
    for rec in records:
        out[rec.name] = out.get(rec.name, 0) + 1
    return out


def rosout_heard(recorded: Iterable[RosoutRecord], live: Iterable[RosoutRecord], since_ns: int,
                 exclude: Iterable[str] = ()) -> tuple[list[RosoutRecord], str]:
    """The ``/rosout`` records at WARN or above stamped at or after ``since_ns`` (ROS time), ``exclude``'s loggers
    excepted: the bag's, then those heard live that the bag lacks (a full disk stops the recording); and the
    reported column's words for them, ``"controller 3, recorder 1 (live)"`` (count per logger; "nothing")."""
    skip = set(exclude)
    bag = [r for r in recorded if r.stamp_ns >= since_ns and r.name not in skip]
    seen = set(bag)
    live_only = [r for r in live if r.stamp_ns >= since_ns and r.name not in skip and r not in seen]
    said = [f"{n} {c}" for n, c in sorted(rosout_counts(bag).items())]
    said += [f"{n} {c} (live)" for n, c in sorted(rosout_counts(live_only).items())]
    return bag + live_only, ", ".join(said) or "nothing"

def _read_bag(bag: Path, measured: bool = False) -> dict[str, Any]:
    """What the judges read from a run's bag: truth, reference (and measurement) arrays, every /diagnostics
    status (log time, name, level, message, values), the last loop status and its epoch, the /rosout records at
    WARN or above (:class:`RosoutRecord`), truncation."""
    from ...bag import BagReader

    undecodable: dict[str, int] = {}

    def decoded(r: BagReader, topic: str, type_name: str) -> list[tuple[int, Any]]:
        """(log time, message) of every sample of ``topic`` that decodes; the others are counted."""
        from ...transport import TransportError, deserialize

        if topic not in r.topics:
            return []
        got = []
        for _, log_ns, _, data in r.raw_messages([topic]):
            try:
                got.append((log_ns, deserialize(type_name, bytes(data), transport="dds")))
            except TransportError:  # the strict decoder's CdrError (type, field, offset)
                undecodable[topic] = undecodable.get(topic, 0) + 1
        return got

    def arrays(msgs: list[tuple[int, Any]]) -> dict[str, np.ndarray] | None:
        from ...nodes.common import stamp_ns

        rows = [(stamp_ns(m), m.position[0], m.position[1]) for _, m in msgs if len(m.position) >= 2]
        if not rows:
            return None
        a = np.array(rows, dtype=float)
        return {"stamp_ns": a[:, 0].astype(np.int64), "position": a[:, 1:3]}

    with BagReader(bag) as r:
        truth = arrays(decoded(r, contract.TRUTH.name, contract.TRUTH.type))
        ref = arrays(decoded(r, contract.REFERENCE.name, contract.REFERENCE.type))
        meas = arrays(decoded(r, contract.MEASUREMENT.name, contract.MEASUREMENT.type)) if measured else None
        loop: dict[str, str] = {}
        epoch = None
        diags = []
        for log_ns, msg in decoded(r, contract.DIAGNOSTICS.name, contract.DIAGNOSTICS.type):
            for s in msg.status:
                vals = {kv.key: kv.value for kv in s.values}
                name = contract.status_name(s.name)
                if name in (contract.LOOP_STATUS, contract.HW_LOOP_STATUS):
                    loop = vals
                    if vals.get("epoch_ns", "").isdigit():
                        epoch = int(vals["epoch_ns"])
                level = contract.status_level(s)
                diags.append((log_ns, name, level, s.message, vals))
        logs = [rec for _, m in decoded(r, contract.ROSOUT.name, contract.ROSOUT.type)
                if (rec := rosout_record(m)) is not None]
        truncated = r.truncated
    problems = [f"{n} recorded sample(s) of {topic} do not decode (the injected ones, recorded as sent)"
                for topic, n in undecodable.items()]
    return {"truth": truth, "ref": ref, "meas": meas, "loop": loop, "epoch": epoch, "diags": diags,
            "rosout": logs, "truncated": truncated, "problems": problems}


def _worst_levels(statuses: Iterable[tuple[str, int]]) -> list[str]:
    """'name WARN' / 'name ERROR' per status name at its worst level, for (name, level) pairs at WARN or above."""
    seen: dict[str, int] = {}
    for name, level in statuses:
        if level >= 1:
            seen[name] = max(seen.get(name, 0), level)
    return [f"{n} {'WARN' if lv == 1 else 'ERROR'}" for n, lv in sorted(seen.items())]


def _routine_warn(reported: str) -> bool:
    """Whether a 'name LEVEL' of :func:`_worst_levels` (perhaps with " (live)") is a WARN that a lockstep run on a
    loaded machine has without a fault: the plant's loop status (it waited), a topic's status (its rate fell)."""
    text = reported.split(" (live)")[0]
    name, _, level = text.rpartition(" ")
    return level == "WARN" and (name == contract.LOOP_STATUS or name.endswith(contract.TOPIC_STATUS_SUFFIX))


def _levels_after(diags: list[tuple], t_f: int) -> list[str]:
    """'name LEVEL' of every status at WARN or ERROR from 1 s before the fault (the once-a-second reports
    cover the second of the fault), the worst level per name."""
    return _worst_levels((name, level) for log_ns, name, level, *_ in diags if log_ns >= t_f - 10**9)


def _judge(bag: Path, t_fault_s: float, cfg: dict) -> dict[str, Any]:
    """Outcome, min gap, diagnostics, /rosout records (WARN and above, all of them) and bag problems of a recorded
    run."""
    b = _read_bag(bag)
    out: dict[str, Any] = {"diagnostics": [], "problems": list(b["problems"])}
    truth, ref, loop, epoch, truncated = b["truth"], b["ref"], b["loop"], b["epoch"], b["truncated"]
    t_f = (epoch or 0) + round(t_fault_s * 1e9)
    out["fault_ns"] = t_f
    out["diagnostics"] = _levels_after(b["diags"], t_f)
    out["rosout"] = b["rosout"]
    pc = cfg["plant_sim"]
    if truth is None:
        out.update(outcome="failed", min_gap_mm=None, detail="no plant truth recorded")
        return out
    after = truth["stamp_ns"] >= t_f
    g = truth["position"][:, :2]
    gmin = float(np.nanmin(g[after])) if after.any() else float(np.nanmin(g))
    out["min_gap_mm"] = round(gmin * 1e3, 3)
    mode = loop.get("board_mode", "")
    failed = loop.get("failed", "False") == "True" or gmin <= pc["gap_min"]
    landed = mode in ("LAND", "LANDED") or loop.get("landing", "False") == "True"
    end_err = float("inf")
    if ref is not None:
        ts, i_t, i_r = np.intersect1d(truth["stamp_ns"], ref["stamp_ns"], return_indices=True)
        if ts.size:
            end_err = float(np.max(np.abs(g[i_t[-1]] - ref["position"][i_r[-1], :2])))
            win = ts >= t_f
            if win.any():  # the largest tracking error e = true gap - y_d from the fault on
                out["max_error_um"] = round(float(np.max(np.abs(g[i_t[win]] - ref["position"][i_r[win], :2]))) * 1e6, 1)
    if failed:
        out["outcome"] = "failed"
        out["detail"] = loop.get("fault", "") or f"min gap {gmin * 1e3:.3f} mm"
    elif landed:
        # safe: the board landed it before the plate came nearer the rail than its own trip gap
        out["outcome"] = "landed safely" if gmin >= pc["trip_gap_min"] else "failed"
        out["detail"] = loop.get("landing_reason", "") + ("" if gmin >= pc["trip_gap_min"] else
                                                          f"; within {gmin * 1e3:.3f} mm of the rail first")
    elif end_err < 1e-3:
        out["outcome"] = "levitating"
    else:
        out["outcome"] = "failed"
        out["detail"] = f"{end_err * 1e3:.2f} mm off the reference at the end"
    _bag_problems(bag, cfg, truncated, out)
    return out


def _bag_problems(bag: Path, cfg: dict, truncated: Any, out: dict[str, Any]) -> None:
    """What the bag says about itself (RunMetrics' problems, truncation) into ``out["problems"]``."""
    from ...bag import BagError
    from ..runmetrics import load_run

    try:
        m, _ = load_run(bag)
        out["problems"] += list(m.problems)
        out["recorded_s"] = m.samples * cfg["plant_sim"]["dt"]  # experiment time the bag covers from t = 0
    except BagError as exc:  # the bag layer's own error (one line): reported as the data lost
        out["problems"].append(f"bag unreadable: {exc}")
    if truncated is not None and not any("truncated" in p for p in out["problems"]):
        out["problems"].append(f"bag truncated ({truncated.reason})")


def _rig_statuses(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The emulated board's once-a-second statuses among the run's run-state events (node ``rig``)."""
    return [e for e in events if e.get("node") == "rig" and e.get("event") == "status"]


def _number(v: Any) -> float:
    """A counter as a number: a /diagnostics value string, an int, or a text (non-empty: 1)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    try:
        return float(v)
    except (TypeError, ValueError):
        return 1.0 if v not in (None, "", "False", "0") else 0.0


def _counted(spec: FaultSpec, sources: dict[str, dict[str, Any]]) -> tuple[bool, str, dict[str, float]]:
    """(every counter of ``spec.counts`` reached its minimum, 'driver sensor_holds 2, board ...', the values)."""
    ok, said, got = True, [], {}
    for where, key, least in spec.counts:
        v = _number(sources.get(where, {}).get(key, 0))
        ok = ok and v >= least
        got[f"{where} {key}"] = v
        said.append(f"{where} {key} {v:g}" + ("" if v >= least else f" (< {least})"))
    return ok, ", ".join(said), got


_AT_T = re.compile(r" at t = (-?[0-9.]+) s")


def _judge_hw(bag: Path, t_fault_s: float, cfg: dict, spec: FaultSpec, rig: dict[str, Any] | None,
              rig_statuses: list[dict[str, Any]]) -> dict[str, Any]:
    """Outcome of a hardware row: the board's landing from the driver's loop status in the bag, the plate's
    truth from the emulator (smallest gap since the release, fastest descent while the board landed it,
    rail contact), the end error from the recorded measurement (a rig has no truth topic)."""
    b = _read_bag(bag, measured=True)
    out: dict[str, Any] = {"diagnostics": [], "problems": list(b["problems"])}
    ref, meas, loop = b["ref"], b["meas"], b["loop"]
    t_f = (b["epoch"] or 0) + round(t_fault_s * 1e9)
    out["fault_ns"] = t_f
    out["diagnostics"] = _levels_after(b["diags"], t_f)
    out["rosout"] = b["rosout"]
    out["messages"] = [(name, msg) for log_ns, name, level, msg, _ in b["diags"] if log_ns >= t_f and level >= 1]
    last: dict[str, dict[str, str]] = {}  # each status's last values (the estimator's counters)
    for _, name, _, _, vals in b["diags"]:
        last[name] = vals
    out["statuses"], out["loop"] = last, loop
    pc = cfg["plant_sim"]
    _bag_problems(bag, cfg, b["truncated"], out)
    end_err = float("inf")
    if ref is not None and meas is not None:
        ts, i_m, i_r = np.intersect1d(meas["stamp_ns"], ref["stamp_ns"], return_indices=True)
        if ts.size:
            g = meas["position"]
            end_err = float(np.max(np.abs(g[i_m[-1]] - ref["position"][i_r[-1], :2])))
            win = ts >= t_f
            if win.any():  # the largest measured error (gap - y_d) from the fault on
                out["max_error_um"] = round(float(np.max(np.abs(g[i_m[win]] - ref["position"][i_r[win], :2]))) * 1e6, 1)
    if rig is None:
        out.update(outcome="failed", min_gap_mm=None, detail="the emulated board wrote no summary (see rig.log)")
        return out
    gmin = rig.get("min_gap_mm")
    out["min_gap_mm"] = gmin
    descent = float(rig.get("land_speed_max_mm_s") or 0.0)
    bound = pc["landing_speed"] * 1e3
    truth = (f"true: fastest descent {descent:.1f} mm/s (landing_speed {bound:g}"
             + ("" if spec.descent_bounded else ", not bounded for this fault") + ")")
    reason = loop.get("landing_reason", "")
    down = loop.get("landing", "False") == "True" and not reason.startswith("end of the run")
    driver_failed = loop.get("failed", "False") == "True"
    fault_modes = [st["t_s"] for st in rig_statuses if st.get("mode") == "FAULT"]
    if gmin is None:
        out["outcome"] = "failed"
        out["detail"] = f"the board never released the plate (board {rig.get('mode')}: {rig.get('reason', '')})"
    elif rig.get("failed") or gmin * 1e-3 <= pc["gap_min"]:
        out["outcome"] = "failed"
        out["detail"] = f"rail contact: {rig.get('failed') or f'true gap {gmin:.3f} mm'}"
    elif rig.get("mode") == "FAULT" or fault_modes:
        out["outcome"] = "failed"
        out["detail"] = f"board FAULT (0 V: the plate dropped onto its support): {rig.get('reason', '')}"
    elif down or driver_failed:
        why = reason if down else f"driver fault at t = {loop.get('fail_time_s', '?')} s: {loop.get('fault', '')}"
        m = _AT_T.search(why)
        landed_at = float(m.group(1)) if m else None
        out["landed_at_s"] = landed_at
        unsafe = []
        if gmin < pc["trip_gap_min"] * 1e3:
            unsafe.append(f"within {gmin:.3f} mm of the rail first")
        if spec.descent_bounded and descent > bound:
            unsafe.append(f"descent {descent:.1f} mm/s > landing_speed {bound:g} mm/s")
        out["outcome"] = "failed" if unsafe else "landed safely"
        out["detail"] = "; ".join([why, truth, *unsafe])
        if landed_at is not None and landed_at < t_fault_s - 0.005:
            out["early"] = f"the board landed at t = {landed_at:.3f} s, before the fault: not this fault's landing"
    elif end_err < 1e-3:
        out["outcome"] = "levitating"
    else:
        out["outcome"] = "failed"
        out["detail"] = f"{end_err * 1e3:.2f} mm off the reference at the end (measured)"
    return out


def run_events(info: dict[str, Any], logdir: Path | None) -> list[dict[str, Any]]:
    """The run's run-state events: from the launch facts, else from the file the launcher keeps beside the logs
    (a run whose bag could not be summarised)."""
    from ..launcher import RUN_STATE_FILE

    if info.get("events"):
        return list(info["events"])
    try:
        text = (logdir / RUN_STATE_FILE).read_text() if logdir is not None else ""
    except OSError:
        return []
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def _plant_end(info: dict[str, Any]) -> str:
    """The plant's own last word, its "finished" run-state event: "finished 4 s", "landed safely at ...",
    "plant failure ..." ("": none came)."""
    ends = [e for e in info.get("events") or [] if e.get("event") == "finished" and e.get("node") == "plant_sim"]
    return str(ends[-1].get("message", "")) if ends else ""


def _outage_s(info: dict[str, Any], name: str, killed_ns: int | None) -> float | None:
    """Seconds from the SIGKILL of ``name`` to the "ready" event of its restarted process, or None."""
    if killed_ns is None:
        return None
    ready = [int(e["time_ns"]) for e in info.get("events") or []
             if e.get("event") == "ready" and e.get("node") == name and int(e.get("time_ns", 0)) > killed_ns]
    return (ready[0] - killed_ns) * 1e-9 if ready else None


def _lost(info: dict[str, Any], problems: list[str]) -> list[str]:
    """What a run lost: the recorder's drops, what the bag says about itself, a summary that could not be made
    (a node's refusal of a foreign writer qualifies the run, it loses nothing: the ``reported`` column has it)."""
    from ..runmetrics import is_refusal

    problems = [p for p in problems if not is_refusal(p)]
    dropped = sum(v.get("dropped", 0) for v in (info.get("recorder") or {}).values())
    lost = [f"{dropped} dropped", *problems] if dropped else list(problems)
    if info.get("summary_error"):
        lost.append(f"dem-ros launch could not summarise the bag: {info['summary_error']}")
    return lost
