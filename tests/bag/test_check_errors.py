"""check() reports, and corrupt/foreign input gives a BagError without traceback."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from bagutil import STORE, joint_state, joint_state_cdr, write_bag
from mcap.writer import Writer as McapWriter

from dem_ros.bag import BagError, BagReader, BagWriter, check, main_check
from dem_ros.contract import MEASUREMENT, QOS_STREAM

ROOT = Path(__file__).resolve().parents[2]


def test_check_complete_bag(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A complete bag: OK, counts agree, compression and chunks listed; CLI returns 0."""
    rep = check(bag)
    assert rep.ok and rep.complete and rep.metadata_yaml == "complete"
    assert rep.compression == ["zstd"] and rep.chunks > 1
    assert {t.name: t.count for t in rep.topics}["/dem/measurement"] == 600
    assert all(t.gaps == 0 for t in rep.topics)
    assert rep.run_metadata is not None and rep.run_metadata["scenario"] == "S1"
    assert main_check([str(bag)]) == 0
    out = capsys.readouterr().out
    assert "result:       OK" in out and "/dem/controller/state" in out


def test_check_stamp_gaps(tmp_path: Path) -> None:
    """Missing 1 kHz samples are counted (gaps, samples missing, largest gap)."""
    with BagWriter(tmp_path / "g") as w:
        w.add_topic(MEASUREMENT.name, MEASUREMENT.type, MEASUREMENT.qos)
        for k in [*range(0, 100), *range(105, 200), *range(250, 300)]:
            w.write(MEASUREMENT.name, k * 10**6,
                    joint_state_cdr(["magnet_1", "magnet_2"], [0, 0], [], [0, 0], k * 10**6))
    rep = check(tmp_path / "g")
    (t,) = rep.topics
    assert (t.gaps, t.missing_samples, t.largest_gap_ns) == (2, 5 + 50, 51 * 10**6)
    assert rep.ok  # gaps are warnings, not integrity problems
    assert any("2 gap(s)" in w for w in rep.warnings)


def test_check_metadata_mismatch_and_missing(bag: Path, tmp_path: Path) -> None:
    """Edited counts in metadata.yaml, then no metadata.yaml at all."""
    b = tmp_path / "edited"
    shutil.copytree(bag, b)
    doc = yaml.safe_load((b / "metadata.yaml").read_text())
    doc["rosbag2_bagfile_information"]["topics_with_message_count"][0]["message_count"] += 7
    (b / "metadata.yaml").write_text(yaml.safe_dump(doc))
    rep = check(b)
    assert not rep.ok
    assert any("metadata.yaml says 607 messages, the MCAP holds 600" in p for p in rep.problems)
    (b / "metadata.yaml").unlink()
    rep = check(b)
    assert rep.metadata_yaml == "missing" and any("metadata.yaml is missing" in p for p in rep.problems)
    assert BagReader(b).topics["/dem/measurement"].count == 600  # still readable


def test_truncated_copy(bag: Path, tmp_path: Path) -> None:
    """A file cut in the middle of a chunk: read up to the previous chunk, report where."""
    b = tmp_path / "cut"
    shutil.copytree(bag, b)
    f = b / f"{bag.name}_0.mcap"
    with BagReader(bag) as r:
        third = r.chunks[2]
    data = f.read_bytes()
    f.write_bytes(data[: third.offset + third.length // 2])
    with BagReader(b) as r:
        assert len(r.chunks) == 2
        tr = r.truncated
        assert tr is not None and tr.offset == third.offset and "cut off" in tr.reason
        n = sum(1 for _ in r.messages())
        assert n == sum(t.count for t in r.topics.values()) > 0
    rep = check(b)
    assert "truncated after chunk 2 at t=" in rep.truncation and f"{n} messages recoverable" in rep.truncation
    assert any("metadata.yaml says" in p for p in rep.problems)  # counts no longer match


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "empty"),
        (b"hello", "too short"),
        (b"not an mcap file at all, just text\n" * 3, "not an MCAP file"),
        (b"\x89MCAP0\r\n\x01\xff\xff\xff\xff\x00\x00\x00\x00", "header record missing or cut off"),
    ],
)
def test_corrupt_files(tmp_path: Path, content: bytes, match: str) -> None:
    """Empty, short, non-MCAP and header-truncated files -> BagError naming the problem."""
    f = tmp_path / "x.mcap"
    f.write_bytes(content)
    with pytest.raises(BagError, match=match):
        BagReader(f)
    with pytest.raises(BagError):
        check(f)


