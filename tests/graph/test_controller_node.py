"""The controller node's guards on its input (real node code, in-memory transport, manual clock)."""

import math

from loop_writers import publish

from dem_ros import contract
from dem_ros.nodes.common import joint_state, named_vector, stamp_ns
from dem_ros.nodes.controller import ControllerNode
from dem_ros.transport.memory import MemoryBus

T = 1_000_000  # ns
REF = [0.008, 0.008, 0, 0, 0, 0, 0, 0, 0.008, 0.008]


def _graph(*ros_args: str):
    bus = MemoryBus()
    ctl = ControllerNode(bus.node("controller", ["--ros-args", *ros_args]))
    cmds: dict[int, list[float]] = {}
    states: dict[int, dict[str, float]] = {}
    diags = []
    probe = bus.node("probe")
    probe.subscribe(contract.COMMAND, lambda m: cmds.__setitem__(stamp_ns(m), list(m.effort)))
    probe.subscribe(contract.CONTROLLER_STATE,
                    lambda m: states.__setitem__(stamp_ns(m), dict(zip(m.name, m.position, strict=True))))
    probe.subscribe(contract.DIAGNOSTICS,
                    lambda m: diags.append(m) if m.status[0].name == contract.CONTROLLER_STATUS else None)
    return bus, ctl, cmds, states, diags


def _feed(bus, k: int, t: int, gap: float) -> None:
    JS = bus.msg("sensor_msgs/msg/JointState")
    publish(bus, contract.APPLIED, joint_state(JS, t, effort=(80.0, 80.0)))
    publish(bus, contract.REFERENCE, named_vector(JS, t, contract.REFERENCE_NAMES, REF))
    publish(bus, contract.ESTIMATE, joint_state(JS, t, position=(gap, 0.008), velocity=(0.0, 0.0), effort=(4.0, 4.0)))
    bus.spin_once()


def test_nan_estimate_never_becomes_a_nan_command():
    """Fed NaN, the controller sends no command for that sample, counts it, and acts on the next one."""
    bus, ctl, cmds, states, _ = _graph()
    t0 = bus.now_ns
    bad = {20, 21, 40}
    for k in range(60):
        bus.now_ns = t0 + k * T  # each sample fresh when it arrives
        _feed(bus, k, t0 + k * T, float("nan") if k in bad else 0.008)
    assert sorted(cmds) == [t0 + k * T for k in range(60) if k not in bad]
    assert all(math.isfinite(v) for u in cmds.values() for v in u)
    assert ctl.counts["non_finite_input"] == 3 and ctl.counts["steps"] == 57
    assert all(states[t0 + k * T]["fault"] == 1.0 for k in bad)  # the state says why there was no command
    assert ctl.node.callback_errors == {}


def test_a_sample_older_than_max_age_is_not_acted_on():
    """Age is measured on the experiment clock (the newest /dem/applied_voltage stamp): wall time is
    irrelevant (a lockstep plant's clock lags it)."""
    bus, ctl, cmds, states, diags = _graph("-p", "max_age:=0.005")
    max_age = ctl.cfg["max_age"]
    assert max_age == 0.005
    t0 = bus.now_ns
    _feed(bus, 0, t0, 0.008)  # fresh
    JS = bus.msg("sensor_msgs/msg/JointState")
    bus.now_ns = t0 + 3_600_000 * T  # an hour of wall time later: still fresh on the plant's clock
    _feed(bus, 1, t0 + T, 0.008)
    late = t0 + 2 * T + round(2 * max_age * 1e9)  # the plant has moved on twice max_age past the next sample
    for t in (late - T, late):  # two samples in a row: a lone jump does not move the clock (a corrupt stamp)
        publish(bus, contract.APPLIED, joint_state(JS, t, effort=(80.0, 80.0)))
    publish(bus, contract.ESTIMATE, joint_state(JS, t0 + 2 * T, position=(0.008, 0.008), velocity=(0.0, 0.0),
                                               effort=(4.0, 4.0)))
    bus.spin_once()
    assert list(cmds) == [t0, t0 + T] and ctl.counts["stale"] == 1
    assert states[t0 + 2 * T]["fault"] == 1.0 and states[t0 + 2 * T]["age_s"] > max_age
    bus.advance(1.0)  # the once-a-second diagnostics report it
    assert diags and diags[-1].status[0].level != 0


