"""The topic statuses of nodes/diagnostics.py (diagnostic_updater's FrequencyStatus, TimeStampStatus and
TopicDiagnostic) fed synthetic tick times, and Diagnostics.report() with them on the in-memory transport: the
key names, value formats, messages and levels are diagnostic_updater's (ros/diagnostics, its Python
``_update_functions.py`` and ``_publisher.py``)."""

from __future__ import annotations

import re

import pytest

from dem_ros import contract
from dem_ros.nodes.common import ERROR, OK, WARN, Diagnostics, joint_state
from dem_ros.nodes.diagnostics import FrequencyStatus, TimeStampStatus, TopicDiagnostic, merge_summary
from dem_ros.transport.memory import MemoryBus

S = 1_000_000_000  # ns
T0 = 1_700_000_000 * S  # a ROS time (ns since the epoch)
FREQ_KEYS = ["Events in window", "Events since startup", "Duration of window (s)", "Actual frequency (Hz)",
             "Target frequency (Hz)", "Minimum acceptable frequency (Hz)", "Maximum acceptable frequency (Hz)"]
STAMP_KEYS = ["Earliest timestamp delay:", "Latest timestamp delay:", "Earliest acceptable timestamp delay:",
              "Latest acceptable timestamp delay:", "Late diagnostic update count:",
              "Early diagnostic update count:", "Zero seen diagnostic update count:"]


def _ticks(td: TopicDiagnostic, t0: int, seconds: float, rate_hz: float, delay_ns: int = 200_000) -> int:
    """Tick ``td`` at ``rate_hz`` for ``seconds`` from ``t0``, each message stamped ``delay_ns`` before its
    publication; the time after the last."""
    n = round(seconds * rate_hz)
    dt = round(S / rate_hz)
    for k in range(n):
        now = t0 + k * dt
        td.tick(now - delay_ns, now)
    return t0 + n * dt


def _topic(rate: float = 1000.0) -> TopicDiagnostic:
    return TopicDiagnostic(contract.MEASUREMENT.name, FrequencyStatus(rate, rate), TimeStampStatus())


def test_frequency_met_exact_keys_and_formats():
    f = FrequencyStatus(1000.0, 1000.0, now_ns=T0)
    for _ in range(1000):
        f.tick()
    level, message, values = f.run(T0 + S)
    assert (level, message) == (OK, "Desired frequency met")
    assert list(values) == FREQ_KEYS
    assert values == {"Events in window": "1000", "Events since startup": "1000", "Duration of window (s)": "1.000000",
                      "Actual frequency (Hz)": "1000.000000", "Target frequency (Hz)": "1000.000000",
                      "Minimum acceptable frequency (Hz)": "900.000000",
                      "Maximum acceptable frequency (Hz)": "1100.000000"}


@pytest.mark.parametrize(("events", "level", "message"), [
    (950, OK, "Desired frequency met"),  # within the 10 % tolerance
    (899, WARN, "Frequency too low."),
    (1101, WARN, "Frequency too high."),
    (0, ERROR, "No events recorded."),
])
def test_frequency_levels_and_messages(events, level, message):
    f = FrequencyStatus(1000.0, 1000.0, now_ns=T0)
    for _ in range(events):
        f.tick()
    got = f.run(T0 + S)
    assert got[:2] == (level, message) and got[2]["Events in window"] == str(events)


def test_without_an_upper_bound_or_target_those_keys_are_left_out():
    f = FrequencyStatus(10.0, now_ns=T0)  # at least 10 Hz, no maximum
    for _ in range(10_000):
        f.tick()
    level, message, values = f.run(T0 + S)
    assert (level, message) == (OK, "Desired frequency met")
    assert list(values) == [k for k in FREQ_KEYS if k not in ("Target frequency (Hz)",
                                                               "Maximum acceptable frequency (Hz)")]


