"""BagReader on our bags and on rosbag2-style bags written by rosbags."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from bagutil import RUN_INFO, STORE, joint_state, joint_state_cdr, string_msg
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer

from dem_ros.bag import BagError, BagReader, BagWriter
from dem_ros.contract import QOS_STREAM, QoS

INF = QosTime(9223372036, 854775807)


def test_topics_messages_and_metadata(bag: Path, stream) -> None:
    """topics (type, count, QoS), decoded messages in file order, run_metadata."""
    with BagReader(bag) as r:
        assert r.truncated is None
        t = r.topics
        assert t["/dem/run_info"].qos == [QoS(reliable=True, transient_local=True, depth=1)]
        assert t["/dem/measurement"].type == "sensor_msgs/msg/JointState"
        assert t["/dem/measurement"].count == 600
        msgs = list(r.messages(["/diagnostics"]))
        assert [m.status[0].values[0].value for _, _, m in msgs] == ["0", "200", "400"]
        assert r.run_metadata() == RUN_INFO
        assert sum(1 for _ in r.messages()) == len(stream)
    # a bare .mcap works too
    with BagReader(bag / f"{bag.name}_0.mcap") as r:
        assert r.metadata_yaml is None
        assert r.run_metadata() == RUN_INFO  # from the MCAP records
        assert r.topics["/dem/command"].count == 600


def test_joint_state_arrays_fast_path(bag: Path) -> None:
    """Uniform layout: vectorised extraction equals the decoded messages."""
    with BagReader(bag) as r:
        a = r.joint_state_arrays("/dem/state_estimate")
        ref = [m for _, _, m in r.messages(["/dem/state_estimate"])]
    assert a["name"] == ["magnet_1", "magnet_2"]
    assert a["position"].shape == (600, 2) and a["velocity"].shape == (600, 2)
    np.testing.assert_array_equal(a["stamp_ns"], np.arange(600) * 1_000_000)
    np.testing.assert_array_equal(a["position"], np.array([m.position for m in ref]))
    np.testing.assert_array_equal(a["velocity"], np.array([m.velocity for m in ref]))
    np.testing.assert_array_equal(a["effort"], np.array([m.effort for m in ref]))
    assert a["log_time_ns"].dtype == np.int64 and len(a["log_time_ns"]) == 600
    # measurement has an empty velocity
    with BagReader(bag) as r:
        m = r.joint_state_arrays("/dem/measurement")
    assert m["velocity"].shape == (600, 0)


def test_joint_state_arrays_mixed_layout(tmp_path: Path) -> None:
    """Varying array lengths / frame_id: slow path, NaN padded; a message naming other joints than the
    topic's (a foreign or corrupt writer) is left out and counted; nothing parses -> BagError."""
    with BagWriter(tmp_path / "m") as w:
        w.add_topic("/js", "sensor_msgs/msg/JointState", QOS_STREAM)
        w.add_topic("/bad", "sensor_msgs/msg/JointState", QOS_STREAM)
        w.add_topic("/s", "std_msgs/msg/String", QOS_STREAM)
        w.write("/js", 1, joint_state_cdr(["a", "b"], [1.0, 2.0], [3.0, 4.0], [5.0, 6.0], 10))
        w.write("/js", 2, joint_state_cdr(["a", "b"], [1.5, 2.5], [], [5.5, 6.5], 20))
        w.write("/bad", 1, joint_state_cdr(["a"], [1.0], [], [], 10))
        w.write("/bad", 2, joint_state_cdr(["b"], [1.0], [], [], 20))
        w.write("/bad", 3, joint_state_cdr(["a"], [3.0], [], [], 30))
        w.add_topic("/junk", "sensor_msgs/msg/JointState", QOS_STREAM)
        w.write("/junk", 1, b"\x00\x01\x00\x00garbage")
    with BagReader(tmp_path / "m") as r:
        a = r.joint_state_arrays("/js")
        np.testing.assert_array_equal(a["stamp_ns"], [10, 20])
        np.testing.assert_array_equal(a["position"], [[1.0, 2.0], [1.5, 2.5]])
        assert np.isnan(a["velocity"][1]).all() and a["velocity"][0].tolist() == [3.0, 4.0]
        assert a["skipped"] == 0
        b = r.joint_state_arrays("/bad")
        assert b["name"] == ["a"] and b["skipped"] == 1
        np.testing.assert_array_equal(b["stamp_ns"], [10, 30])
        np.testing.assert_array_equal(b["position"], [[1.0], [3.0]])
        with pytest.raises(BagError, match="no message is a valid JointState"):
            r.joint_state_arrays("/junk")
        with pytest.raises(BagError, match="not sensor_msgs/msg/JointState"):
            r.joint_state_arrays("/s")
        with pytest.raises(BagError, match="not in"):
            r.joint_state_arrays("/dem/measurement")
        assert r.run_metadata() is None


def _rosbags_bag(path: Path, version: int) -> Path:
    """A bag as `ros2 bag record -s mcap` lays it out, written by rosbags."""
    qos = Qos(QosHistory.UNKNOWN, 0, QosReliability.RELIABLE, QosDurability.VOLATILE, INF, INF,
              QosLiveliness.AUTOMATIC, INF, False)
    with Writer(path, version=version, storage_plugin=StoragePlugin.MCAP) as w:
        js = w.add_connection("/dem/measurement", "sensor_msgs/msg/JointState", typestore=STORE,
                              offered_qos_profiles=[qos])
        info = w.add_connection("/dem/run_info", "std_msgs/msg/String", typestore=STORE,
                                offered_qos_profiles=[qos])
        w.write(info, 5, bytes(STORE.serialize_cdr(string_msg(json.dumps({"scenario": "ext"})), "std_msgs/msg/String")))
        for k in range(100):
            w.write(js, 10 + k, bytes(STORE.serialize_cdr(joint_state(k, 1), "sensor_msgs/msg/JointState")))
    return path


@pytest.mark.parametrize("version", [8, 9])
def test_foreign_rosbag2_mcap(tmp_path: Path, version: int) -> None:
    """Directory and bare .mcap written by another rosbag2 writer (v8 and v9 metadata)."""
    bag = _rosbags_bag(tmp_path / f"ext{version}", version)
    for p in (bag, next(bag.glob("*.mcap"))):
        with BagReader(p) as r:
            assert r.topics["/dem/measurement"].count == 100
            assert r.topics["/dem/measurement"].qos == [QoS(reliable=True, transient_local=False, depth=0)]
            a = r.joint_state_arrays("/dem/measurement")
            np.testing.assert_array_equal(a["stamp_ns"], np.arange(100) * 1_000_000)
            assert r.run_metadata() == {"scenario": "ext"}  # from the /dem/run_info topic
