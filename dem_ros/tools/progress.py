"""Progress of a long ``dem-ros`` command: the one mechanism every command uses.

A command that may take more than a few seconds (compiling the kernels, ``report``, ``study``,
``replay --publish``, a what-if replay) reports on stderr through :class:`Progress`:

* nothing is printed if the work ends within ``quiet`` seconds (a warm start stays silent);
* then one line, and again at least every ``every`` seconds while it runs, whether or not the
  work advanced (one long step, e.g. a compile, is never a silent wait);
* on a terminal the line is redrawn in place (``\\r``) twice a second; in a log or a pipe each
  report is a new line and no ``\\r`` is written;
* :meth:`Progress.close` ends with a summary line (or the final count), if anything was printed.

The work advances with :meth:`Progress.step` (cheap: a counter; the reporting thread prints) and
names its current stage with :meth:`Progress.stage`. Lines look like::

    dem-ros report: [#########                     ] 24/84 runs, 31 s, ETA 71 s, 1 failed
    dem-ros sim: compiling numba kernels (first run only; cached for later runs): controller paper ... (10 s)
"""

from __future__ import annotations

import sys
import threading
import time
from types import TracebackType
from typing import IO

__all__ = ["Progress"]


class Progress:
    """A progress report on ``stream`` (default stderr), printed by a background thread.

    Args:
        prefix: who reports (``"dem-ros report"``); starts every line.
        total: number of steps (runs, messages, ...), or None for work of unknown length
            (then the line shows the stage and the elapsed time); may be set later, once known.
        unit: what a step is, in the plural (``"runs"``, ``"messages"``).
        stage: what is being done first (see :meth:`stage`).
        done: steps already done before this session (e.g. rows of a resumed study).
        enabled: False: print nothing (``--quiet``, tests).
        stream: where to write; its ``isatty()`` picks in-place redraws or new lines.
        quiet: seconds of silence before the first line [s].
        every: longest silence after that on a non-terminal [s] (a terminal redraws every 0.5 s).
    """

    def __init__(self, prefix: str, total: int | None = None, unit: str = "steps", *, stage: str = "", done: int = 0,
                 enabled: bool = True, stream: IO[str] | None = None, quiet: float = 1.0, every: float = 5.0):
        self.prefix, self.total, self.unit = prefix, total, unit
        self.done = done
        self.failed = 0
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.quiet, self.every = quiet, every
        self.what = stage
        self.said = False
        self._start_done = done
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        if enabled:
            self._thread = threading.Thread(target=self._run, name=f"progress: {prefix}", daemon=True)
            self._thread.start()

    # -- what the work calls -------------------------------------------------------------------------------------
    def step(self, n: int = 1, failed: int = 0) -> None:
        """``n`` more steps done, ``failed`` of them failed."""
        self.done += n
        self.failed += failed

    def stage(self, what: str) -> None:
        """Name what is being done now (shown on the line)."""
        self.what = what

    @property
    def elapsed(self) -> float:
        """Seconds since the start [s]."""
        return time.monotonic() - self._t0

    def close(self, summary: str | None = None) -> float:
        """Stop reporting; returns the elapsed s.

        If anything was printed, ``summary`` follows (e.g. "ready in 12 s"); without one, a counted job
        ends with its final count (a terminal's redrawn line always ends with its final state).
        """
        dt = self.elapsed
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
            if self.said and (summary or self.total is not None or self.tty):
                self._print(summary or self.line(), end=True)
        return dt

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, typ: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # -- the reporting thread ------------------------------------------------------------------------------------
    def line(self) -> str:
        """The current state as one line (no newline)."""
        dt = self.elapsed
        what = f" - {self.what}" if self.what and self.total is not None else ""
        if self.total is None:
            return f"{self.prefix}: {self.what or 'working'} ... ({dt:.0f} s)"
        frac = min(1.0, self.done / max(self.total, 1))
        new = self.done - self._start_done
        rate = new / dt if dt > 0 else 0.0
        settled = new >= max(1, self.total // 100)  # a rate from the first few steps is no estimate
        eta = f", ETA {(self.total - self.done) / rate:.0f} s" if settled and rate > 0 and self.done < self.total else ""
        failed = f", {self.failed} failed" if self.failed else ""
        return (f"{self.prefix}: [{'#' * int(30 * frac):<30}] {self.done}/{self.total} {self.unit}, "
                f"{dt:.0f} s{eta}{failed}{what}")

    def _print(self, text: str, end: bool = False) -> None:
        with self._lock:
            if self.tty:
                self.stream.write("\r" + text + "\033[K" + ("\n" if end else ""))
            else:
                self.stream.write(text + "\n")
            self.stream.flush()

    def _run(self) -> None:
        if self._stop.wait(self.quiet):
            return
        period = 0.5 if self.tty else self.every
        while True:
            self.said = True
            self._print(self.line())
            if self._stop.wait(period):
                return