def test_the_window_spans_the_last_window_size_reports():
    f = FrequencyStatus(1000.0, 1000.0, window_size=5, now_ns=T0)
    for second in range(1, 9):
        for _ in range(1000 if second <= 3 else 0):  # silent from the 4th second on
            f.tick()
        level, message, values = f.run(T0 + second * S)
        window = min(second, 5)
        assert values["Duration of window (s)"] == f"{window:f}", (second, values)
        events = sum(1000 for s in range(second - window + 1, second + 1) if s <= 3)
        assert values["Events in window"] == str(events), (second, values)
        assert values["Events since startup"] == str(1000 * min(second, 3))
        # silent for a whole window (5 reports) at the 8th second: until then the rate is just low
        assert level == (OK if second <= 3 else WARN if second < 8 else ERROR), (second, level, message)


def test_a_topic_silent_for_a_whole_window_is_an_error():
    td = _topic()
    t = _ticks(td, T0, 1.0, 1000.0)
    td.run(t)
    for second in range(1, 6):
        level, message, values = td.run(t + second * S)
    assert level == ERROR and message.startswith("No events recorded.") and values["Events in window"] == "0"


def test_timestamps_reasonable_none_late_early_zero():
    ts = TimeStampStatus()
    for delay in (100_000, 300_000, -50_000):
        ts.tick(T0 - delay, T0)
    level, message, values = ts.run()
    assert (level, message) == (OK, "Timestamps are reasonable.")
    assert list(values) == STAMP_KEYS
    assert values == {"Earliest timestamp delay:": "-0.000050", "Latest timestamp delay:": "0.000300",
                      "Earliest acceptable timestamp delay:": "-1.000000",
                      "Latest acceptable timestamp delay:": "5.000000", "Late diagnostic update count:": "0",
                      "Early diagnostic update count:": "0", "Zero seen diagnostic update count:": "0"}
    assert ts.run()[:2] == (WARN, "No data since last update.")  # nothing since the previous report
    ts.tick(T0 - 6 * S, T0)
    assert ts.run()[:2] == (ERROR, "Timestamps too far in past seen.")
    ts.tick(T0 + 2 * S, T0)
    assert ts.run()[:2] == (ERROR, "Timestamps too far in future seen.")
    ts.tick(0, T0)  # a zero stamp alone: no delay to judge (diagnostic_updater checks zeros with the delays)
    assert ts.run()[:2] == (WARN, "No data since last update.")
    ts.tick(0, T0)
    ts.tick(T0 - 100_000, T0)
    level, message, values = ts.run()
    assert (level, message) == (ERROR, "Zero timestamp seen.")
    assert (values["Late diagnostic update count:"], values["Early diagnostic update count:"],
            values["Zero seen diagnostic update count:"]) == ("1", "1", "1")


def test_merge_summary_is_diagnostic_updaters():
    assert merge_summary((OK, ""), OK, "a") == (OK, "a")
    assert merge_summary((OK, "a"), OK, "b") == (OK, "a; b")
    assert merge_summary((OK, "a"), WARN, "b") == (WARN, "b")
    assert merge_summary((WARN, "b"), OK, "c") == (WARN, "b")
    assert merge_summary((WARN, "b"), ERROR, "c") == (ERROR, "b; c")


