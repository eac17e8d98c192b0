"""Every user mistake: one line naming the problem, exit status 2, no traceback, nothing written.

Each row runs the real command line (``python -m dem_ros.tools.cli ...``) as a
subprocess in an empty working directory. The checks that make these mistakes
cheap run before anything starts (argument types, the parameter schema, the
environment), so no row starts a node, compiles a kernel or writes a bag.

Rows: (id, argv, extra environment, a word the one line must contain).

On a loaded machine the interpreter may take seconds to load numpy and the package before the
arguments are read; ``dem-ros`` then says so on a progress line (``dem-ros sim: starting: loading ...
(2 s)``), which is not part of the error report and is not counted (its form is checked).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from dem_ros.transport import rclpy_available

ROOT = Path(__file__).resolve().parents[2]

#: a params file with a YAML syntax error (an unclosed flow sequence and mapping)
BAD_YAML = "controller:\n  ros__parameters:\n    k1: [1, 2\n    w: {\n"

MISTAKES: list[tuple[str, list[str], dict[str, str], str]] = [
    ("sim-negative-seed", ["sim", "--seed", "-1"], {}, "--seed"),
    ("sim-seed-not-int", ["sim", "--seed", "1.5"], {}, "--seed"),
    ("sim-duration-nan", ["sim", "--duration", "nan"], {}, "--duration"),
    ("sim-duration-inf", ["sim", "--duration", "inf"], {}, "--duration"),
    ("sim-duration-zero", ["sim", "--duration", "0"], {}, "--duration"),
    ("sim-json-missing-dir", ["sim", "--json", "/nonexistent/x.json"], {}, "/nonexistent"),
    ("sim-plot-under-a-file", ["sim", "--plot", "/etc/passwd/figs"], {}, "/etc/passwd"),
    ("sim-record-under-a-file", ["sim", "--record", "/etc/passwd/bag"], {}, "/etc/passwd"),
    ("sim-yaml-syntax-error", ["sim", "--params", "bad.yaml"], {}, "YAML"),
    ("sim-params-missing", ["sim", "--params", "missing.yaml"], {}, "missing.yaml"),
    ("sim-unknown-scenario", ["sim", "--scenario", "S99"], {}, "S99"),
    ("sim-unknown-controller", ["sim", "--controller", "lqr"], {}, "lqr"),
    ("sim-set-unknown-key", ["sim", "--set", "controller.nope=1"], {}, "nope"),
    ("sim-set-out-of-range", ["sim", "--set", "controller.w=-5"], {}, "controller.w"),
    ("sim-set-wrong-type", ["sim", "--set", "controller.k1=abc"], {}, "k1"),
    ("sim-negative-delay", ["sim", "--delay", "-1"], {}, "command_delay"),
    ("launch-bad-domain-env", ["launch", "--duration", "1"], {"ROS_DOMAIN_ID": "abc"}, "ROS_DOMAIN_ID"),
    ("launch-domain-out-of-range", ["launch", "--duration", "1", "--domain-id", "999"], {}, "--domain-id"),
    # above 101 (the range safe on every OS, contract.DOMAIN_ID_MAX): refused before any node starts
    ("launch-domain-above-101", ["launch", "--duration", "1", "--domain-id", "177"], {}, "[0, 101]"),
    ("launch-set-unknown-key", ["launch", "--duration", "1", "--set", "controller.nope=1"], {}, "nope"),
    ("launch-duration-nan", ["launch", "--duration", "nan"], {}, "--duration"),
    ("launch-bad-hardware-url", ["launch", "--duration", "1", "--hardware", "bogus://x"], {}, "--hardware"),
    ("launch-fault-without-rig", ["launch", "--duration", "1", "--fault", "linkloss@1+0.1"], {}, "--fault"),
    ("launch-apart-without-compose", ["launch", "--duration", "1", "--apart", "controller"], {}, "--compose"),
    ("launch-apart-unknown-node", ["launch", "--duration", "1", "--compose", "--apart", "plant_sim"], {}, "--apart"),
    ("launch-udp-without-port", ["launch", "--duration", "1", "--hardware", "udp://localhost"], {}, "udp://HOST:PORT"),
    ("launch-udp-unresolvable", ["launch", "--duration", "1", "--hardware", "udp://nohost.invalid:47000"], {},
     "resolve"),
    ("launch-serial-no-device", ["launch", "--duration", "1", "--hardware", "serial:///dev/ttyNOPE"], {}, "ttyNOPE"),
    ("launch-serial-not-a-device", ["launch", "--duration", "1", "--hardware", "serial:///etc/passwd"], {},
     "character device"),
    ("replay-plot-unwritable", ["replay", "notabag.txt", "--plot", "/proc/nope"], {}, "/proc/nope"),
    ("launch-yaml-syntax-error", ["launch", "--duration", "1", "--params", "bad.yaml"], {}, "YAML"),
    ("launch-rclpy-without-ros", ["launch", "--duration", "1", "--transport", "rclpy"], {}, "rclpy"),
    ("replay-missing-bag", ["replay", "no_such_bag"], {}, "no_such_bag"),
    ("bag-check-not-a-bag", ["bag", "check", "notabag.txt"], {}, "notabag.txt"),
    ("bag-info-not-a-bag", ["bag", "info", "notabag.txt"], {}, "notabag.txt"),
    ("param-set-malformed-value", ["param", "set", "controller", "w", "abc"], {}, "controller.w"),
    ("param-set-out-of-range", ["param", "set", "/controller", "w", "-1"], {}, "controller.w"),
    ("study-bad-scheduler", ["study", "--preset", "acceptance", "--scheduler", "bogus"], {}, "--scheduler"),
    ("hw-without-driver", ["hw", "status", "--timeout", "1"], {}, "hw_driver"),
    ("rig-bad-url", ["rig", "--url", "bogus://x"], {}, "bogus"),
    ("report-zero-jobs", ["report", "--jobs", "0"], {}, "--jobs"),
    ("bench-zero-batch", ["bench", "sim", "--batch", "0"], {}, "--batch"),
    ("node-bad-transport", ["node", "controller", "--transport", "zenoh"], {}, "--transport"),
    ("unknown-command", ["simulate"], {}, "simulate"),
]


#: the start-up progress line of tools/cli.main (tools/progress.Progress, work of unknown length)
PROGRESS = re.compile(r"^dem-ros( [a-z]+)?: starting: loading numpy and the dem_ros modules \.\.\. \(\d+ s\)$")


def _files(d: Path) -> set[str]:
    return {str(p.relative_to(d)) for p in d.rglob("*")}


def _env(extra: dict[str, str]) -> dict[str, str]:
    env = dict(os.environ)
    env.update(PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")  # the run's own ROS_DOMAIN_ID: nobody else's driver answers
    env.update(extra)
    return env


def test_the_table_has_the_twenty_mistakes_the_issue_asks_for():
    assert len(MISTAKES) >= 20
    assert len({m[0] for m in MISTAKES}) == len(MISTAKES)


@pytest.mark.parametrize(("argv", "env", "word"), [m[1:] for m in MISTAKES], ids=[m[0] for m in MISTAKES])
def test_mistake_is_one_line_exit_2_nothing_written(tmp_path, argv, env, word):
    if "rclpy" in argv and rclpy_available():
        pytest.skip("rclpy imports here: --transport rclpy is not a mistake on this machine")
    (tmp_path / "bad.yaml").write_text(BAD_YAML)
    (tmp_path / "notabag.txt").write_text("not a bag\n")
    before = _files(tmp_path)
    # generous: a cold interpreter importing numpy/numba on a loaded 2-core machine; the commands
    # themselves fail in their argument checks (the slowest row waits 1 s for a hardware driver)
    proc = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", *argv], cwd=tmp_path, env=_env(env),
                          capture_output=True, text=True, timeout=300)
    out = proc.stdout + proc.stderr
    lines = [ln for ln in out.splitlines() if ln.strip() and not PROGRESS.match(ln)]
    assert proc.returncode == 2, out
    assert "Traceback" not in out, out
    assert len(lines) == 1, out
    assert "error" in lines[0] and word.lower() in lines[0].lower(), lines[0]
    assert _files(tmp_path) == before, "the mistake wrote files"
