"""Shared, seeded closed-loop runs for the core tests (computed once per session)."""

from __future__ import annotations

import pytest

from dem_ros.core.numba_cache import configure

configure()  # before any kernel is compiled: the cache of this version of the core's sources

from dem_ros.core.scenarios import load_scenarios  # noqa: E402
from dem_ros.core.simulate import simulate  # noqa: E402


@pytest.fixture(scope="session")
def scenarios():
    return load_scenarios()


@pytest.fixture(scope="session")
def s1_adaptive_15s(scenarios):
    """S1, ``adaptive`` (A2), raw noiseless measurements, docs/manual/controllers.md timing (delay 0), first 15 s."""
    return simulate(scenarios["S1"].config(), controller="adaptive", estimator="none", duration=15.0, delay=0,
                    scenario="S1")


@pytest.fixture(scope="session")
def s2_adaptive(scenarios):
    """S2, ``adaptive``, raw noiseless measurements, docs/manual/controllers.md timing (delay 0), the full 100 s."""
    return simulate(scenarios["S2"].config(), controller="adaptive", estimator="none", duration=100.0, delay=0,
                    scenario="S2")
