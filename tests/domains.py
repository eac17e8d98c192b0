"""DDS domain ids for tests, leased so that no two runs of the suite on one machine share one.

A test that starts DDS participants (in this process or in children) needs a domain nobody else
uses: not the user's own ROS graph, not another test of this run, not a test of another run of the
suite (a second checkout, a CI job, a helper's worktree). Each id has a lock file under
``$TMPDIR/dem_ros-test-domains/``; a lease holds an exclusive ``flock`` on it. The kernel drops
the lock when the holder's process ends, however it ends, so a killed run leaves no stale lease.

Within one process, leases go round the ids (the next lease starts after the last id leased), so a
test never gets the id the test before it used: late discovery traffic of that test's children, or
of this process's own participants, cannot reach the next test.

Ids are 1..101: 0 is every ROS install's default domain, and above 101 Cyclone's ports may
collide with Linux's ephemeral port range (the range ROS documents as safe on every OS).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from pathlib import Path

__all__ = ["DOMAIN_IDS", "FOREIGN_DDS_ENV", "LOCK_DIR", "DomainLease", "hold", "lease"]

DOMAIN_IDS = range(1, 102)
LOCK_DIR = Path(tempfile.gettempdir()) / "dem_ros-test-domains"
#: variables of the user's shell that would take a test's participants off its private domain on
#: loopback (a config file, static peers, a discovery server, Humble's localhost switch)
FOREIGN_DDS_ENV = ("CYCLONEDDS_URI", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY", "ROS_DISCOVERY_SERVER")

#: the domain of the shell that started the run: never leased
_USER_DOMAIN = os.environ.get("ROS_DOMAIN_ID", "0").strip()
_next = 0  # index into DOMAIN_IDS where the next search starts
_held: list[DomainLease] = []


class DomainLease:
    """An exclusive claim on DDS domain ``id`` until :meth:`release` (or this process's end)."""

    def __init__(self, domain_id: int, fd: int) -> None:
        self.id = domain_id
        self._fd: int | None = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    def __enter__(self) -> int:
        return self.id

    def __exit__(self, *exc: object) -> None:
        self.release()


def _lock_dir() -> Path:
    LOCK_DIR.mkdir(exist_ok=True)
    # shared by every user of the machine (their runs must see each other's leases); if another
    # user made it, they set the mode
    with contextlib.suppress(PermissionError):
        LOCK_DIR.chmod(0o1777)
    return LOCK_DIR


def lease() -> DomainLease:
    """A domain id no other process holds; RuntimeError if all 101 are held."""
    global _next
    d = _lock_dir()
    n = len(DOMAIN_IDS)
    for k in range(n):
        i = (_next + k) % n
        domain_id = DOMAIN_IDS[i]
        if str(domain_id) == _USER_DOMAIN:
            continue
        path = d / f"{domain_id}.lock"
        fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o666)  # flock needs no write access
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        _next = i + 1
        return DomainLease(domain_id, fd)
    raise RuntimeError(f"all DDS domain ids {DOMAIN_IDS.start}..{DOMAIN_IDS.stop - 1} are held by other test "
                       f"runs on this machine (lock files in {d}); wait for them or end them")


def hold() -> int:
    """A domain id leased for the rest of this process (for helpers outside a fixture's life)."""
    lease_ = lease()
    _held.append(lease_)
    return lease_.id
