"""The linters run as tests (as ros2's ament_flake8 / ament_mypy do): ruff and mypy, as pyproject.toml configures them.

The configuration is the contract: ``ruff check`` over the repository with the
rule set explained in pyproject.toml, and ``mypy`` over the package (strict for
core/, bag/, transport/; bodies checked everywhere). A finding fails the test
with the linter's own report.
"""

import fcntl
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason="ruff is not installed (pip install ruff)")
def test_ruff_finds_nothing():
    r = _run("ruff", "check", "--no-cache", ".", timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.skipif(importlib.util.find_spec("mypy") is None, reason="mypy is not installed (pip install mypy)")
def test_mypy_finds_nothing():
    # mypy's incremental cache (it re-checks what changed and re-reports the errors of what did not), this
    # checkout's own: a clone's first run fills it (20+ s on a loaded 2-core machine), later runs take about a
    # second. Runs of the suite in this checkout take turns on it (flock); other worktrees have their own.
    cache = ROOT / ".mypy_cache"
    cache.mkdir(exist_ok=True)
    with (cache / "dem_ros-tests.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        r = _run("mypy", "--cache-dir", str(cache), timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
