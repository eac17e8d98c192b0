"""The estimator node's plausibility, convergence and diagnostics (real node code, in-memory transport)."""

from __future__ import annotations

import numpy as np
import pytest
from loop_writers import publish

from dem_ros import contract
from dem_ros.core.model import hover_state
from dem_ros.core.params import default_config
from dem_ros.nodes.common import ERROR, OK, WARN, joint_state, stamp_ns
from dem_ros.nodes.estimator import EstimatorNode
from dem_ros.transport.memory import MemoryBus

T = 1_000_000  # ns
EC = default_config()["estimator"]
X0, U0 = hover_state(default_config()["plant_sim"], 0.008)


def _level(st) -> int:
    return st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")


def _graph(*ros_args: str):
    bus = MemoryBus()
    node = EstimatorNode(bus.node("estimator", ["--ros-args", *ros_args]))
    est: dict[int, list[float]] = {}
    diags: list = []
    probe = bus.node("probe")
    probe.subscribe(contract.ESTIMATE, lambda m: est.__setitem__(stamp_ns(m), list(m.position)))
    probe.subscribe(contract.DIAGNOSTICS, lambda m: diags.extend(
        (_level(s), s.message, {kv.key: kv.value for kv in s.values})
        for s in m.status if s.name == contract.ESTIMATOR_STATUS))
    return bus, node, est, diags


def _feed(bus, k: int, gaps=(X0[0], X0[2]), frame=contract.FRAME, position=None, rates=(0.0, 0.0)) -> int:
    JS = bus.msg("sensor_msgs/msg/JointState")
    t = bus.now_ns + k * T
    publish(bus, contract.APPLIED, joint_state(JS, t, effort=U0))
    pos = position if position is not None else gaps
    publish(bus, contract.MEASUREMENT, joint_state(JS, t, position=pos, velocity=rates, effort=(X0[4], X0[5]),
                                                  frame=frame))
    bus.spin_once()
    return t


def test_a_restart_without_measured_rates_publishes_only_once_converged():
    bus, node, est, _ = _graph()
    n = EC["converge_samples"]
    stamps = [_feed(bus, k, rates=()) for k in range(n + 10)]
    # the n-th sample in a row that passed the gates is the first out
    assert sorted(est) == stamps[n - 1:], (len(est), n)
    assert node.counts["withheld"] == n - 1
    assert any("converged after" in line[2] for line in bus.log)


def test_a_restart_mid_run_with_measured_rates_publishes_once_the_next_sample_confirms_the_start():
    """Every published state measured: the start is the measurement (core/estimator.py), once the next sample
    confirms it (the start passed only the range gate); then the start's estimate goes out too, first (a
    lockstep plant waits for every sample's command); the gates still test every later one."""
    bus, node, est, _ = _graph()
    t0 = _feed(bus, 0)
    assert est == {} and node.counts["withheld"] == 1  # not before the next sample confirms it
    stamps = [t0] + [_feed(bus, k) for k in range(1, 5)]
    assert list(est) == stamps and node.counts["withheld"] == 0  # in stamp order, the start first
    t_spike = _feed(bus, 5, gaps=(X0[0] + 0.005, X0[2]))  # a 5 mm spike right after the start: held, not taken
    assert abs(est[t_spike][0] - X0[0]) < 1e-6


def test_an_in_range_spike_as_the_first_sample_of_a_restart_is_never_published():
    """Review defect: a restart with measured rates published its first sample after the range gate only: a
    2 mm spike as that sample went out as the estimate, and the innovation gate then rejected the true samples
    after it. Now the start is confirmed by the next sample first, and one it does not confirm is replaced:
    the spike is never published, the filter starts again from the next sample (published once the one after
    confirms it), on the true gaps, and so is every estimate after it."""
    bus, node, est, diags = _graph()
    stamps = [_feed(bus, 0, gaps=(X0[0] + 0.002, X0[2]))]  # in range (0..20 mm), 2 mm off
    stamps += [_feed(bus, k) for k in range(1, 50)]
    assert list(est) == stamps[1:] and node.counts["withheld"] == 1
    assert all(abs(p[0] - X0[0]) < 1e-6 and abs(p[1] - X0[2]) < 1e-6 for p in est.values()), est[stamps[1]]
    bus.advance(1.0)
    level, _message, values = diags[-1]
    assert level != ERROR and values["unconfirmed_starts"] == "1" and values["faults"] == "", diags[-1]


def test_convergence_fits_inside_the_boards_hold():
    """Without measured rates a restarted filter withholds converge_samples samples: shorter than the
    board's hold_timeout, so the convergence itself never costs a landing (a process restart still may)."""
    cfg = default_config()
    assert EC["converge_samples"] * EC["dt"] < cfg["plant_sim"]["hold_timeout"]


