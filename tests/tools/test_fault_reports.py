"""What counts as a fault's report in ``dem-ros faults``: a WARN that a lockstep run on a loaded machine has
without any fault (the plant's loop status after a wait, a topic's status whose rate fell) does not."""

from dem_ros import contract
from dem_ros.tools.faults import _routine_warn


def test_routine_warns_are_not_reports_and_errors_are():
    topic = contract.topic_status("plant_sim", contract.MEASUREMENT.name)
    assert _routine_warn(f"{contract.LOOP_STATUS} WARN") and _routine_warn(f"{contract.LOOP_STATUS} WARN (live)")
    assert _routine_warn(f"{topic} WARN") and _routine_warn(f"{topic} WARN (live)")
    assert not _routine_warn(f"{topic} ERROR")  # silent for a whole window, or stamps far off
    assert not _routine_warn(f"{contract.LOOP_STATUS} ERROR")
    assert not _routine_warn(f"{contract.ESTIMATOR_STATUS} WARN") and not _routine_warn("plant_sim: inputs WARN")