def test_missing_and_foreign_inputs(tmp_path: Path) -> None:
    """Missing path, empty dir, bad metadata.yaml, sqlite bag, non-ROS MCAP, MCAP without our topics."""
    with pytest.raises(BagError, match="does not exist"):
        BagReader(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"without metadata\.yaml or any \.mcap"):
        BagReader(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "metadata.yaml").write_text("just: [a, list\n")
    with pytest.raises(BagError, match="not rosbag2 metadata"):
        BagReader(tmp_path / "bad")
    (tmp_path / "sq").mkdir()
    (tmp_path / "sq" / "metadata.yaml").write_text(
        yaml.safe_dump({"rosbag2_bagfile_information": {"storage_identifier": "sqlite3"}}))
    with pytest.raises(BagError, match="sqlite3"):
        BagReader(tmp_path / "sq")
    with open(tmp_path / "json.mcap", "wb") as fh:
        w = McapWriter(fh)
        w.start(profile="", library="test")
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/x", "json", sid)
        w.add_message(cid, 1, b"{}", 1)
        w.finish()
    with pytest.raises(BagError, match="not a ROS 2 one"):
        BagReader(tmp_path / "json.mcap")
    with BagWriter(tmp_path / "other") as w:
        w.add_topic("/chatter", "std_msgs/msg/String", QOS_STREAM)
        w.write("/chatter", 1, bytes(STORE.serialize_cdr(STORE.types["std_msgs/msg/String"](data="hi"),
                                                         "std_msgs/msg/String")))
    rep = check(tmp_path / "other")
    assert any("none of the dem_ros contract topics" in p for p in rep.problems)
    with BagReader(tmp_path / "other") as r, pytest.raises(BagError, match=r"/dem/measurement.*not in"):
        r.joint_state_arrays("/dem/measurement")


def test_cli_prints_error_without_traceback(tmp_path: Path) -> None:
    """main_check on garbage: exit status 2, one-line error, no traceback."""
    f = tmp_path / "garbage.mcap"
    f.write_bytes(b"\x00" * 100)
    code = "import sys; from dem_ros.bag import main_check; sys.exit(main_check(sys.argv[1:]))"
    p = subprocess.run([sys.executable, "-c", code, str(f)], capture_output=True, text=True, cwd=ROOT)
    assert p.returncode == 2
    assert p.stdout.startswith("error: ") and "not an MCAP file" in p.stdout
    assert "Traceback" not in p.stdout + p.stderr


def test_bag_package_imports_no_middleware() -> None:
    """dem_ros.bag must not pull in rclpy or cyclonedds."""
    code = ("import sys, dem_ros.bag, dem_ros.bag.bench; "
            "bad = [m for m in sys.modules if m.split('.')[0] in ('rclpy', 'cyclonedds')]; "
            "sys.exit(1 if bad else 0)")
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT).returncode == 0


def test_bench_record_smoke() -> None:
    """bench_record runs and returns the documented keys (no timing assertions)."""
    from dem_ros.bag.bench import bench_record

    out = bench_record(0.1, unpaced_messages=2000)
    assert {"msgs_per_s", "mb_per_s", "cpu_percent"} <= out.keys()
    assert out["paced_written"] + out["paced_dropped"] == 700


def test_write_bag_helper_roundtrip_small(tmp_path: Path) -> None:
    """The shared helper with a tiny stream (guards the fixtures themselves)."""
    b = write_bag(tmp_path / "s", [("/dem/measurement", 5, joint_state(0, 0), MEASUREMENT.type)])
    assert check(b).ok


def _summary(mcap: Path) -> tuple[bytearray, int, int]:
    """(file bytes, summary_start, footer offset) of an MCAP file."""
    import struct

    d = bytearray(mcap.read_bytes())
    footer = len(d) - 8 - 29
    return d, struct.unpack_from("<Q", d, footer + 9)[0], footer


def test_check_finds_a_damaged_summary_section(bag: Path, tmp_path: Path) -> None:
    """One flipped byte in the summary section: the footer's summary CRC no longer matches (issue #21: such a
    bag passed with `result: OK`)."""
    import struct

    dst = tmp_path / "damaged"
    shutil.copytree(bag, dst)
    mcap = next(dst.glob("*.mcap"))
    d, start, _footer = _summary(mcap)
    pos = start
    while d[pos] != 0x08:  # the first ChunkIndex record: a flipped bit in its start time still parses
        pos += 9 + struct.unpack_from("<Q", d, pos + 1)[0]
    d[pos + 9] ^= 0x01
    mcap.write_bytes(bytes(d))
    rep = check(dst)
    assert not rep.ok and any("summary section damaged (summary CRC" in p for p in rep.problems), rep.problems
    assert main_check([str(dst)]) == 1


def test_check_finds_a_chunk_index_that_points_nowhere(bag: Path, tmp_path: Path) -> None:
    """A chunk index whose chunk offset is wrong, with the summary CRC made to match again: the index is
    checked against the chunk it names."""
    import struct
    import zlib

    dst = tmp_path / "index"
    shutil.copytree(bag, dst)
    mcap = next(dst.glob("*.mcap"))
    d, start, footer = _summary(mcap)
    pos = start
    while d[pos] != 0x08:  # the first ChunkIndex record
        pos += 9 + struct.unpack_from("<Q", d, pos + 1)[0]
    offset = struct.unpack_from("<Q", d, pos + 9 + 16)[0]
    struct.pack_into("<Q", d, pos + 9 + 16, offset + 1)
    struct.pack_into("<I", d, footer + 9 + 16, zlib.crc32(d[start:footer + 9 + 16]))
    mcap.write_bytes(bytes(d))
    rep = check(dst)
    assert any(f"chunk index 1: no chunk at offset {offset + 1}" in p for p in rep.problems), rep.problems
    assert not any("summary CRC" in p for p in rep.problems)
