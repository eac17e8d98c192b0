"""The CE step called from Python (#9): :class:`CEController` keeps its arrays in two buffers and calls
``kernels.ce_step_buffers`` with them; the result must be the compiled ``ce_step`` on the records, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from dem_ros.core.controllers import kernels as K
from dem_ros.core.controllers import make_controller
from dem_ros.core.model import hover_state
from dem_ros.core.scenarios import get_scenario
from dem_ros.core.simulate import _ce_shapes, prepare, simulate

OFF = {"ki": 0.0, "coil_weight": 0.0, "q_R": 0.0, "q_rho": 0.0}


def test_buffer_layouts_hold_the_records_fields():
    st, u, diag = K.state_views(np.arange(K.NSB, dtype=float))
    assert [a.shape for a in st] == [a.shape for a in _ce_shapes()]
    assert u.shape == (2,) and diag.shape == (K.NDIAG,)
    parts = [*st, u, diag]
    assert all(a.flags.c_contiguous and a.flags.writeable for a in parts)
    # the views tile the buffer: every entry once, in order
    np.testing.assert_array_equal(np.concatenate([a.ravel() for a in parts]), np.arange(K.NSB))
    cp, Ad, Bd = K.law_views(np.arange(K.NLB, dtype=float))
    assert cp.shape == (K.NCP,) and Ad.shape == (3, 3) and Bd.shape == (3,)
    np.testing.assert_array_equal(np.concatenate([cp, Ad.ravel(), Bd]), np.arange(K.NLB))


@pytest.mark.parametrize("terms", ["on", "off"])
@pytest.mark.parametrize("name", ["adaptive", "adaptive_enhanced", "paper_fixed", "nonlinear_decoupling", "paper"])
def test_step_from_python_is_the_compiled_step_bit_for_bit(name, terms):
    """300 samples of an S1 trajectory: ``step`` (two buffers) against ``ce_step_arrays`` (the records' fields as
    sixteen separate arrays) on a twin controller: the same commands, diagnostics and states, bit for bit."""
    cfg = {g: dict(v) for g, v in get_scenario("S1").config().items()}
    if terms == "off":
        cfg["controller"].update(OFF)
    xs = simulate(cfg, controller="adaptive", estimator="none", duration=0.3).x
    ref = prepare(cfg, 0.3)[2]
    pc = cfg["plant_sim"]
    x0, u0 = hover_state(pc, pc["gap0"])
    a = make_controller(cfg["controller"], name)
    b = make_controller(cfg["controller"], name)
    a.reset(x0.copy(), u0)
    b.reset(x0.copy(), u0)
    assert all(np.shares_memory(f, a._sb) for f in (*a.state, a.u, a.diag))
    for k in range(len(xs)):
        meas = xs[k] if k != 150 else np.r_[np.nan, xs[k][1:]]  # and one non-finite sample (fault, state untouched)
        ua = a.step(meas, ref[k]).copy()
        K.ce_step_arrays(*b.law, *b.state, meas, ref[k], b.u, b.diag)
        assert np.array_equal(ua, b.u, equal_nan=True) and np.array_equal(a.diag, b.diag, equal_nan=True), k
    assert np.array_equal(a._sb, b._sb, equal_nan=True)
