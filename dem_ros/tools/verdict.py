"""The one place that calls a run ``ok``, ``degraded`` or ``failed``, and says why.

Every command that reports a run (``sim``, ``launch``, ``replay``, ``bench loop``, the rows of ``faults``)
gathers the run's facts into a :class:`RunFacts` and asks :func:`judge`; the :class:`Verdict` it returns is
printed as the summary's first line, written to the JSON (``verdict``, ``verdict_reasons``) and is the
exit status (:attr:`Verdict.exit_code`). docs/manual/runs.md has the table.

* **failed** (exit 1): the run never reached t = 0; it has fewer samples than planned (counted on the
  plant's stamp grid in the bag, not from the recorder's counters); the plant failed, or the plate was
  landed, or the driver faulted before the planned end (the end-of-run landing is part of a good run);
  on hardware, the board never reached RUN; the run could not start (no board answered, a node exited).
* **degraded** (exit 3): the run went to its end, but its record is incomplete or its figures are
  qualified: samples or references missing from the bag, a truncated bag, a recorder that stopped, a node
  that refused samples from a writer not bound to its inputs (the graph ran on, but someone else wrote).
* **ok** (exit 0): none of the above.

An interrupted run (Ctrl-C) is judged as any other (it is short: failed) and exits 130.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["DEGRADED", "EXIT_CODES", "FAILED", "INTERRUPTED_EXIT", "OK", "RunFacts", "Verdict", "judge"]

OK, DEGRADED, FAILED = "ok", "degraded", "failed"
#: the exit status of each verdict (an interrupted run: 130 whatever its verdict)
EXIT_CODES = {OK: 0, FAILED: 1, DEGRADED: 3}
INTERRUPTED_EXIT = 130


@dataclass(frozen=True)
class Verdict:
    """``status`` (ok / degraded / failed) and its reasons, one line each (empty when ok)."""

    status: str
    reasons: tuple[str, ...] = ()

    @property
    def failed(self) -> bool:
        return self.status == FAILED

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.status]

    def line(self) -> str:
        """The summary's first line: ``verdict  failed: never reached t = 0; ...``."""
        return f"verdict  {self.status}" + (f": {'; '.join(self.reasons)}" if self.reasons else "")

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.status, "verdict_reasons": list(self.reasons)}


@dataclass
class RunFacts:
    """What a verdict is made of, as the bag (or the offline result, or the launcher) tells it.

    Attributes:
        planned_samples: experiment samples planned (duration / dt); None: no plan known (the run is
            judged on what it has).
        samples: experiment samples the plant produced from t = 0, on its stamp grid (a sample the
            recorder lost still counts: the plant made it).
        reached_t0: the experiment's t = 0 came (the plant's epoch).
        dt: the sample period [s] (to say times).
        failure: (t [s] or None, why) of a plant failure or a driver fault during the experiment.
        landing: (t [s] or None, why) of a landing during the experiment (not the end-of-run landing).
        board_ran: hardware: the board ran the controller's commands (mode RUN) at some sample of the
            experiment; None: not hardware.
        not_started: why the run could not start (no board answered, a node exited before t = 0).
        cut_short: why the run ended before its plan from outside the plant (a node exited).
        problems: what qualifies a complete run (degraded), one line each.
    """

    planned_samples: int | None = None
    samples: int = 0
    reached_t0: bool = True
    dt: float = 1e-3
    failure: tuple[float | None, str] | None = None
    landing: tuple[float | None, str] | None = None
    board_ran: bool | None = None
    not_started: str | None = None
    cut_short: str | None = None
    problems: list[str] = field(default_factory=list)

    def cut_time(self) -> float | None:
        """The experiment time [s] from which the run's samples are not a levitating run's (a failure,
        a landing), or None."""
        times = [x[0] for x in (self.failure, self.landing) if x is not None and x[0] is not None]
        return min(times) if times else None


def _at(t: float | None) -> str:
    return "" if t is None else f" at t = {t:.3f} s"


def judge(f: RunFacts) -> Verdict:
    """The verdict of a run from its facts (see the module docstring for the rules)."""
    failed: list[str] = []
    if f.not_started:
        failed.append(f.not_started)
    elif not f.reached_t0:
        failed.append("never reached t = 0")
    if f.failure is not None:
        failed.append(f"failed{_at(f.failure[0])}: {f.failure[1]}")
    if f.landing is not None:
        failed.append(f"landed before the planned end{_at(f.landing[0])}: {f.landing[1]}")
    if f.board_ran is False and f.reached_t0 and not f.not_started:
        failed.append("the board never reached RUN (it never applied a controller command)")
    if f.cut_short:
        failed.append(f"cut short: {f.cut_short}")
    if f.reached_t0 and not f.not_started and f.planned_samples is not None and f.samples < f.planned_samples:
        failed.append(f"{f.samples} of {f.planned_samples} planned samples ({f.samples * f.dt:.3f} of"
                      f" {f.planned_samples * f.dt:g} s)")
    if failed:
        return Verdict(FAILED, tuple(failed + f.problems))
    if f.problems:
        return Verdict(DEGRADED, tuple(f.problems))
    return Verdict(OK)
