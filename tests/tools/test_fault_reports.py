"""What counts as a fault's report in ``dem-ros faults``: a WARN that a lockstep run on a loaded machine has
without any fault (the plant's loop status after a wait, a topic's status whose rate fell) does not; the nodes'
WARN/ERROR log records come from the bag's ``/rosout`` and what the injector heard live, never from log text."""

from dem_ros import contract
from dem_ros.tools.faults.judge import _routine_warn


def test_routine_warns_are_not_reports_and_errors_are():
    topic = contract.topic_status("plant_sim", contract.MEASUREMENT.name)
    assert _routine_warn(f"{contract.LOOP_STATUS} WARN") and _routine_warn(f"{contract.LOOP_STATUS} WARN (live)")
    assert _routine_warn(f"{topic} WARN") and _routine_warn(f"{topic} WARN (live)")
    assert not _routine_warn(f"{topic} ERROR")  # silent for a whole window, or stamps far off
    assert not _routine_warn(f"{contract.LOOP_STATUS} ERROR")
    assert not _routine_warn(f"{contract.ESTIMATOR_STATUS} WARN") and not _routine_warn("plant_sim: inputs WARN")


def _log(stamp_ns: int, name: str, level: int, text: str):
    from dem_ros.typestore import typestore

    T = typestore().types
    return T["rcl_interfaces/msg/Log"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), level=level,
        name=name, msg=text, file="", function="", line=0)


def test_rosout_records_are_read_from_the_bag_at_warn_and_above(tmp_path):
    """The judge reads the nodes' WARN/ERROR log records from the bag's /rosout (rcl_interfaces/msg/Log), by
    logger name, level and stamp: structured records, no log text parsed."""
    from dem_ros.bag import BagWriter
    from dem_ros.tools.faults.judge import RosoutRecord, _read_bag
    from dem_ros.typestore import typestore

    bag = tmp_path / "bag"
    with BagWriter(bag, metadata={"scenario": "S1"}) as w:
        w.add_topic(contract.ROSOUT.name, contract.ROSOUT.type, contract.ROSOUT.qos)
        for i, (name, level, text) in enumerate([("controller", 20, "ready"), ("controller", 30, "refused"),
                                                 ("recorder", 40, "recording stopped: disk full")]):
            data = typestore().serialize_cdr(_log(10**9 + i, name, level, text), contract.ROSOUT.type)
            w.write(contract.ROSOUT.name, 10**9 + i, bytes(data))
    assert _read_bag(bag)["rosout"] == [RosoutRecord(10**9 + 1, "controller", 30, "refused"),
                                        RosoutRecord(10**9 + 2, "recorder", 40, "recording stopped: disk full")]


def test_rosout_reports_count_the_bags_records_then_those_heard_live_only():
    from dem_ros.tools.faults.inject import INJECTOR_NODE
    from dem_ros.tools.faults.judge import RosoutRecord, rosout_heard, rosout_record

    early = RosoutRecord(1, "controller", 30, "before the window")
    a, b = RosoutRecord(10, "controller", 30, "refused"), RosoutRecord(11, "controller", 40, "refused again")
    lost = RosoutRecord(12, "recorder", 40, "recording stopped: disk full")  # heard live, never recorded
    own = RosoutRecord(13, INJECTOR_NODE, 30, "a sample that does not decode")  # the injector's: not the graph's
    got, said = rosout_heard([early, a, b, own], [a, lost, own], 5, exclude=(INJECTOR_NODE,))
    assert got == [a, b, lost] and said == "controller 2, recorder 1 (live)"
    assert rosout_heard([early], [], 5) == ([], "nothing")
    assert rosout_record(_log(7, "estimator", 20, "converged")) is None  # INFO is no report
    assert rosout_record(_log(7, "estimator", 50, "x")) == RosoutRecord(7, "estimator", 50, "x")
