"""Fixtures for the transport tests: child processes (the ``domain_id`` fixture is in tests/conftest.py)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PEER = Path(__file__).with_name("peer.py")
def child_env(domain_id, **extra) -> dict:
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""),
        PYTHONUNBUFFERED="1",
    )
    env.update({k: str(v) for k, v in extra.items()})
    return env


@pytest.fixture
def spawn():
    """spawn(domain_id, role, *args, **env) -> Popen running tests/transport/peer.py; killed at teardown."""
    procs = []

    def _spawn(domain_id, role, *args, **env):
        p = subprocess.Popen(
            [sys.executable, str(PEER), role, *map(str, args)],
            env=child_env(domain_id, **env), cwd=str(ROOT),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        procs.append(p)
        return p

    yield _spawn
    for p in procs:
        if p.poll() is None:
            p.kill()
        p.wait(timeout=5)
        for f in (p.stdout, p.stderr):
            if f:
                f.close()


def _wait_line(proc, prefix: str, timeout: float = 15.0) -> str:
    """Read the child's stdout until a line starting with ``prefix`` (fails on exit or timeout)."""
    import selectors
    import time

    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sel.select(timeout=0.1):
            line = proc.stdout.readline()
            if not line:
                break
            if line.startswith(prefix):
                return line[len(prefix):].strip()
    err = proc.stderr.read() if proc.poll() is not None else ""
    raise AssertionError(f"child never printed {prefix!r} (rc={proc.poll()}): {err[-2000:]}")


@pytest.fixture
def wait_line():
    """wait_line(proc, prefix, timeout=15) -> rest of the first stdout line starting with prefix."""
    return _wait_line
