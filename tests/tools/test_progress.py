"""The one progress mechanism of the long commands (dem_ros/tools/progress.py)."""

import io
import time

from dem_ros.tools.progress import Progress

WAIT_S = 30.0  # bound on waiting for the reporting thread's first line (it needs microseconds of CPU)


class _Tty(io.StringIO):
    def isatty(self):
        return True


def _until_said(bar: Progress) -> None:
    end = time.monotonic() + WAIT_S
    while not bar.said and time.monotonic() < end:
        time.sleep(0.01)
    assert bar.said, "the reporting thread printed nothing"


def test_a_quick_job_prints_nothing():
    out = io.StringIO()
    with Progress("dem-ros x", 10, "runs", stream=out, quiet=60.0) as bar:
        bar.step(10)
    assert out.getvalue() == ""


def test_a_log_gets_whole_lines_with_the_count_eta_failures_and_the_final_state():
    out = io.StringIO()
    bar = Progress("dem-ros x", 10, "runs", stream=out, quiet=0.0, every=0.01)
    bar.stage("matrix")
    bar.step(3, failed=1)
    _until_said(bar)
    bar.step(7)
    bar.close()
    text = out.getvalue()
    assert "\r" not in text and "\033" not in text  # a log carries no redraws
    lines = text.splitlines()
    assert all(x.startswith("dem-ros x: [") for x in lines)
    assert lines[-1].startswith("dem-ros x: [" + "#" * 30 + "] 10/10 runs, ")
    assert "1 failed" in lines[-1] and "- matrix" in lines[-1]


def test_work_of_unknown_length_shows_its_stage_and_ends_with_the_summary():
    out = io.StringIO()
    bar = Progress("dem-ros sim", None, stage="compiling numba kernels: controller adaptive", stream=out, quiet=0.0,
                   every=0.01)
    _until_said(bar)
    bar.close("dem-ros sim: kernels ready in 3 s")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("dem-ros sim: compiling numba kernels: controller adaptive ... (")
    assert lines[-1] == "dem-ros sim: kernels ready in 3 s"


def test_a_terminal_line_is_redrawn_in_place_and_ended():
    out = _Tty()
    bar = Progress("dem-ros x", 4, "messages", stream=out, quiet=0.0)
    bar.step(2)
    _until_said(bar)
    bar.close()
    text = out.getvalue()
    assert text.startswith("\r") and text.endswith("\033[K\n") and text.count("\n") == 1
    assert "4 messages" in text


def test_no_eta_from_the_first_few_steps():
    bar = Progress("dem-ros x", 63033, "messages", enabled=False)
    bar.step(3)
    assert "ETA" not in bar.line()
    bar.step(1000)
    assert "ETA" in bar.line()


def test_disabled_prints_nothing_and_close_is_idempotent():
    out = io.StringIO()
    bar = Progress("dem-ros x", 2, stream=out, enabled=False, quiet=0.0)
    bar.step(2)
    bar.close()
    bar.close()
    assert out.getvalue() == "" and bar.done == 2


def test_a_command_that_cannot_run_still_shows_its_elapsed_time(tmp_path):
    """The lines on a real stream come from a helper process: a command stalled for seconds (here stopped
    outright, SIGSTOP: the extreme of a loaded machine or a compile holding the interpreter) still reports."""
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    log = tmp_path / "progress.log"
    code = ("import sys, time\nfrom dem_ros.tools.progress import Progress\n"
            "bar = Progress('dem-ros x', None, stage='stalled work', quiet=0.0, every=0.2)\ntime.sleep(600)\n")
    root = Path(__file__).resolve().parents[2]
    with open(log, "w") as err:
        cmd = subprocess.Popen([sys.executable, "-c", code], stderr=err, env={**os.environ, "PYTHONPATH": str(root)})

    def lines() -> list[str]:
        return log.read_text().splitlines()

    try:
        end = time.monotonic() + WAIT_S
        while not lines() and time.monotonic() < end:
            time.sleep(0.05)
        assert lines(), "no progress line at all"
        cmd.send_signal(signal.SIGSTOP)  # the command cannot run at all from here
        before = len(lines())
        end = time.monotonic() + WAIT_S
        while len(lines()) < before + 3 and time.monotonic() < end:
            time.sleep(0.05)
        stalled = lines()[before:]
        assert len(stalled) >= 3, f"{len(stalled)} line(s) while the command was stopped"
        assert all(x.startswith("dem-ros x: stalled work ... (") and x.endswith(" s)") for x in stalled)
    finally:
        cmd.send_signal(signal.SIGCONT)
        cmd.kill()
        cmd.wait()
    # the command is gone: its helper sees the end of its input and exits (nothing left behind)
    end = time.monotonic() + WAIT_S
    n = len(lines())
    time.sleep(1.0)
    while len(lines()) != n and time.monotonic() < end:
        n = len(lines())
        time.sleep(1.0)
    assert len(lines()) == n
