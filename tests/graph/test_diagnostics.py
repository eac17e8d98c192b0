"""The per-node /diagnostics reporter (nodes/common.Diagnostics) on the in-memory transport: 1 Hz reports,
the counters, WARN for the report after a counter grew, a latched ERROR published at once."""

from __future__ import annotations

from loop_writers import publish

from dem_ros import contract
from dem_ros.nodes.common import ERROR, OK, WARN, Diagnostics
from dem_ros.transport.memory import MemoryBus


def _level(st) -> int:
    return st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")


def _setup():
    bus = MemoryBus()
    node = bus.node("probe")
    seen: list = []
    watcher = bus.node("watcher")
    watcher.subscribe(contract.DIAGNOSTICS, lambda m: seen.extend(
        (_level(s), s.name, s.message, {kv.key: kv.value for kv in s.values}) for s in m.status))
    return bus, node, seen


def test_reports_once_a_second_with_counters_and_warns_only_after_an_increase():
    bus, node, seen = _setup()
    d = Diagnostics(node, warn_on=("rejected",), values=lambda: {"mode": "run"})
    d.counters["rejected"] = 0
    bus.advance(3.0)
    assert [s[0] for s in seen] == [OK, OK, OK] and seen[-1][1] == "probe: status" and seen[-1][2] == "ok"
    assert seen[-1][3] == {"mode": "run", "rejected": "0"}
    d.count("rejected", 3)
    bus.advance(1.0)
    assert seen[-1][0] == WARN and seen[-1][2] == "rejected +3" and seen[-1][3]["rejected"] == "3"
    bus.advance(1.0)  # nothing new: back to OK, the counter keeps the history
    assert seen[-1][0] == OK and seen[-1][3]["rejected"] == "3"
    assert len(seen) == 5


def test_a_fault_is_published_at_once_logged_once_and_latched():
    bus, node, seen = _setup()
    d = Diagnostics(node)
    d.set_condition(WARN, "converging")
    bus.advance(1.0)
    assert seen[-1][:3] == (WARN, "probe: status", "converging")
    d.fault("sensor 1 stuck")
    d.fault("sensor 1 stuck")  # latched: not logged nor published again
    bus.spin_once()
    assert seen[-1][0] == ERROR and seen[-1][2] == "sensor 1 stuck" and len(seen) == 2
    d.set_condition(OK)
    bus.advance(2.0)
    assert [s[0] for s in seen[-2:]] == [ERROR, ERROR]  # latched until cleared
    assert sum("fault: sensor 1 stuck" in line[2] for line in bus.log) == 1
    d.clear_fault()
    bus.advance(1.0)
    assert seen[-1][0] == OK


def test_callback_exceptions_count_and_warn():
    bus, node, seen = _setup()
    Diagnostics(node)

    def boom(msg):
        raise ValueError("bad")

    node.subscribe(contract.MEASUREMENT, boom)
    publish(bus, contract.MEASUREMENT, bus.msg(contract.MEASUREMENT.type)())
    bus.advance(1.0)
    assert seen[-1][0] == WARN and "callback errors: subscription /dem/measurement +1" in seen[-1][2]
    assert seen[-1][3]["callback_errors"] == "1"


def test_an_event_report_keeps_a_latched_fault():
    bus, node, seen = _setup()
    d = Diagnostics(node, name="probe: loop")
    d.publish(WARN, "landing: no command", {"holds": 3})
    bus.spin_once()
    assert seen[-1] == (WARN, "probe: loop", "landing: no command", {"holds": "3"})
    d.fault("trip")
    d.publish(OK, "finished")
    bus.spin_once()
    assert seen[-1][0] == ERROR and seen[-1][2] == "trip"  # a latched fault outranks the event


def test_the_reference_node_reports_refused_measurements():
    from dem_ros.nodes.common import joint_state
    from dem_ros.nodes.reference import ReferenceNode

    bus, _probe, seen = _setup()
    ReferenceNode(bus.node("reference"))
    JS = bus.msg("sensor_msgs/msg/JointState")
    publish(bus, contract.MEASUREMENT, joint_state(JS, bus.now_ns, position=(0.008,)))  # one gap: rejected
    bus.advance(1.0)
    ref = [s for s in seen if s[1] == "reference: inputs"]
    assert (ref and ref[-1][0] == WARN and "malformed +1" in ref[-1][2]
            and ref[-1][3]["measurement_malformed"] == "1"), ref
    bus.advance(1.0)
    assert [s for s in seen if s[1] == "reference: inputs"][-1][0] == OK