def test_topic_status_name_keys_and_merged_message():
    td = _topic()
    assert td.name == "/dem/measurement topic status" and not td.started and not td.ready(T0, 0)
    t = _ticks(td, T0, 1.0, 1000.0)
    assert td.started and td.ready(T0 + S // 2, S // 2) and not td.ready(T0 + S // 2 - 1, S // 2)
    level, message, values = td.run(t)
    assert (level, message) == (OK, "Desired frequency met; Timestamps are reasonable.")
    assert list(values) == FREQ_KEYS + STAMP_KEYS
    assert values["Actual frequency (Hz)"] == "1000.000000" and values["Latest timestamp delay:"] == "0.000200"
    t = _ticks(td, t, 1.0, 500.0, delay_ns=7 * S)  # half the rate, stamps 7 s old
    level, message, values = td.run(t)
    assert (level, message) == (ERROR, "Frequency too low.; Timestamps too far in past seen.")
    assert values["Actual frequency (Hz)"] == "750.000000"  # 1500 events in the 2 s window


def test_the_window_starts_at_the_first_publication():
    """A topic first published long after its status was made: its first window is from the first message."""
    td = _topic()
    t = _ticks(td, T0 + 100 * S, 1.0, 1000.0)
    level, _, values = td.run(t)
    assert level == OK and values["Duration of window (s)"] == "1.000000"


def _level(st) -> int:
    return st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")


def test_report_carries_each_published_topic_with_the_node_status_and_publish_does_not():
    bus = MemoryBus()
    node = bus.node("probe")
    arrays: list = []
    bus.node("watcher").subscribe(contract.DIAGNOSTICS, lambda m: arrays.append(m.status))
    d = Diagnostics(node, "probe: loop", timer=False, hardware_id="board 7")
    pub = d.diagnosed(contract.MEASUREMENT)
    d.diagnosed(contract.ESTIMATE)  # never published: not reported
    JS = node.msg("sensor_msgs/msg/JointState")
    received: list = []
    bus.node("sink").subscribe(contract.MEASUREMENT, received.append)
    node.timer(0.001, lambda: pub.publish(joint_state(JS, bus.now_ns - 100_000, position=(0.008, 0.008))))
    node.timer(1.0, d.report)
    bus.advance(3.0)
    assert len(received) == 3000 and pub.subscription_count == 1  # the publisher's own, through the wrapper
    d.publish(WARN, "an event")  # an event report: the node's status alone
    bus.spin_once()
    assert [len(a) for a in arrays] == [2, 2, 2, 1]
    node_st, topic_st = arrays[-2]
    assert node_st.name == "probe: loop" and topic_st.name == "probe: /dem/measurement topic status"
    assert topic_st.name == contract.topic_status("probe", contract.MEASUREMENT.name)
    assert {s.hardware_id for a in arrays for s in a} == {"board 7"}
    values = {kv.key: kv.value for kv in topic_st.values}
    assert (_level(topic_st), topic_st.message) == (OK, "Desired frequency met; Timestamps are reasonable.")
    assert values["Target frequency (Hz)"] == "1000.000000" and values["Latest timestamp delay:"] == "0.000100"
    assert abs(float(values["Actual frequency (Hz)"]) - 1000.0) <= 1.0, values
    assert all(re.fullmatch(r"[a-z_]+: .+", s.name) for a in arrays for s in a)


def test_a_topic_is_reported_once_its_first_message_is_half_a_period_old():
    """Published from 0.8 s on, reports at 1 s, 2 s: the one at 1 s has no window to speak of (0.2 s) and leaves
    the topic out; the one at 2 s has 1.2 s."""
    bus = MemoryBus()
    node = bus.node("probe")
    arrays: list = []
    bus.node("watcher").subscribe(contract.DIAGNOSTICS, lambda m: arrays.append(m.status))
    d = Diagnostics(node, "probe: loop")
    pub = d.diagnosed(contract.MEASUREMENT)
    JS = node.msg("sensor_msgs/msg/JointState")
    t_start = bus.now_ns + 800_000_000
    node.timer(0.001, lambda: pub.publish(joint_state(JS, bus.now_ns)) if bus.now_ns >= t_start else None)
    bus.advance(2.0)
    assert [[s.name for s in a] for a in arrays] == [["probe: loop"], ["probe: loop",
                                                                      "probe: /dem/measurement topic status"]]
    values = {kv.key: kv.value for kv in arrays[-1][1].values}
    assert values["Duration of window (s)"] == "1.200000" and values["Events in window"] == "1200", values


def test_software_nodes_report_an_empty_hardware_id_and_a_topic_without_a_rate_is_refused():
    bus = MemoryBus()
    node = bus.node("probe")
    seen: list = []
    bus.node("watcher").subscribe(contract.DIAGNOSTICS, lambda m: seen.extend(m.status))
    d = Diagnostics(node, "probe: task")
    bus.advance(1.0)
    assert [(s.name, s.hardware_id) for s in seen] == [("probe: task", "")]
    with pytest.raises(ValueError, match="no nominal rate"):
        d.diagnosed(contract.RUN_INFO)
