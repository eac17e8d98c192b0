"""``dem-ros sim`` bit for bit: hashes of the trajectories of every scenario x every control law.

A refactoring must not change what the offline simulator computes. Each run of the grid (the scenarios of
config/scenarios.yaml x the laws of ``controller.type``, the default estimator, ``SIM_DURATION`` s) is
reduced to a SHA-256 of its true states, applied voltages, diagnostics and failure time; the table below
holds the expected digests. A change that is meant to change results updates the table in the same commit
and says in its message which rows changed and why; print the current table with

    .venv/bin/python tests/core/test_sim_hashes.py

The digests are of IEEE doubles as this platform's numba/LLVM computes them (x86-64; the kernels are
compiled without fastmath, so the same sources give the same bits on the same toolchain).
"""

from __future__ import annotations

import hashlib
import sys

import numpy as np
import pytest

from dem_ros.core.numba_cache import configure

configure()  # before any kernel is compiled: the cache of this version of the core's sources

from dem_ros.core.params import SCHEMA  # noqa: E402
from dem_ros.core.scenarios import load_scenarios  # noqa: E402
from dem_ros.core.simulate import SimResult, simulate  # noqa: E402

#: seconds per run: both steps (1 s, 10 s), the load and heating ramps under way (S2, S5, S6 from 20 s)
SIM_DURATION = 25.0
LAWS = tuple(SCHEMA.spec("controller", "type").choices or ())
SCENARIOS = ("S1", "S2", "S3a", "S3b", "S3c", "S4a", "S4b", "S4c", "S5", "S6")

EXPECTED: dict[str, str] = {
    "S1/adaptive": "3f4ed0db536e5752",
    "S1/adaptive_enhanced": "4c4634cbf12d87e4",
    "S1/paper": "fd58a135a7dbff87",
    "S1/paper_fixed": "571a097f5e9a4eeb",
    "S1/nonlinear_decoupling": "a5bbea49ca81d0d3",
    "S1/decentralized_pid": "303c17eafe327fc7",
    "S2/adaptive": "60a40d3619b69c66",
    "S2/adaptive_enhanced": "43dfd54869c47a9f",
    "S2/paper": "fd58a135a7dbff87",
    "S2/paper_fixed": "b2b170c6e0a3c7a8",
    "S2/nonlinear_decoupling": "12be2231f7544ae0",
    "S2/decentralized_pid": "6931dc94c442b575",
    "S3a/adaptive": "2e3ff749a1eeb705",
    "S3a/adaptive_enhanced": "9b1b172b3abbd883",
    "S3a/paper": "6982698c203d2c7f",
    "S3a/paper_fixed": "cd20537d446fb7ce",
    "S3a/nonlinear_decoupling": "b52630ce1b224212",
    "S3a/decentralized_pid": "be703a5f95ee91f8",
    "S3b/adaptive": "e72fbab3542c98a4",
    "S3b/adaptive_enhanced": "7ef0495776f0f3ea",
    "S3b/paper": "182d839594d34b39",
    "S3b/paper_fixed": "7bbeab707c80d485",
    "S3b/nonlinear_decoupling": "e6bebb94a8afa614",
    "S3b/decentralized_pid": "3cf6367023efdf19",
    "S3c/adaptive": "c01e0d93eb200cc2",
    "S3c/adaptive_enhanced": "d2cc5828927fa878",
    "S3c/paper": "3c2bb85942e20dfd",
    "S3c/paper_fixed": "d7f4e7dd68e344c7",
    "S3c/nonlinear_decoupling": "99b32f5682280a45",
    "S3c/decentralized_pid": "52262f7a8e5899bb",
    "S4a/adaptive": "1bdb39f927d3e755",
    "S4a/adaptive_enhanced": "e0b3a8d67e728660",
    "S4a/paper": "9cf12954ab44b08b",
    "S4a/paper_fixed": "2e23989cf88f52ce",
    "S4a/nonlinear_decoupling": "e9e1143c29edd847",
    "S4a/decentralized_pid": "c5d59e4e55577971",
    "S4b/adaptive": "eb3dedb01ec33ac1",
    "S4b/adaptive_enhanced": "341ee6c60b599aa0",
    "S4b/paper": "af970a7f3191205c",
    "S4b/paper_fixed": "e2c03cbacd40d894",
    "S4b/nonlinear_decoupling": "28fbbaf7bc0db9fd",
    "S4b/decentralized_pid": "f4302c9b084698bb",
    "S4c/adaptive": "183dc5fe0a1ba666",
    "S4c/adaptive_enhanced": "70e228df580ca620",
    "S4c/paper": "a4ac5e3376ac8e0e",
    "S4c/paper_fixed": "517a8c767922a87d",
    "S4c/nonlinear_decoupling": "aaae7514f0ff1d80",
    "S4c/decentralized_pid": "62ca07b3b7962ee2",
    "S5/adaptive": "0aeb19abafba9a36",
    "S5/adaptive_enhanced": "80a475bafc6da5b9",
    "S5/paper": "d0338b9924733993",
    "S5/paper_fixed": "faf3cf3ffdbf867a",
    "S5/nonlinear_decoupling": "e762d3ab1a28151d",
    "S5/decentralized_pid": "aff4786e39dc379d",
    "S6/adaptive": "708fdb1bf2aa7676",
    "S6/adaptive_enhanced": "6f51c58ddced4b92",
    "S6/paper": "fd58a135a7dbff87",
    "S6/paper_fixed": "743707d5dc3964a0",
    "S6/nonlinear_decoupling": "55d2b94f9477fe03",
    "S6/decentralized_pid": "25285cbc1c4cddfa",
}


def digest(r: SimResult) -> str:
    """SHA-256 (first 16 hex digits) of a run's x, u, diag, failure flag and time."""
    h = hashlib.sha256()
    for a in (r.x, r.u, r.diag):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(repr((r.failed, r.fail_time, len(r.t))).encode())
    return h.hexdigest()[:16]


def run(scenario: str, law: str) -> str:
    sc = load_scenarios()[scenario]
    return digest(simulate(sc.config(), controller=law, duration=SIM_DURATION, scenario=scenario))


def test_the_grid_is_complete():
    assert set(load_scenarios()) == set(SCENARIOS)
    assert set(EXPECTED) == {f"{s}/{law}" for s in SCENARIOS for law in LAWS}


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_sim_trajectory_is_bit_for_bit(scenario, law):
    assert run(scenario, law) == EXPECTED[f"{scenario}/{law}"]


if __name__ == "__main__":
    for s in SCENARIOS:
        for law in LAWS:
            print(f'    "{s}/{law}": "{run(s, law)}",', flush=True)
    sys.exit(0)
