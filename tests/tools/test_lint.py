"""The linters run as tests (as ros2's ament_flake8 / ament_mypy do): ruff and mypy, as pyproject.toml configures them.

The configuration is the contract: ``ruff check`` over the repository with the
rule set explained in pyproject.toml, and ``mypy`` over the package (strict for
core/, bag/, transport/; bodies checked everywhere). A finding fails the test
with the linter's own report.
"""

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
def test_mypy_finds_nothing(tmp_path):
    # a private cache: parallel runs (and other worktrees) must not share a half-written one
    r = _run("mypy", "--cache-dir", str(tmp_path / "mypy_cache"), timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
