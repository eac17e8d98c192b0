"""The watch on the recorder, hosted by the plant node of the graph (``plant_sim``, or ``hw_driver`` on a rig).

A recorder killed or hung loses the recording from there, and says nothing: the bag ends without a word. So
another node watches it: the plant node, the one every graph has, which owns the run's clock (the experiment's
t = 0) and which the launcher stops before the recorder (a run's normal end is never taken for a lost recorder).

The recorder reports on ``/diagnostics`` once a second (status ``recorder: bag``, ``contract.RECORDER_STATUS``);
the watch checks once a second (its own timer) whether a report came since its previous check, and publishes
its status (``plant_sim: recording``, ``hw_driver: recording``: ``contract.RECORDING_STATUS`` /
``contract.HW_RECORDING_STATUS``). After the recorder has been seen, ``RECORDER_MISSED`` consecutive checks
without a report latch ERROR on that status and log it, with the experiment time of the recorder's last report.

Periods are counted, not wall seconds: after a stall of the host or the executor (seconds without either timer)
the watch's timer may fire before the recorder's, which is one missed check, not a dead recorder; a dead one is
reported 2 to 3 s after its last report.
"""

from __future__ import annotations

from collections.abc import Callable

from .. import contract
from ..transport import Node
from .common import Diagnostics

__all__ = ["RECORDER_CHECK_S", "RECORDER_MISSED", "RecordingWatch"]

RECORDER_CHECK_S = 1.0  # the watch checks the recorder's reports this often (the recorder reports once a second)
RECORDER_MISSED = 2  # consecutive checks without a report: the recorder is dead or hung


class RecordingWatch:
    """The recorder's liveness as ``node`` sees it, on the status ``status`` (module docstring).

    ``experiment_t`` gives the host's experiment time now [s] (the newest sample's t; None before t = 0): the
    time of each of the recorder's reports, named in the fault. The watch subscribes to ``/diagnostics`` and
    runs its own once-a-second timer; the host only makes it.
    """

    def __init__(self, node: Node, status: str, experiment_t: Callable[[], float | None]):
        self.node = node
        self.experiment_t = experiment_t
        self.seen: tuple[int, float | None] | None = None  # (node clock [ns], experiment t [s]) at its last report
        self.reports = 0  # the recorder's reports received
        self._checked = 0  # ... of which were there at the previous check
        self.missed = 0  # consecutive checks with no report since the one before
        self.diag = Diagnostics(node, status, values=self.values, timer=False)
        node.timer(RECORDER_CHECK_S, self.check)
        node.subscribe(contract.DIAGNOSTICS, self.on_diagnostics)

    def on_diagnostics(self, msg) -> None:
        """Note the recorder's reports (their time on the node's clock and the experiment's)."""
        for st in msg.status:
            if st.name == contract.RECORDER_STATUS:
                self.seen = (self.node.now_ns(), self.experiment_t())
                self.reports += 1

    def check(self) -> None:
        """Once a second: did the recorder report since the previous check? ``RECORDER_MISSED`` checks in a row
        without latch the fault (module docstring); else the status is published."""
        seen = self.seen
        if seen is not None:
            if self.reports != self._checked:
                self._checked = self.reports
                self.missed = 0
            else:
                self.missed += 1
            if self.missed >= RECORDER_MISSED and self.diag.faulted is None:
                silent = (self.node.now_ns() - seen[0]) * 1e-9
                when = f"t = {seen[1]:.3f} s" if seen[1] is not None else "before t = 0"
                self.diag.fault(f"the recorder has sent no status for {silent:.1f} s ({self.missed} checks in a row;"
                                f" its last at {when} of the experiment): it is dead or hung, the recording is lost"
                                " from there")
                return  # (published at once by the fault)
        self.diag.publish()

    def values(self) -> dict:
        """The status's values: the recorder ``not seen``, ``alive``, ``late`` (a check missed its report) or
        ``silent`` (``RECORDER_MISSED`` or more), the checks missed in a row, the seconds since its last report
        and that report's experiment time [s] (when after t = 0)."""
        seen = self.seen
        if seen is None:
            return {"recorder": "not seen"}
        silent = (self.node.now_ns() - seen[0]) * 1e-9
        state = "alive" if not self.missed else "silent" if self.missed >= RECORDER_MISSED else "late"
        out: dict = {"recorder": state, "recorder_missed_checks": self.missed, "recorder_silent_s": round(silent, 1)}
        if seen[1] is not None:
            out["recorder_last_t_s"] = round(seen[1], 3)
        return out