def test_a_start_in_the_preroll_publishes_once_confirmed():
    """Without measured rates too: in the pre-roll the plate hovers in equilibrium, where the filter starts, so
    the estimates go out as soon as the next sample confirms the start (not after converge_samples), the
    start's first: the plant's first sample gets its command (a lockstep plant waits for it)."""
    bus, node, est, _ = _graph()
    t0 = _feed(bus, 0, frame=contract.FRAME_PREROLL, rates=())
    assert est == {}
    stamps = [t0] + [_feed(bus, k, frame=contract.FRAME_PREROLL, rates=()) for k in range(1, 3)]
    assert list(est) == stamps and node.counts["withheld"] == 0


def test_spikes_are_held_counted_and_warned_and_a_dead_sensor_is_an_error():
    bus, _node, est, diags = _graph()
    k = 0
    for _ in range(200):
        _feed(bus, k)
        k += 1
    bus.advance(1.0)
    assert diags[-1][0] == OK, diags[-1]
    t_spike = _feed(bus, k, gaps=(X0[0] + 0.010, X0[2]))  # a 10 mm spike on gap 1
    k += 1
    t_far = _feed(bus, k, gaps=(X0[0], 0.050))  # a 50 mm reading of gap 2
    k += 1
    assert abs(est[t_spike][0] - X0[0]) < 1e-6 and abs(est[t_far][1] - X0[2]) < 1e-6  # the prediction held
    bus.advance(1.0)
    level, message, values = diags[-1]
    assert level == WARN and "gap1_innovation +1" in message and "gap2_out_of_range +1" in message, diags[-1]
    assert values["gap1_innovation"] == "1" and values["gap2_out_of_range"] == "1"
    for _ in range(EC["fault_samples"]):
        _feed(bus, k, gaps=(X0[0], 0.0))  # gap sensor 2 dead
        k += 1
    bus.spin_once()
    level, message, values = diags[-1]
    assert level == ERROR and message.startswith("gap sensor 2:"), diags[-1]  # published at once
    assert sum("fault: gap sensor 2" in line[2] for line in bus.log) == 1
    _feed(bus, k)  # estimates go on (from the other sensor, the currents and the model)
    assert len(est) == 200 + 2 + EC["fault_samples"] + 1  # rates measured: every sample (the start once confirmed)


def test_malformed_measurements_are_dropped_and_settings_retune_without_a_restart():
    bus, node, est, _diags = _graph()
    for k in range(150):
        _feed(bus, k)
    _feed(bus, 150, position=[0.008])  # one gap: rejected by the input's binding, counted
    assert node.inputs.values()["measurement_malformed"] == 1 and node.node.callback_errors == {}
    assert node.node.set_parameters({"sigma_gap": 2e-5}) is None
    n = len(est)
    _feed(bus, 151)
    assert len(est) == n + 1 and node.counts["restarts"] == 1  # still publishing: no re-convergence
    assert "cannot change" in (node.node.set_parameters({"type": "none"}) or "")
    bus.advance(1.0)
    assert node.inputs.diag.reports and any("malformed" in line[2] for line in bus.log)
    assert np.isclose(node.est.rm[0], 4e-10)


def test_a_measurement_stamped_far_ahead_holds_nothing_back():
    """A foreign measurement stamped +1 h (a corrupt stamp) waits for a voltage that never comes: the
    measurements after it, whose voltages come, go on at once (held behind it, the controller would get no
    estimate: measured, a lockstep landing in the faults row stale-stamps)."""
    bus, node, est, _ = _graph()
    for k in range(5):
        _feed(bus, k)
    JS = bus.msg("sensor_msgs/msg/JointState")
    far = bus.now_ns + 3_600_000 * T
    publish(bus, contract.MEASUREMENT, joint_state(JS, far, position=(X0[0], X0[2]), velocity=(0.0, 0.0),
                                                  effort=(X0[4], X0[5])))
    bus.spin_once()
    stamps = [_feed(bus, k) for k in range(5, 10)]
    assert all(t in est for t in stamps) and far not in est
    # measurement before voltage (either order is allowed): still its own voltage, one sample late at most
    t = bus.now_ns + 10 * T
    publish(bus, contract.MEASUREMENT, joint_state(JS, t, position=(X0[0], X0[2]), velocity=(0.0, 0.0),
                                                  effort=(X0[4], X0[5])))
    bus.spin_once()
    publish(bus, contract.APPLIED, joint_state(JS, t, effort=U0))
    bus.spin_once()
    assert t in est and node.counts["unpaired"] == 0


