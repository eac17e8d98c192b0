"""Suite-wide DDS isolation (see domains.py): the run never joins the user's ROS graph or another run's.

At start the run leases one domain id for itself and puts it in ``ROS_DOMAIN_ID``, with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and without the shell's DDS configuration
(``domains.FOREIGN_DDS_ENV``): every process a test starts without choosing a domain - a CLI
call, a launch - talks on that private domain, on loopback. A test that needs a domain of its
own takes the ``domain_id`` fixture (or ``module_domain_id``).

numba: the run sets ``NUMBA_CACHE_DIR`` (``dem_ros.core.numba_cache``: the cache of this version of the
core's sources) for every process a test starts, and when the suite has not yet filled that cache for this
checkout (the first run after an edit of ``dem_ros/core``, or the first run of another checkout of the same
version: the directory is keyed by the sources' contents, but numba keeps kernels per source *path*, see
``dem_ros.tools.common.warm_kernels``) compiles the kernels into it once, here, with progress: otherwise
every node process of the first graph test compiles the same kernels at once, and on a loaded 2-core
machine they were not ready within the launcher's 120 s. The marker that says so is keyed the same way
(:func:`warm_marker`). Only tests/tools/test_first_use.py uses an empty cache of its own (it proves first use).
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import domains
import pytest

_session: domains.DomainLease | None = None


def pytest_configure(config: pytest.Config) -> None:
    global _session
    _session = domains.lease()
    for name in domains.FOREIGN_DDS_ENV:
        os.environ.pop(name, None)
    os.environ["ROS_DOMAIN_ID"] = str(_session.id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    _fill_numba_cache()


def warm_marker(cache: str) -> Path:
    """The file in numba cache directory ``cache`` that says the suite compiled every kernel of *this checkout*
    into it: keyed as numba keys the kernels, by the absolute path of the sources' directory
    (``<cache>/core_<sha1 of that path>``, what ``dem_ros.tools.common.warm_kernels`` looks at; abspath, not
    resolve, as numba does), not only by the sources' contents (the cache directory's key)."""
    import dem_ros.core

    core = os.path.abspath(os.path.dirname(dem_ros.core.__file__))
    return Path(cache) / f"warmed-by-tests-core_{hashlib.sha1(core.encode()).hexdigest()}"


def _fill_numba_cache() -> None:
    """Point this run and its child processes at the shared numba cache; compile into it once if this
    checkout's kernels are not all in it."""
    from dem_ros.core.numba_cache import configure

    done = warm_marker(configure())  # every kernel is in (not only those a killed process wrote)
    if done.exists():
        return  # each process loads what it needs
    from dem_ros.tools.common import warm_kernels

    warm_kernels("tests", stream=sys.stderr)  # compiles what is missing, loads the rest (seconds)
    done.touch()


def pytest_unconfigure(config: pytest.Config) -> None:
    if _session is not None:
        _session.release()


@pytest.fixture
def domain_id(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """A DDS domain of this test's own, set as ``ROS_DOMAIN_ID`` (loopback, Jazzy conventions) for its life."""
    with domains.lease() as d:
        monkeypatch.setenv("ROS_DOMAIN_ID", str(d))
        monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        monkeypatch.delenv("DEM_ROS_DISTRO", raising=False)
        yield d


@pytest.fixture(scope="module")
def module_domain_id() -> Iterator[int]:
    """A DDS domain held for the test module's life (for module-scoped runs; the environment is not changed)."""
    with domains.lease() as d:
        yield d
