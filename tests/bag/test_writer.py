"""BagWriter output read back by independent readers (rosbags, mcap)."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml
from bagutil import RUN_INFO, STORE, write_bag
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader

from dem_ros.bag import BagError, BagReader, BagWriter
from dem_ros.bag._rosfmt import qos_to_v8_string
from dem_ros.contract import QOS_STREAM, TOPICS, QoS


def _expected_counts(stream):
    return Counter(t for t, *_ in stream)


def _assert_equal_msg(a, b):
    """Deep comparison of two rosbags message objects."""
    if hasattr(a, "__dataclass_fields__"):
        for f in a.__dataclass_fields__:
            _assert_equal_msg(getattr(a, f), getattr(b, f))
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, list):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_equal_msg(x, y)
    else:
        assert a == b


def test_rosbags_rosbag2_reader_roundtrip(bag: Path, stream) -> None:
    """Topics, types, counts, QoS, log times and every decoded value via rosbags.rosbag2.Reader."""
    counts = _expected_counts(stream)
    with Reader(bag) as r:
        conns = {c.topic: c for c in r.connections}
        assert set(conns) == {t.name for t in TOPICS}
        for t in TOPICS:
            c = conns[t.name]
            assert c.msgtype == t.type
            assert c.msgcount == counts[t.name]
            (q,) = c.ext.offered_qos_profiles
            assert q.depth == t.qos.depth
            assert q.reliability == (QosReliability.RELIABLE if t.qos.reliable else QosReliability.BEST_EFFORT)
            assert q.durability == (QosDurability.TRANSIENT_LOCAL if t.qos.transient_local else QosDurability.VOLATILE)
        assert r.message_count == len(stream)
        got = [(c.topic, ts, STORE.deserialize_cdr(raw, c.msgtype)) for c, ts, raw in r.messages()]
    key = lambda x: (x[1], x[0])  # noqa: E731
    want = sorted(((t, lt, m) for t, lt, m, _ in stream), key=key)
    got.sort(key=key)
    assert [(t, lt) for t, lt, _ in got] == [(t, lt) for t, lt, _ in want]
    for (_, _, a), (_, _, b) in zip(got, want, strict=True):
        _assert_equal_msg(a, b)


def test_anyreader_decodes_with_bag_schemas(bag: Path, stream) -> None:
    """AnyReader (types from the bag's own schemas) decodes stamps and values."""
    with AnyReader([bag]) as r:
        meas = [c for c in r.connections if c.topic == "/dem/measurement"]
        stamps, pos = [], []
        for c, _ts, raw in r.messages(connections=meas):
            m = r.deserialize(raw, c.msgtype)
            stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
            pos.append(m.position)
        info = [c for c in r.connections if c.topic == "/dem/run_info"]
        (run,) = [r.deserialize(raw, c.msgtype).data for c, _ts, raw in r.messages(connections=info)]
    assert stamps == [k * 1_000_000 for k in range(600)]
    np.testing.assert_allclose(np.array(pos)[:, 0], 0.010 + 1e-6 * np.arange(600))
    assert json.loads(run) == RUN_INFO


def test_metadata_yaml_v8(bag: Path, stream) -> None:
    """metadata.yaml is version 8 with every key Humble and Jazzy parse, and right counts."""
    doc = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = doc["rosbag2_bagfile_information"]
    assert info["version"] == 8
    assert info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == [f"{bag.name}_0.mcap"]
    assert info["compression_format"] == "" and info["compression_mode"] == ""
    assert isinstance(info["ros_distro"], str)
    counts = _expected_counts(stream)
    assert info["message_count"] == len(stream) == info["files"][0]["message_count"]
    lts = [lt for _, lt, _, _ in stream]
    assert info["starting_time"]["nanoseconds_since_epoch"] == min(lts)
    assert info["duration"]["nanoseconds"] == max(lts) - min(lts)
    for t in info["topics_with_message_count"]:
        md = t["topic_metadata"]
        assert t["message_count"] == counts[md["name"]]
        assert md["serialization_format"] == "cdr"
        assert md["type_description_hash"] == STORE.hash_rihs01(md["type"])
        assert isinstance(md["offered_qos_profiles"], str)  # v8: a YAML string, not a list
        (q,) = yaml.safe_load(md["offered_qos_profiles"])
        assert isinstance(q["history"], int) and isinstance(q["reliability"], int)
    cd = info["custom_data"]
    assert all(isinstance(v, str) for v in cd.values())
    assert json.loads(cd["dem_ros.run_info"]) == RUN_INFO
    assert cd["dem_ros.status"] == "complete"


def test_mcap_records_match_rosbag2_conventions(bag: Path, stream) -> None:
    """Header profile, schemas, channel metadata, statistics, chunk indexes, rosbag2 record (mcap lib)."""
    with open(bag / f"{bag.name}_0.mcap", "rb") as f:
        r = make_reader(f)
        assert r.get_header().profile == "ros2"
        s = r.get_summary()
        assert s is not None and s.statistics is not None
        assert s.statistics.message_count == len(stream)
        assert len(s.chunk_indexes) == s.statistics.chunk_count > 1
        assert {ci.compression for ci in s.chunk_indexes} == {"zstd"}
        for sc in s.schemas.values():
            assert sc.encoding == "ros2msg"
            assert sc.data.decode() == STORE.generate_msgdef(sc.name, ros_version=2)[0]
        by_topic = {c.topic: c for c in s.channels.values()}
        for t in TOPICS:
            c = by_topic[t.name]
            assert c.message_encoding == "cdr"
            assert s.schemas[c.schema_id].name == t.type
            assert c.metadata["offered_qos_profiles"] == qos_to_v8_string(t.qos)
            assert c.metadata["topic_type_hash"] == STORE.hash_rihs01(t.type)
        meta = {m.name: m.metadata for m in r.iter_metadata()}
        ser = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])
        assert ser["version"] == 8 and ser["message_count"] == len(stream)
        assert json.loads(ser["custom_data"]["dem_ros.run_info"]) == RUN_INFO
        assert json.loads(meta["dem_ros"]["dem_ros.run_info"]) == RUN_INFO
        assert sum(1 for _ in r.iter_messages()) == len(stream)