@pytest.mark.parametrize("preroll", [0.05, 0.0])
def test_a_lockstep_plant_runs_from_its_first_sample_through_the_estimator(preroll):
    """The confirmed start's own estimate goes out (on the confirming sample): a lockstep plant waits for the
    command of every sample, and a withheld first estimate stalled the whole graph until lockstep_timeout,
    then landed the plate at t = 0 (what the graph test's run did when the start was only withheld). The real
    plant, estimator, reference and controller nodes on one memory bus, the plant paced by the wall clock."""
    import time

    from dem_ros.nodes.controller import ControllerNode
    from dem_ros.nodes.plant_sim import PlantSimNode
    from dem_ros.nodes.reference import ReferenceNode

    bus = MemoryBus()
    args = ["--ros-args", "-p", "start_delay:=0.0", "-p", "min_subscribers:=0", "-p", f"preroll:={preroll}",
            "-p", "lockstep:=true", "-p", "lockstep_timeout:=0.5", "-p", "duration:=0.2"]
    plant = PlantSimNode(bus.node("plant_sim", args))
    node = EstimatorNode(bus.node("estimator", []))
    ReferenceNode(bus.node("reference", []))
    ControllerNode(bus.node("controller", []))
    end = time.monotonic() + 30.0
    while not plant.finished and time.monotonic() < end:
        bus.advance(0.001)
    assert plant.finished and plant.lockstep_landing == 0, plant.board.reason if hasattr(plant.board, "reason") else ""
    assert plant.k_next > 200  # every sample of the 0.2 s run
    assert node.counts["withheld"] == 0 and node.counts["published"] == node.counts["measurements"]


def test_a_voltage_or_measurement_with_a_stamp_already_taken_is_dropped():
    """The plant sends each stamp once: a second /dem/applied_voltage or /dem/measurement with a stamp already
    taken is someone else's (`dem-ros faults` bad-cdr publishes the measurement, currents ~4 A, as a voltage of
    the same stamp: taken, it put the filter off and the plate on its support). The first stays; the repeat is
    counted ('repeated', WARN) and the estimates are those of the clean run."""
    runs = []
    for inject in (False, True):
        bus, node, est, diags = _graph()
        JS = bus.msg("sensor_msgs/msg/JointState")
        for k in range(80):
            t = _feed(bus, k)
            if inject and k == 40:
                publish(bus, contract.APPLIED, joint_state(JS, t, effort=(X0[4], X0[5])))  # 4 "volts"
                publish(bus, contract.MEASUREMENT,
                        joint_state(JS, t, position=(X0[0] + 1e-3, X0[2]), velocity=(0.0, 0.0),
                                                              effort=(X0[4], X0[5])))
                bus.spin_once()
        runs.append((dict(est), node.counts["repeated"], node.counts["measurements"]))
        if inject:
            bus.advance(1.0)
            assert diags and diags[-1][0] == WARN
    (clean, n0, m0), (hit, n1, m1) = runs
    assert n0 == 0 and n1 == 2 and m1 == m0 == 80
    assert hit == clean


def test_measurements_before_the_first_voltage_wait_for_it_instead_of_stepping_on_zero_volts():
    """One process per node binds the two topics in the order their first samples come: the measurement's writer
    may be bound ms before the voltage's. Stepped on 0 V, a hovering plate's currents were predicted to collapse:
    20 innovation rejections on both gaps, a latched sensor fault, and the law started from a model-only estimate
    4 mm off (the rig board landed the plate at t = 0). They wait instead; the oldest beyond PENDING_MAX go."""
    from dem_ros.nodes.estimator import PENDING_MAX

    bus, node, est, diags = _graph()
    JS = bus.msg("sensor_msgs/msg/JointState")
    t0 = bus.now_ns
    n_early = 40  # a voltage writer bound 40 ms after the measurement's
    for k in range(n_early):
        publish(bus, contract.MEASUREMENT, joint_state(JS, t0 + k * T, position=(X0[0], X0[2]), velocity=(),
                                                      effort=(X0[4], X0[5]), frame=contract.FRAME_PREROLL))
        bus.spin_once()
    assert est == {} and len(node.pending) == PENDING_MAX  # nothing stepped, at most PENDING_MAX waiting
    for k in range(n_early, n_early + 200):
        _feed(bus, k - (bus.now_ns - t0) // T, rates=(), frame=contract.FRAME_PREROLL)
    kf = node.est
    assert kf is not None and not kf.faulty, kf.faults
    c = kf.counters()
    assert c["gap1_innovation"] == c["gap2_innovation"] == 0, c
    last = est[max(est)]
    np.testing.assert_allclose(last, [X0[0], X0[2]], atol=2e-6)
    assert all(level != ERROR for level, *_ in diags)
