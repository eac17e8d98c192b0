"""A ``run_graph`` supervise hook that stops one node process for a while mid-run (SIGSTOP, then SIGCONT).

What a starved or stalled process looks like to the rest of the graph: its sockets fill, its writers' and
readers' DDS peers see it silent. Shared by the tests that stall the recorder.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from typing import Any


class StopOnce:
    """``supervise(t, procs, restart)``: SIGSTOP ``name`` once the experiment clock reaches ``at_s``, SIGCONT
    ``stop_s`` later (on a thread: the run goes on meanwhile). :attr:`stopped_s` is how long it was stopped
    (None: never, the run ended first); :meth:`join` waits for the SIGCONT."""

    def __init__(self, name: str, at_s: float, stop_s: float):
        self.name, self.at_s, self.stop_s = name, at_s, stop_s
        self.thread: threading.Thread | None = None
        self.stopped_s: float | None = None

    def _stop_and_continue(self, pid: int) -> None:
        os.kill(pid, signal.SIGSTOP)
        t0 = time.monotonic()
        time.sleep(self.stop_s)
        os.kill(pid, signal.SIGCONT)
        self.stopped_s = time.monotonic() - t0

    def __call__(self, t: float | None, procs: dict[str, Any], _restart: Callable[[str], None]) -> tuple[()]:
        if t is not None and t >= self.at_s and self.thread is None:
            self.thread = threading.Thread(target=self._stop_and_continue, args=(procs[self.name].pid,))
            self.thread.start()
        return ()

    def join(self) -> None:
        if self.thread is not None:
            self.thread.join()
