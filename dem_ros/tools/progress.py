"""Progress of a long ``dem-ros`` command: the one mechanism every command uses.

A command that may take more than a few seconds (compiling the kernels, ``report``, ``study``,
``replay --publish``, a what-if replay) reports on stderr through :class:`Progress`:

* nothing is printed if the work ends within ``quiet`` seconds (a warm start stays silent);
* then one line, and again at least every ``every`` seconds while it runs, whether or not the
  work advanced (one long step, e.g. a compile, is never a silent wait);
* on a terminal the line is redrawn in place (``\\r``) twice a second; in a log or a pipe each
  report is a new line and no ``\\r`` is written;
* :meth:`Progress.close` ends with a summary line (or the final count), if anything was printed.

The lines on a real stream (stderr, a log file, a pipe) are written by a small helper process, not by
a thread of the command: a thread needs the interpreter lock to print, and a command that compiles
(numba), reads a bag or tears down a large interpreter on a loaded machine may not let it have the
lock for many seconds. The command's thread sends the helper the current line whenever it changes;
the helper prints the latest with its own clock, so a stalled command still shows its elapsed time
on time. A stream without a file descriptor (a ``StringIO`` in tests) is written by the thread.

The work advances with :meth:`Progress.step` (cheap: a counter; the reporting thread prints) and
names its current stage with :meth:`Progress.stage`. Lines look like::

    dem-ros report: [#########                     ] 24/84 runs, 31 s, ETA 71 s, 1 failed
    dem-ros sim: compiling numba kernels (first run only; cached for later runs): controller paper ... (10 s)
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
from types import TracebackType
from typing import IO

__all__ = ["Progress"]

#: where the elapsed seconds go in a line sent to the helper (it fills them in at print time)
_ELAPSED = "\x00"

#: the helper: prints the latest line received on stdin (``_ELAPSED`` -> its own elapsed time) after
#: ``quiet`` s and then every ``period`` s; exits on EOF (also when the command dies), status 3 if it printed
#: anything; Ctrl-C (the whole foreground group gets it) is the command's to handle. Arguments:
#: t0 (CLOCK_MONOTONIC of the start, shared by every process on Linux), quiet, period, 1 = redraw in place
_HELPER = r"""
import os, select, signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the command's to handle; it ends this with EOF
t0, quiet, period, tty = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4] == "1"
line, buf, said, due = "", b"", False, t0 + quiet
while True:
    ready = select.select([0], [], [], max(0.0, due - time.monotonic()))[0]
    if ready:
        data = os.read(0, 65536)
        if not data:
            break
        *lines, buf = (buf + data).split(b"\n")
        line = lines[-1].decode() if lines else line
        continue
    if line:
        text = line.replace("\x00", f"{time.monotonic() - t0:.0f}")
        os.write(1, (("\r" + text + "\x1b[K") if tty else (text + "\n")).encode())
        said = True
    due = time.monotonic() + period
sys.exit(3 if said else 0)
"""


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
        self._helper: subprocess.Popen | None = None
        if enabled:
            self._helper = self._start_helper()
            self._thread = threading.Thread(target=self._feed if self._helper else self._run,
                                            name=f"progress: {prefix}", daemon=True)
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
            if self._helper is not None:
                self._stop_helper(self._helper)
                self._helper = None
            if self.said and (summary or self.total is not None or self.tty):
                self._print(summary or self.line(), end=True)
        return dt

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, typ: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # -- the reporting thread ------------------------------------------------------------------------------------
    def line(self, elapsed: str | None = None) -> str:
        """The current state as one line (no newline); ``elapsed``: the text in place of the elapsed seconds."""
        dt = self.elapsed
        secs = f"{dt:.0f}" if elapsed is None else elapsed
        what = f" - {self.what}" if self.what and self.total is not None else ""
        if self.total is None:
            return f"{self.prefix}: {self.what or 'working'} ... ({secs} s)"
        frac = min(1.0, self.done / max(self.total, 1))
        new = self.done - self._start_done
        rate = new / dt if dt > 0 else 0.0
        settled = new >= max(1, self.total // 100)  # a rate from the first few steps is no estimate
        eta = (f", ETA {(self.total - self.done) / rate:.0f} s" if settled and rate > 0 and self.done < self.total
               else "")
        failed = f", {self.failed} failed" if self.failed else ""
        return (f"{self.prefix}: [{'#' * int(30 * frac):<30}] {self.done}/{self.total} {self.unit}, "
                f"{secs} s{eta}{failed}{what}")

    def _print(self, text: str, end: bool = False) -> None:
        with self._lock:
            if self.tty:
                self.stream.write("\r" + text + "\033[K" + ("\n" if end else ""))
            else:
                self.stream.write(text + "\n")
            self.stream.flush()

    def _start_helper(self) -> subprocess.Popen | None:
        """The printing process on the stream's file descriptor; None (the thread prints) if it has none."""
        try:
            fd = self.stream.fileno()
        except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError
            return None
        period = 0.5 if self.tty else self.every
        self.stream.flush()
        try:
            return subprocess.Popen([sys.executable, "-I", "-S", "-c", _HELPER, repr(self._t0), str(self.quiet),
                                     str(period), "1" if self.tty else "0"],
                                    stdin=subprocess.PIPE, stdout=fd, stderr=subprocess.DEVNULL)
        except OSError:
            return None

    def _feed(self) -> None:
        """Send the helper the current line whenever it changes (4 times a second at most)."""
        helper = self._helper
        assert helper is not None and helper.stdin is not None
        fd = helper.stdin.fileno()
        os.set_blocking(fd, False)
        sent = ""
        while True:
            text = self.line(elapsed=_ELAPSED)
            if text != sent:
                with contextlib.suppress(BlockingIOError, BrokenPipeError):  # a stalled helper: the next change
                    os.write(fd, (text.replace("\n", " ") + "\n").encode())
                    sent = text
            if self._stop.wait(0.25):
                return

    def _stop_helper(self, helper: subprocess.Popen) -> None:
        assert helper.stdin is not None
        with contextlib.suppress(OSError):
            helper.stdin.close()  # EOF: the helper exits (status 3 if it printed)
        try:
            helper.wait(timeout=30.0)  # scheduled at once on an idle machine, within seconds on a loaded one
        except subprocess.TimeoutExpired:
            helper.kill()
            helper.wait()
        self.said = self.said or helper.returncode == 3

    def _run(self) -> None:
        if self._stop.wait(self.quiet):
            return
        period = 0.5 if self.tty else self.every
        while True:
            self.said = True
            self._print(self.line())
            if self._stop.wait(period):
                return
