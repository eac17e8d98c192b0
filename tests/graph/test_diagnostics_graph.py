"""/diagnostics of the real graph by the convention: every status named "<node>: <task>", no hardware_id for the
software nodes, and each 1 kHz topic's "<node>: <topic> topic status" with diagnostic_updater's keys, at 1000 Hz.

Real node processes (one per node, dds transport) on a domain of their own; the recorded bag is read back with
rosbags (an independent reader), not with dem_ros's.
"""

from __future__ import annotations

import re
from pathlib import Path

import domains
import pytest
from loop_writers import STREAMS

from dem_ros import contract
from dem_ros.core.scenarios import get_scenario
from dem_ros.tools import launcher

DURATION = 6.0  # s of experiment: past a whole frequency window (5 reports) at full rate
FREQ_KEYS = ["Events in window", "Events since startup", "Duration of window (s)", "Actual frequency (Hz)",
             "Target frequency (Hz)", "Minimum acceptable frequency (Hz)", "Maximum acceptable frequency (Hz)"]
STAMP_KEYS = ["Earliest timestamp delay:", "Latest timestamp delay:", "Earliest acceptable timestamp delay:",
              "Latest acceptable timestamp delay:", "Late diagnostic update count:",
              "Early diagnostic update count:", "Zero seen diagnostic update count:"]


@pytest.fixture(scope="module")
def statuses(tmp_path_factory) -> list[tuple[str, int, str, str, dict[str, str]]]:
    """(name, level, message, hardware_id, values) of every status in the bag of a recorded S1 run."""
    from rosbags.highlevel import AnyReader

    from dem_ros.board import Supervisor
    from dem_ros.core.warmup import warm_up

    warm_up()  # the kernels from the on-disk cache (the node processes load it instead of compiling each)
    cfg = get_scenario("S1").config()
    Supervisor(cfg["plant_sim"], cfg["plant_sim"]["dt"])
    cfg["plant_sim"]["start_delay"] = 6.0  # every endpoint matched before the clock starts (test_free_run.py)
    root = tmp_path_factory.mktemp("diag")
    bag = root / "run"
    meta = {"scenario": "S1", "controller": "adaptive", "estimator": "kf", "transport": "dds", "config": cfg}
    launcher.run_graph(cfg, duration=DURATION, transport="dds", bag=bag, meta=meta, domain_id=domains.hold(),
                       status=False, workdir=root / "logs")
    out = []
    with AnyReader([Path(bag)]) as reader:
        conns = [c for c in reader.connections if c.topic == contract.DIAGNOSTICS.name]
        for conn, _t, raw in reader.messages(connections=conns):
            for st in reader.deserialize(raw, conn.msgtype).status:
                level = st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")
                out.append((st.name, level, st.message, st.hardware_id, {kv.key: kv.value for kv in st.values}))
    assert out, "no /diagnostics in the bag"
    return out


def test_every_status_is_node_colon_task_with_no_hardware_id(statuses):
    names = {name for name, *_ in statuses}
    assert all(re.fullmatch(r"[a-z_]+: .+", n) for n in names), sorted(names)
    assert {hw for _, _, _, hw, _ in statuses} == {""}  # software nodes only (no hardware driver here)
    assert {contract.LOOP_STATUS, contract.ESTIMATOR_STATUS, contract.CONTROLLER_STATUS, contract.REFERENCE_STATUS,
            contract.RECORDING_STATUS, contract.RECORDER_STATUS} <= names, sorted(names)
    former = set(contract.FORMER_STATUS_NAMES)
    assert not names & former, sorted(names & former)


def test_the_plant_watches_the_recorder(statuses):
    """The plant node's watch on the recorder (nodes/recording_watch.py) saw its once-a-second reports."""
    reports = [values for name, _, _, _, values in statuses if name == contract.RECORDING_STATUS]
    assert reports and all("recorder" in v for v in reports), reports[:3]
    assert any(v["recorder"] == "alive" for v in reports), [v["recorder"] for v in reports]


@pytest.mark.parametrize(("node", "topic"), [(n, t.name) for n, ts in STREAMS.items() if n != "hw_driver"
                                             for t in ts])
def test_each_1khz_topic_has_its_topic_status_at_1000_hz(statuses, node, topic):
    name = contract.topic_status(node, topic)
    reports = [(level, message, values) for n, level, message, _, values in statuses if n == name]
    assert reports, f"no {name!r} in the bag"
    for _level, _message, values in reports:
        assert list(values) == FREQ_KEYS + STAMP_KEYS, values
        assert values["Target frequency (Hz)"] == "1000.000000"
        assert values["Minimum acceptable frequency (Hz)"] == "900.000000"
        assert float(values["Duration of window (s)"]) >= 0.5  # never a first window of a few ms
    # the report over the longest full-rate window (the first ones start at the node's first message; the last
    # ones may span the end of the run, when the plant stopped): within diagnostic_updater's 10 % of 1000 Hz
    level, message, values = max(reports, key=lambda r: int(r[2]["Events in window"]))
    hz = float(values["Actual frequency (Hz)"])
    assert 900.0 <= hz <= 1100.0, (name, level, message, values)
    assert message.startswith("Desired frequency met"), (name, level, message, values)
    # delays: the age of each stamp at its publication, ms in a closed loop (the reference's is about -1 ms)
    assert -1.0 <= float(values["Earliest timestamp delay:"]) <= float(values["Latest timestamp delay:"]) <= 5.0
