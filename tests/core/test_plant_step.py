"""DemPlant's one compiled call per sample equals the composition it replaces, faults included."""

import numpy as np
import pytest

from dem_ros.core.model import IP, IQ, apply_schedule, rk4
from dem_ros.core.params import default_config
from dem_ros.core.plant import DemPlant

PC = default_config()["plant_sim"]


def test_advance_is_schedule_then_rk4_under_u_plus_perturbation_bit_for_bit():
    pc = {**PC, "perturbation": "uniform", "perturbation_amplitude": 2.0}
    plant = DemPlant(pc, 0.1)  # open loop: unstable poles near +50 rad/s, so 0.1 s stays near hover
    x = plant.x.copy()
    p = plant.p.copy()
    rng = np.random.default_rng(7)
    for k in range(100):
        u = plant.u0 + rng.uniform(-3.0, 3.0, 2)
        apply_schedule(p, plant._dist.schedule[k], pc["L"], pc["l"])
        rk4(x, u + plant._dist.pert[k], p, pc["dt"], pc["substeps"])
        plant.advance(u)
        np.testing.assert_array_equal(plant.x, x)
    assert plant.fault is None and plant.k == 100 and np.all(np.isfinite(x))


@pytest.mark.parametrize("u, says", [
    (lambda u0: u0 * 1.6, "rail contact"),           # too much current: the plate is pulled to the rail
    (lambda u0: np.zeros(2), "plate dropped"),        # no current: it falls off
    (lambda u0: np.array([np.nan, 0.0]), "state is not finite"),
])
def test_faults_are_detected_and_named(u, says):
    plant = DemPlant(PC, 2.0)
    for _ in range(2000):
        plant.advance(u(plant.u0))
        if plant.fault:
            break
    assert plant.fault is not None and plant.fault.startswith(says), plant.fault
    x, p = plant.x, plant.p
    if says == "rail contact":
        d1, d2 = p[IP] * x[0] + p[IQ] * x[2], p[IQ] * x[0] + p[IP] * x[2]
        assert min(x[0], x[2], d1, d2) <= PC["gap_min"]
    elif says == "plate dropped":
        assert max(x[0], x[2]) > PC["gap_max"]