def test_hover_window_holds_the_applied_voltage_then_initialises_from_it():
    """Pre-roll samples: the node holds the applied voltage for hover_window, then the law starts from that
    window (the same hover fit as the offline simulator)."""
    bus, ctl, cmds, _, _ = _graph("-p", "hover_window:=0.01")
    n = ctl.seq.window_n
    assert n == 10
    JS = bus.msg("sensor_msgs/msg/JointState")
    t0 = bus.now_ns
    for k in range(n + 5):
        t = t0 + k * T
        bus.now_ns = t
        publish(bus, contract.APPLIED, joint_state(JS, t, effort=(80.0, 80.0), frame=contract.FRAME_PREROLL))
        publish(bus, contract.REFERENCE,
                named_vector(JS, t, contract.REFERENCE_NAMES, REF, frame=contract.FRAME_PREROLL))
        publish(bus, contract.ESTIMATE, joint_state(JS, t, position=(0.008, 0.008), velocity=(0.0, 0.0),
                                                   effort=(4.0, 4.0), frame=contract.FRAME_PREROLL))
        bus.spin_once()
    assert [cmds[t0 + k * T] for k in range(n - 1)] == [[80.0, 80.0]] * (n - 1)  # held while collecting
    assert ctl.seq.started and ctl.seq.law.hover_fit.samples == n and ctl.seq.law.hover_fit.determined == 3
    assert ctl.seq.law.diag[1] == 20.0  # R_hat = u/i of the window
    assert all(abs(v - 80.0) < 1e-6 for k in range(n, n + 5) for v in cmds[t0 + k * T])  # the law holds the hover


def test_an_applied_voltage_with_a_refused_stamp_is_not_taken_as_the_applied_voltage():
    """Review defect: a /dem/applied_voltage whose stamp the plant clock's guard refuses (the ``future-applied``
    fault: a copy of a measurement, its currents ~4 A where the voltages are ~80 V, stamped +1 h) still
    overwrote ``u_applied``: the hover window took 4 V for that sample (R_hat 18.1 instead of 20) and a
    restart on the next estimate would start the law from it. Refused stamp: nothing of the sample is taken."""
    bus, ctl, cmds, _, _ = _graph("-p", "hover_window:=0.01")
    n = ctl.seq.window_n
    JS = bus.msg("sensor_msgs/msg/JointState")
    t0 = bus.now_ns
    bad = 4
    for k in range(n + 3):
        t = t0 + k * T
        bus.now_ns = t
        publish(bus, contract.APPLIED, joint_state(JS, t, effort=(80.0, 80.0), frame=contract.FRAME_PREROLL))
        if k == bad:  # the injected fault: the measurement's copy, stamped an hour ahead
            publish(bus, contract.APPLIED, joint_state(JS, t + 3600 * 10**9, position=(0.008, 0.008),
                                                      effort=(4.0, 4.0), frame=contract.FRAME_PREROLL))
        publish(bus, contract.REFERENCE,
                named_vector(JS, t, contract.REFERENCE_NAMES, REF, frame=contract.FRAME_PREROLL))
        publish(bus, contract.ESTIMATE, joint_state(JS, t, position=(0.008, 0.008), velocity=(0.0, 0.0),
                                                   effort=(4.0, 4.0), frame=contract.FRAME_PREROLL))
        bus.spin_once()
        if k == bad:
            assert ctl.counts["plant_stamp_jump"] == 1
            assert ctl.u_applied is not None and ctl.u_applied.tolist() == [80.0, 80.0]
            assert cmds[t] == [80.0, 80.0]  # the hover held with the plant's voltage, not the copy's 4 V
    assert ctl.seq.started and ctl.seq.law.hover_fit.samples == n
    assert ctl.seq.law.diag[1] == 20.0  # R_hat = u/i of the window: the refused sample's 4 V is not in it
    assert all(abs(v - 80.0) < 1e-6 for k in range(n, n + 3) for v in cmds[t0 + k * T])
    assert ctl.node.callback_errors == {}


def test_an_estimate_with_a_stamp_already_acted_on_is_not_acted_on_again():
    """The estimator sends each stamp once: a second estimate with that stamp (a foreign or corrupt writer, as
    `dem-ros faults` bad-cdr sends) must not step the law a second time for the sample nor send a second
    command for it (the plant takes the last command of a stamp)."""
    bus, ctl, cmds, _, _ = _graph()
    t0 = bus.now_ns
    JS = bus.msg("sensor_msgs/msg/JointState")
    for k in range(30):
        bus.now_ns = t0 + k * T
        _feed(bus, k, t0 + k * T, 0.008)
        if k == 20:
            sent = list(cmds[t0 + k * T])
            publish(bus, contract.ESTIMATE, joint_state(JS, t0 + k * T, position=(0.0085, 0.008), velocity=(0.0, 0.0),
                                                       effort=(4.0, 4.0)))
            bus.spin_once()
            assert cmds[t0 + k * T] == sent  # the first command of the stamp stands
    assert ctl.counts["estimate_repeated"] == 1 and ctl.counts["steps"] == 30
    assert sorted(cmds) == [t0 + k * T for k in range(30)]
