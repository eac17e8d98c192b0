"""The metrics of one run, computed once and printed once, whatever ran it.

``dem-ros sim`` builds a :class:`RunMetrics` from the offline result
(:meth:`RunMetrics.from_sim`), ``dem-ros launch`` and ``dem-ros replay`` from
the recorded bag (:func:`load_run`, the same code for both), and all three
print it with :meth:`RunMetrics.format` and write it with :meth:`RunMetrics.to_dict`.

Tracking error e = true gap - reference-model output y_m (docs/manual/scenarios.md), in
micrometres (``*_um``), matched by stamp and counted from the experiment's
t = 0 (the plant's ``epoch_ns``; the pre-roll is left out); voltages in V,
currents in A, latencies in us.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from .. import contract
from ..core.metrics import error_metrics
from .common import fmt_pair
from .verdict import OK, RunFacts, Verdict, judge

__all__ = ["LoopStats", "RunMetrics", "load_run", "tracking_text"]

_NAN = float("nan")


@dataclass
class LoopStats:
    """The 1 kHz loop as the plant measured it (its last ``plant_sim: loop`` status).

    ``latency_us``: p50 / p99 / max of sensor stamp -> command applied at the plant (us);
    ``realtime_factor``: simulated s per wall s; ``lockstep``: the plant waited for each
    command; ``epoch_ns``: wall-clock stamp of t = 0; ``cpu_percent``: per process, % of one
    core (filled by the launcher, which can measure it; ``plant_cpu_percent`` is the
    plant's own figure, reported because its process ends before the launcher can read it).
    """

    cycles: int
    deadline_misses: int
    latency_us: dict[str, float]
    realtime_factor: float = _NAN
    lockstep: bool = False
    epoch_ns: int | None = None
    plant_cpu_percent: float | None = None
    cpu_percent: dict[str, float] = field(default_factory=dict)
    holds: int = 0  # samples the board held the last voltage for a missing command
    landing: bool = False  # the board landed the plate (or was landing it when the run ended)
    landing_reason: str = ""
    board_mode: str = ""  # the board's last mode (dem_ros.board.Mode name)

    @classmethod
    def from_status(cls, values: Mapping[str, str]) -> LoopStats:
        """From the key/value strings of the plant's loop status."""
        epoch = values.get("epoch_ns")
        try:
            plant_cpu: float | None = round(100.0 * float(values["cpu_s"]) / float(values["wall_s"]), 1)
        except (KeyError, ValueError, ZeroDivisionError):
            plant_cpu = None
        return cls(
            cycles=int(values.get("cycles", 0)),
            deadline_misses=int(values.get("deadline_misses", 0)),
            latency_us={k: float(values.get(f"latency_{k}_us", "nan")) for k in ("p50", "p99", "max")},
            realtime_factor=float(values.get("realtime_factor", "nan")),
            lockstep=values.get("lockstep") == "True",
            epoch_ns=int(epoch) if epoch is not None else None,
            plant_cpu_percent=plant_cpu,
            holds=int(values.get("holds", 0)),
            landing=values.get("landing") == "True",
            landing_reason=values.get("landing_reason", ""),
            board_mode=values.get("board_mode", ""),
        )

    def summary(self) -> str:
        """One line; in lockstep the plant waits for every late command, so those are waits, not misses."""
        lat = self.latency_us
        share = 100.0 * min(self.deadline_misses, self.cycles) / max(self.cycles, 1)
        if self.lockstep:
            text = f"cycles {self.cycles}, plant waited for the command in {self.deadline_misses} ({share:.1f} %)"
        else:
            text = f"cycles {self.cycles}, deadline misses {self.deadline_misses} ({share:.3f} %)"
        if all(math.isfinite(lat.get(k, _NAN)) for k in ("p50", "p99", "max")):  # none before the first sample
            text += f", latency p50 {lat['p50']:.0f} us, p99 {lat['p99']:.0f} us, max {lat['max']:.0f} us"
        if math.isfinite(self.realtime_factor):
            text += f"; x{self.realtime_factor:.2f} real time{' (lockstep)' if self.lockstep else ' (free-running)'}"
        text += f"; holds {self.holds}; landing: " + (f"yes ({self.landing_reason})" if self.landing else "no")
        return text


@dataclass
class RunMetrics:
    """Tracking, effort and loop figures of one run (keys of ``--json``)."""

    scenario: str | None
    controller: str | None
    estimator: str | None
    transport: str | None  # "offline" for dem-ros sim
    error_source: str  # what the true gap is: "simulation", "truth" (/dem/plant/truth) or "measurement"
    samples: int
    failed: bool
    fail_time_s: float | None
    rms_error_um: list[float]  # e1, e2
    max_error_um: list[float]
    rms_error_after_40s_um: list[float]
    peak_voltage_v: float | None = None
    peak_current_a: float | None = None
    final_estimates: dict[str, float] | None = None  # m_kg, R_ohm, K (N m^2/A^2)
    duration_s: float | None = None  # of the experiment (s)
    #: p50, p99, max [us] of the recorder's receipt of a sample's measurement -> of its command (one clock)
    command_latency_at_recorder_us: dict[str, float] | None = None
    wall_time_s: float | None = None
    loop: LoopStats | None = None
    controllers_used: list[str] | None = None  # the laws in the order they ran (a live switch adds one)
    #: what makes a recorded run incomplete or degraded (truncated bag, samples without a reference,
    #: recording failed): the verdict's reasons when there is no worse one
    problems: list[str] = dataclasses.field(default_factory=list)
    #: ok / degraded / failed (dem_ros.tools.verdict: the one place that decides) and why
    verdict: str = OK
    verdict_reasons: list[str] = dataclasses.field(default_factory=list)
    planned_samples: int | None = None  # experiment samples the run was planned for (duration / dt)
    #: a failed run's figures cover only its samples before the failure (or landing): up to this time [s]
    metrics_until_s: float | None = None
    #: what the verdict was made of (not in the JSON: the verdict and its reasons are)
    facts: RunFacts | None = dataclasses.field(default=None, repr=False, compare=False)

    def set_verdict(self, v: Verdict) -> None:
        """Take ``v`` as this run's verdict (``failed`` follows it)."""
        self.verdict, self.verdict_reasons = v.status, list(v.reasons)
        self.failed = v.failed

    @property
    def exit_code(self) -> int:
        return Verdict(self.verdict, tuple(self.verdict_reasons)).exit_code

    def verdict_line(self) -> str:
        return Verdict(self.verdict, tuple(self.verdict_reasons)).line()

    @classmethod
    def from_sim(cls, res: Any) -> RunMetrics:
        """From an offline :class:`~dem_ros.core.simulate.SimResult` (its ``metrics()``)."""
        m = res.metrics()
        out = cls(
            scenario=m["scenario"], controller=m["controller"], estimator=m["estimator"], transport="offline",
            error_source="simulation", samples=int(res.t.size), failed=m["failed"], fail_time_s=m["fail_time_s"],
            rms_error_um=m["rms_error_um"], max_error_um=m["max_error_um"],
            rms_error_after_40s_um=m["rms_error_after_40s_um"], peak_voltage_v=m["peak_voltage_v"],
            peak_current_a=m["peak_current_a"], final_estimates=m["final_estimates"], duration_s=m["duration_s"],
            wall_time_s=m["wall_time_s"],
        )
        fail = (m["fail_time_s"], "a gap left its range (rail contact or drop) or the state went non-finite")
        out.set_verdict(judge(RunFacts(failure=fail if m["failed"] else None, samples=int(res.t.size))))
        if out.failed:
            out.metrics_until_s = m["fail_time_s"]
        return out

    @classmethod
    def from_bag(cls, bag: Path) -> RunMetrics:
        """From a recorded run (graph or ``dem-ros sim --record``); see :func:`load_run`."""
        return load_run(bag)[0]

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out.pop("facts", None)
        return out

    def rows(self) -> list[tuple[str, str]]:
        """(label, value) rows of the printed table."""
        laws = " -> ".join(self.controllers_used) if self.controllers_used else self.controller
        made = self.facts.samples if self.facts is not None else None
        planned = (f"; the plant made {made} of the {self.planned_samples} planned" if made is not None
                   and self.planned_samples is not None else "")
        rows = [
            ("verdict", Verdict(self.verdict, tuple(self.verdict_reasons)).line().split("  ", 1)[1]),
            ("scenario / controller / estimator", f"{self.scenario} / {laws} / {self.estimator} ({self.transport})"),
            ("samples", f"{self.samples} with gap and reference (e = {self.error_source} gap - y_m){planned}"),
        ]
        # a figure that does not apply is left out, never printed as nan: no sample from t = 0 (a plate that
        # landed in the pre-roll) has no error, a run shorter than 40 s no error after 40 s; a failed run's
        # figures cover its samples before the failure, and say so
        span = f", t < {self.metrics_until_s:.3f} s (before the failure)" if self.metrics_until_s is not None else ""
        for label, v in (("RMS error e1 / e2 [um]", self.rms_error_um), ("max error e1 / e2 [um]", self.max_error_um),
                         ("RMS error after 40 s [um]", self.rms_error_after_40s_um)):
            if _finite(v):
                rows.append((label.replace(" [um]", f" [um{span}]"), fmt_pair(v)))
        if self.peak_voltage_v is not None and math.isfinite(self.peak_voltage_v):
            rows.append(("peak |u| [V]", f"{self.peak_voltage_v:.2f}"))
        if self.peak_current_a is not None and math.isfinite(self.peak_current_a):
            rows.append(("peak |i| [A]", f"{self.peak_current_a:.3f}"))
        fe = self.final_estimates
        if fe:
            rows.append(("final m_hat / R_hat / K_hat",
                         f"{fe['m_kg']:.3f} kg / {fe['R_ohm']:.4f} ohm / {fe['K']:.4e} N m^2/A^2"))
        if self.loop is not None:
            rows.append(("loop", self.loop.summary()))
            if self.loop.cpu_percent:
                cpu = self.loop.cpu_percent
                rows.append(("CPU [% of one core]", ", ".join(f"{k} {v:.1f}" for k, v in cpu.items())
                             + f"; total {sum(cpu.values()):.1f}"))
        if self.wall_time_s is not None:
            rows.append(("wall time [s]", f"{self.wall_time_s:.2f}"))
        return rows

    def format(self, extra: Iterable[tuple[str, str]] = ()) -> str:
        """The table: one ``label  value`` line per row (the verdict first), ``extra`` rows appended."""
        rows = self.rows() + list(extra) + [("PROBLEM", p) for p in self.problems]
        w = max(len(k) for k, _ in rows)
        return "\n".join(f"  {k:<{w}}  {v}" for k, v in rows)

    def print(self, file: IO[str] | None = None, extra: Iterable[tuple[str, str]] = ()) -> None:
        print(self.format(extra), file=file)


def tracking_text(rms_um: Iterable[float] | None, offline_um: Iterable[float] | None = None) -> str | None:
    """``"a / b"`` RMS error e1 / e2 [um] (with the offline run's ``"(offline, same timing: c / d)"``), or None.

    None when the run has no such figure (no sample with gap and reference from t = 0, e.g. a plate that
    landed in the pre-roll): the caller leaves the line out instead of printing nan. The offline part is
    left out the same way.
    """
    if not _finite(rms_um):
        return None
    assert rms_um is not None
    text = fmt_pair(list(rms_um))
    if _finite(offline_um):
        assert offline_um is not None
        text += f" (offline, same timing: {fmt_pair(list(offline_um))})"
    return text


def _finite(v: Iterable[float] | None) -> bool:
    """True if ``v`` has values and all are finite numbers."""
    if v is None:
        return False
    vals = list(v)
    return bool(vals) and all(isinstance(x, (int, float)) and math.isfinite(x) for x in vals)


def _final_estimates(names: list[str], row: np.ndarray) -> dict[str, float] | None:
    """m_hat, R_hat, K_hat of the controller's last state message, None if the law has none."""
    v = dict(zip(names, row, strict=False))
    est = [float(v.get(k, _NAN)) for k in ("m_hat", "R_hat", "K_hat")]
    if not all(math.isfinite(x) for x in est):
        return None
    return {"m_kg": est[0], "R_ohm": est[1], "K": est[2]}


def load_run(bag: Path) -> tuple[RunMetrics, dict[str, Any]]:
    """(metrics, series) of a recorded run; the series (s, m, V, A, us) feed the figures.

    Raises:
        BagError: not a bag, or not a dem_ros run (no reference, or neither truth nor measurement).
    """
    from ..bag import BagError, BagReader

    r = BagReader(bag)

    skipped: dict[str, int] = {}  # messages a foreign or corrupt writer left in the bag, per topic

    def arrays(topic: str) -> dict[str, Any] | None:
        if topic not in r.topics or r.topics[topic].count == 0:
            return None
        a = r.joint_state_arrays(topic)
        if a["skipped"]:
            skipped[topic] = a["skipped"]
        return a

    truth = arrays(contract.TRUTH.name)
    ref = arrays(contract.REFERENCE.name)
    meas = arrays(contract.MEASUREMENT.name)
    if ref is None or (truth is None and meas is None):
        have = ", ".join(r.topics) or "none"
        raise BagError(f"{bag}: not a dem_ros run (needs {contract.REFERENCE.name} and {contract.TRUTH.name}"
                       f" or {contract.MEASUREMENT.name}; has: {have})")
    loop_hist = []
    laws: list[str] = []
    refusals: dict[str, tuple[int, str]] = {}  # node's inputs status -> (samples refused so far, its last ERROR)
    for _, log_ns, msg in r.messages([contract.DIAGNOSTICS.name]):
        for s in msg.status:
            name = contract.status_name(s.name)  # a bag recorded before the "<node>: <task>" names: its names now
            if name in (contract.LOOP_STATUS, contract.HW_LOOP_STATUS):
                loop_hist.append((log_ns, {kv.key: kv.value for kv in s.values}))
            elif name.endswith(": " + contract.INPUTS_TASK):
                _note_refusals(refusals, s)
            elif name == contract.CONTROLLER_STATUS:
                law = next((kv.value for kv in s.values if kv.key == "law"), "")
                if law and (not laws or laws[-1] != law):
                    laws.append(law)
    last = loop_hist[-1][1] if loop_hist else {}
    loop = LoopStats.from_status(last) if loop_hist else None
    src = truth if truth is not None else meas
    assert src is not None
    ts, i_s, i_r = np.intersect1d(src["stamp_ns"], ref["stamp_ns"], return_indices=True)
    if loop is not None and loop.epoch_ns is not None:  # the experiment, not the pre-roll
        keep = ts >= loop.epoch_ns
        ts, i_s, i_r = ts[keep], i_s[keep], i_r[keep]
    t0 = ts[0] if ts.size else 0
    t = (ts - t0) * 1e-9
    gaps = src["position"][i_s, :2]
    e = gaps - ref["position"][i_r, :2]
    run = r.run_metadata() or {}
    failed = last.get("failed") == "True"
    em = error_metrics(t, e)
    m = RunMetrics(
        scenario=run.get("scenario"), controller=run.get("controller"), estimator=run.get("estimator"),
        transport=run.get("transport"), error_source="truth" if truth is not None else "measurement",
        samples=int(ts.size), failed=failed,
        fail_time_s=float(last.get("fail_time_s", last.get("t_sim_s", "nan"))) if failed else None,
        rms_error_um=em["rms_error_um"], max_error_um=em["max_error_um"],
        rms_error_after_40s_um=em["rms_error_after_40s_um"], loop=loop,
        duration_s=float(run["duration_s"]) if "duration_s" in run else None,
        controllers_used=laws if len(laws) > 1 else None,
    )
    if len(laws) == 1:
        m.controller = laws[0]
    series: dict[str, Any] = {"t": t, "gaps": gaps, "ref": ref["position"][i_r, :2], "e": e,
                              "config": run.get("config")}
    cmd = arrays(contract.COMMAND.name)
    if cmd is not None and cmd["effort"].size:
        m.peak_voltage_v = float(np.nanmax(np.abs(cmd["effort"])))
        series["cmd_t"] = (cmd["stamp_ns"] - t0) * 1e-9
        series["cmd"] = cmd["effort"][:, :2]
        if meas is not None:  # one clock, the recorder's: it had the sample's measurement, then its command
            _, ic, im = np.intersect1d(cmd["stamp_ns"], meas["stamp_ns"], return_indices=True)
            # A stamp is on the plant's experiment clock (lockstep: behind or ahead of wall time), the log time
            # on the recorder's: their difference is no latency (it was negative). Received together (the
            # recorder read the command's topic first) is 0, never negative
            lat = np.maximum(cmd["log_time_ns"][ic] - meas["log_time_ns"][im], 0) * 1e-3
            if lat.size:
                series["cmd_latency_t"] = (cmd["stamp_ns"][ic] - t0) * 1e-9
                series["cmd_latency_us"] = lat
                m.command_latency_at_recorder_us = {"p50": float(np.percentile(lat, 50)),
                                                    "p99": float(np.percentile(lat, 99)), "max": float(lat.max())}
    if truth is not None:
        series["current"] = truth["effort"][i_s, :2]
        series["mass"] = truth["position"][i_s, 2] if truth["position"].shape[1] > 2 else None
        m.peak_current_a = float(np.nanmax(np.abs(truth["effort"][:, :2])))
    st = arrays(contract.CONTROLLER_STATE.name)
    if st is not None and st["position"].shape[0]:
        m.final_estimates = _final_estimates(list(st["name"]), st["position"][-1])
        series["est_t"] = (st["stamp_ns"] - t0) * 1e-9
        series["est"] = st["position"][:, :3]
    if loop_hist:  # on the experiment clock (t_sim_s), as every other series; not the recorder's arrival times
        series["loop"] = [(float(v.get("t_sim_s", "nan")), int(v.get("deadline_misses", 0)), int(v.get("cycles", 0)))
                          for _, v in loop_hist]
        landing = next((v for _, v in loop_hist if v.get("landing") == "True"), None)
        if landing is not None:
            series["landing"] = (float(landing.get("t_sim_s", "nan")), landing.get("landing_reason", ""))
    epoch = loop.epoch_ns if loop is not None and loop.epoch_ns is not None else None
    had_ref = None  # stamps at which the controller had the reference of its sample (ref_lag 0)
    if st is not None and "ref_lag" in st["name"]:
        had_ref = st["stamp_ns"][st["position"][:, list(st["name"]).index("ref_lag")] == 0]
    m.problems = run_problems(r, src["stamp_ns"], ref["stamp_ns"], epoch, ts, m.duration_s, had_ref)
    m.problems += [f"{n} message(s) on {topic} left out: not the topic's JointState layout (a foreign or corrupt"
                   " writer)" for topic, n in skipped.items()]
    m.problems += [f"{name.split(':')[0]} refused {n} sample(s) {REFUSED} ({why})"
                   for name, (n, why) in refusals.items() if n > 0]
    status = ((r.metadata_yaml or {}).get("custom_data") or {}).get("dem_ros.status")
    facts = run_facts(src["stamp_ns"], epoch, run, loop_hist, m.problems,
                      record_incomplete=r.truncated is not None or status == "failed")
    m.facts = facts
    m.set_verdict(judge(facts))
    m.planned_samples = facts.planned_samples
    cut = facts.cut_time()
    if m.failed and m.fail_time_s is None:
        m.fail_time_s = cut if cut is not None else (facts.samples * facts.dt if facts.reached_t0 else None)
    if m.failed and cut is not None and t.size:  # the figures of the samples before the failure, never after
        keep = t < cut
        em = error_metrics(t[keep], e[keep])
        m.rms_error_um, m.max_error_um = em["rms_error_um"], em["max_error_um"]
        m.rms_error_after_40s_um = em["rms_error_after_40s_um"]
        m.metrics_until_s = cut
    return m, series


_END_OF_RUN = "end of the run"  # how the hardware driver's loop status names the landing that ends a good run


def _float(v: str | None) -> float | None:
    try:
        x = float(v) if v is not None else math.nan
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def run_facts(src_ns: np.ndarray, epoch_ns: int | None, run: Mapping[str, Any],
              loop_hist: list[tuple[int, dict[str, str]]], problems: list[str],
              record_incomplete: bool = False) -> RunFacts:
    """The facts of a recorded run for its verdict (:func:`dem_ros.tools.verdict.judge`).

    Args:
        src_ns: (N,) stamps [ns] of every plant sample in the bag (true or measured gaps), pre-roll included.
        epoch_ns: t = 0 of the experiment (the plant's ``epoch_ns``), None when the bag has no loop status.
        run: the run's metadata (``duration_s``, ``config``).
        loop_hist: (log time, values) of every loop status of the plant (or hardware driver), in order.
        problems: what qualifies the record (degraded); extended here by a recorder that stopped before the
            plant's last samples.
        record_incomplete: the bag says its recording stopped early (truncated, or the recorder's failure):
            samples missing at its end are the record's loss, not a short run (degraded, not failed).

    Samples are counted on the plant's stamp grid (t = 0 to its last stamp in the bag, dt apart), not from
    the recorder's counters: a sample the recorder lost inside the run still counts (a problem of the
    record, reported by :func:`run_problems`), a run the plant ended early does not.
    """
    cfg = run.get("config") or {}
    dt = float((cfg.get("plant_sim") or {}).get("dt") or 1e-3)
    dt_ns = round(dt * 1e9)
    duration = run.get("duration_s")
    planned = round(float(duration) / dt) if duration else None
    exp = src_ns if epoch_ns is None else src_ns[src_ns >= epoch_ns]
    origin = epoch_ns if epoch_ns is not None else (int(exp.min()) if exp.size else 0)
    samples = round((int(exp.max()) - origin) / dt_ns) + 1 if exp.size else 0
    if planned is not None:  # plant_sim stamps t = 0 .. duration (planned + 1 samples), a driver t < duration
        samples = min(samples, planned)
    last = loop_hist[-1][1] if loop_hist else {}
    cycles = int(last.get("cycles", 0) or 0)
    if planned is not None and samples < planned and (planned <= cycles or record_incomplete):
        # the plant made them (its last status says so) or the bag cannot tell (its recording stopped): the
        # record is short, not (as far as the bag knows) the run
        problems.append(f"the bag ends {planned - samples} sample(s) before the planned end (at t = {samples * dt:.3f}"
                        f" of {planned * dt:g} s): the recording stopped early - the metrics cover the recorded"
                        " samples" + ("" if planned <= cycles else "; what happened after is not in the bag"))
        samples = planned
    f = RunFacts(planned_samples=planned, samples=samples, reached_t0=exp.size > 0, dt=dt, problems=problems)
    if last.get("failed") == "True":
        f.failure = (_float(last.get("fail_time_s", last.get("t_sim_s"))), last.get("fault") or "plant failure")
    landing = next((v for _, v in loop_hist if v.get("landing") == "True"
                    and not v.get("landing_reason", "").startswith(_END_OF_RUN)), None)
    if landing is not None:
        t_land = _float(landing.get("landing_t_s", landing.get("t_sim_s")))
        f.landing = (t_land, landing.get("landing_reason") or "the board landed the plate")
    if "board_run_samples" in last:  # hardware: did the board ever apply a controller command in the experiment?
        f.board_ran = int(last["board_run_samples"]) > 0
    return f


def _stretches(idx: np.ndarray) -> tuple[int, int, int]:
    """Runs of consecutive indices in sorted ``idx``: (count of runs, start and length of the longest)."""
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate(([idx[0]], idx[breaks + 1]))
    ends = np.concatenate((idx[breaks], [idx[-1]]))
    k = int(np.argmax(ends - starts))
    return int(starts.size), int(starts[k]), int(ends[k] - starts[k] + 1)


#: the words of a verdict reason that says a node refused a writer's samples (a qualified run, not lost data)
REFUSED = "from writers not bound to its inputs"


def is_refusal(problem: str) -> bool:
    """Whether a run's problem line is a node's refusal of writers (``refused N sample(s) ...``), not a loss."""
    return REFUSED in problem


def _note_refusals(refusals: dict[str, tuple[int, str]], status: Any) -> None:
    """A node's ``<node>: inputs`` status (nodes/common.Inputs): the samples it refused from writers not bound to
    its inputs so far (``refused``, a running count) and the last ERROR that named them (GID and why)."""
    values = {kv.key: kv.value for kv in status.values}
    try:
        n = int(values.get("refused", "0"))
    except ValueError:
        return
    level = contract.status_level(status)
    prev_n, prev_why = refusals.get(status.name, (0, ""))
    why = status.message if level >= 2 and "refused" in status.message else prev_why
    refusals[status.name] = (max(n, prev_n), why)


def run_problems(r: Any, src_ns: np.ndarray, ref_ns: np.ndarray, epoch_ns: int | None, ts: np.ndarray,
                 duration_s: float | None, had_ref_ns: np.ndarray | None = None) -> list[str]:
    """What makes a recorded run's metrics incomplete, one line each (empty: nothing).

    Args:
        r: the open BagReader.
        src_ns: (N,) stamps [ns] of the true (or measured) gaps; ref_ns: (M,) stamps of the reference.
        epoch_ns: t = 0 of the experiment (None: no pre-roll recorded).
        ts: (K,) stamps [ns] the metrics use (both present, from the epoch).
        duration_s: planned experiment length [s] from the run metadata, or None.
        had_ref_ns: stamps [ns] at which the controller had the reference of its sample (its state's
            ``ref_lag`` 0), or None: a reference missing from the bag at such a stamp was lost by the
            recorder, not by the reference node.

    The plant publishes every sample, so a hole in ``src_ns`` is a sample the recorder lost (or, with
    hardware, the board link lost before the driver could publish it): a reader
    that falls behind by more than the writers' history (``contract`` depth, keep-last) loses the oldest
    samples without a trace on its side. Such losses are reported here, from the bag itself.
    """
    out = []
    if r.truncated is not None:
        tr = r.truncated
        out.append(f"bag truncated ({tr.reason}): {tr.file_size - tr.offset} of {tr.file_size} bytes unreadable"
                   " - the metrics cover only what was written")
    status = ((r.metadata_yaml or {}).get("custom_data") or {}).get("dem_ros.status")
    if status == "failed":
        reason = r.metadata_yaml["custom_data"].get("dem_ros.failure", "reason not recorded")
        out.append(f"recording stopped early: {reason}")
    exp = src_ns if epoch_ns is None else src_ns[src_ns >= epoch_ns]
    if exp.size > 2:
        step = np.diff(exp)
        dt = float(np.median(step))
        holes = np.round(step / dt).astype(np.int64) - 1 if dt > 0 else np.zeros(0, np.int64)
        if holes.size and holes.max() > 0:
            out.append(f"{int(holes[holes > 0].sum())} plant sample(s) missing from the bag in {int((holes > 0).sum())}"
                       f" stretch(es), longest {int(holes.max()) * dt * 1e-6:.0f} ms (lost by a recorder that fell "
                       "behind the writers' history on a stalled host, or by the board link before the driver)"
                       " - the metrics cover the recorded samples")
    missing = ~np.isin(exp, ref_ns)
    if missing.any() and had_ref_ns is not None:  # the controller had them: lost in recording
        lost = missing & np.isin(exp, had_ref_ns)
        if lost.any():
            out.append(f"the recorder lost {int(lost.sum())} reference sample(s) the controller received"
                       " - not in the metrics")
        missing &= ~lost
    if missing.any():
        n, start, longest = _stretches(np.flatnonzero(missing))
        out.append(f"{int(missing.sum())} sample(s) without a reference in {n} stretch(es); longest "
                   f"{longest} samples from t = {(exp[start] - exp[0]) * 1e-9:.3f} s"
                   " (reference node down?) - not in the metrics")
    # a run shorter than planned is not a problem of the record but a failed run: the verdict's (run_facts)
    return out