def test_qos_string_is_yaml_cpp_block_form() -> None:
    """The v8 QoS string, byte for byte as rosbag2 (yaml-cpp YAML::Dump) writes it."""
    assert qos_to_v8_string(QoS(reliable=True, transient_local=False, depth=10)) == (
        "- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n"
        "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
        "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
        "  liveliness: 1\n"
        "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
        "  avoid_ros_namespace_conventions: false"
    )
    assert "reliability: 2\n  durability: 1" in qos_to_v8_string(QoS(reliable=False, transient_local=True, depth=1))


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compressions_roundtrip(tmp_path: Path, stream, compression: str) -> None:
    """Each chunk compression reads back through rosbags and our reader."""
    bag = write_bag(tmp_path / "b", stream[:500], compression=compression)
    with Reader(bag) as r:
        assert r.message_count == 500
    with BagReader(bag) as br:
        assert sum(t.count for t in br.topics.values()) == 500
        assert {c.compression for c in br.chunks} == {"" if compression == "none" else compression}


def test_writer_errors(tmp_path: Path) -> None:
    """Misuse raises BagError with the offending value; close() is idempotent."""
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(BagError, match="not an empty directory"):
        BagWriter(tmp_path / "full")
    with pytest.raises(BagError, match="compression"):
        BagWriter(tmp_path / "c", compression="bz2")
    w = BagWriter(tmp_path / "w", metadata={"a": 1})
    with pytest.raises(BagError, match="unknown to the rosbags typestore"):
        w.add_topic("/x", "nope_msgs/msg/Nope", QOS_STREAM)
    w.add_topic("/a", "std_msgs/msg/String", QOS_STREAM)
    with pytest.raises(BagError, match="not added"):
        w.write("/b", 1, b"\x00\x01\x00\x00")
    w.close()
    w.close()
    with pytest.raises(BagError, match="closed"):
        w.write("/a", 1, b"\x00\x01\x00\x00")
    with pytest.raises(BagError, match="JSON"):
        BagWriter(tmp_path / "j", metadata={"a": object()})
    with BagReader(tmp_path / "w") as r:
        assert r.topics["/a"].count == 0
        assert r.run_metadata() == {"a": 1}
