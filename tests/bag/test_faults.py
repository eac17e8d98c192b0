"""Recording that loses nothing it could keep: a real full disk (a small tmpfs), corrupted chunks, malformed
metadata. Each failure is reported (one line, naming what and where), never a traceback or a silent loss."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml
from bagutil import joint_state_cdr

from dem_ros.bag import BagError, BagReader, BagWriter, Recorder, check, main_check
from dem_ros.contract import COMMAND, MEASUREMENT

ROOT = Path(__file__).resolve().parents[2]
NAMES = ["magnet_1", "magnet_2"]


def _msg(k: int, rng: random.Random) -> bytes:
    """A JointState whose floats do not compress (so the disk fills at a predictable rate)."""
    return joint_state_cdr(NAMES, [rng.random(), rng.random()], [], [rng.random(), rng.random()], k * 10**6)


def test_full_disk_stops_the_recorder_cleanly_reports_at_once_and_keeps_what_was_written(small_disk: Path):
    reported: list[str] = []
    when = threading.Event()

    def on_error(reason: str) -> None:
        reported.append(reason)
        when.set()

    rng = random.Random(1)
    rec = Recorder(small_disk / "bag", [MEASUREMENT, COMMAND], {"scenario": "S1"}, compression="none",
                   chunk_size=8 * 1024, on_error=on_error)
    n = 0
    while not when.is_set() and n < 100_000:  # 100 000 x ~100 B = 10 MB: far more than 192 KiB
        rec.on_message(MEASUREMENT.name if n % 2 else COMMAND.name, 10**9 + n * 10**6, _msg(n, rng))
        n += 1
        if n % 500 == 0:
            when.wait(0.01)  # let the writer thread drain (the queue is bounded)
    assert when.wait(60), "the writer never reported the full disk"
    # reported at once, on the writer thread, exactly once, in one line that says why
    assert len(reported) == 1 and "No space left on device" in reported[0] and "\n" not in reported[0]
    assert rec.failure == reported[0]
    assert rec.on_message(MEASUREMENT.name, 0, _msg(0, rng)) is False  # stopped: later messages are drops
    counters = rec.close()  # no exception: the failure is state, not a crash
    assert rec.close() == counters  # idempotent
    total = sum(c.received for c in counters.values())
    assert total == n + 1
    assert all(c.written + c.dropped == c.received for c in counters.values())
    written = {k: c.written for k, c in counters.items()}
    assert all(v > 50 for v in written.values()), written  # the bag kept what reached the disk
    # readable up to the failure: exactly the messages counted as written
    with BagReader(small_disk / "bag") as r:
        got = {t: 0 for t in written}
        for topic, *_ in r.raw_messages():
            got[topic] += 1
    assert got == written
    rep = check(small_disk / "bag")
    assert not rep.ok
    assert any("No space left on device" in p for p in rep.problems), rep.problems
    # finalised on the full disk: the reserve made room for the summary and the final metadata.yaml
    assert rep.complete and not list((small_disk / "bag").glob(".*.reserve"))
    meta = yaml.safe_load((small_disk / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    cd = meta["custom_data"]
    assert cd["dem_ros.status"] == "failed" and "No space left" in cd["dem_ros.failure"]
    saved = json.loads(cd["dem_ros.recorder_counters"])
    assert {k: v["written"] for k, v in saved.items()} == written
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]} == written
    assert rep.problems == [f"recording stopped early: {cd['dem_ros.failure']}"]


def test_full_disk_in_the_writer_raises_one_bag_error_then_refuses(small_disk: Path):
    rng = random.Random(2)
    w = BagWriter(small_disk / "w", compression="none", chunk_size=4096)
    w.add_topic(MEASUREMENT.name, MEASUREMENT.type, MEASUREMENT.qos)
    with pytest.raises(BagError, match="No space left on device") as e:
        for k in range(100_000):
            w.write(MEASUREMENT.name, 10**9 + k, _msg(k, rng))
    assert str(small_disk / "w") in str(e.value)
    assert w.lost[MEASUREMENT.name] > 0 and w.failure
    with pytest.raises(BagError, match="recording stopped"):
        w.write(MEASUREMENT.name, 0, _msg(0, rng))
    in_file = w.counts[MEASUREMENT.name]
    w.close()  # finalises; the failure was already raised by write()
    with BagReader(small_disk / "w") as r:
        assert sum(1 for _ in r.raw_messages()) == in_file > 0
    assert check(small_disk / "w").complete


def test_recorder_counters_survive_a_full_disk_in_a_child_that_exits(small_disk: Path):
    """The recorder process on a full disk exits 0 with its counters printed (no traceback at exit)."""
    code = (
        "import random, sys, time\n"
        "from dem_ros.bag import Recorder\n"
        "from dem_ros.transport.dds.fastcdr import joint_state_bytes\n"
        "from dem_ros.contract import MEASUREMENT\n"
        "rec = Recorder(sys.argv[1], [MEASUREMENT], compression='none', chunk_size=8192,\n"
        "               on_error=lambda r: print('REPORTED', r, flush=True))\n"
        "rng = random.Random(3)\n"
        "for k in range(40000):\n"
        "    rec.on_message(MEASUREMENT.name, k, "
        "joint_state_bytes(0, k, '', ['a', 'b'], [rng.random()] * 2, [], [1.0, 2.0]))\n"
        "    if k % 500 == 0: time.sleep(0.002)\n"
        "c = rec.close()[MEASUREMENT.name]\n"
        "print('COUNTERS', c.received, c.written, c.dropped)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", code, str(small_disk / "c")], capture_output=True, text=True,
                       env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("REPORTED") and "No space left on device" in lines[0]
    received, written, dropped = map(int, lines[-1].split()[1:])
    assert received == 40000 and written + dropped == received and written > 0 and dropped > 0


# --------------------------------------------------------------------------- corrupted chunks
def _bag_with_chunks(path: Path, compression: str) -> int:
    rng = random.Random(4)
    with BagWriter(path, compression=compression, chunk_size=4096) as w:
        w.add_topic(MEASUREMENT.name, MEASUREMENT.type, MEASUREMENT.qos)
        for k in range(400):
            w.write(MEASUREMENT.name, 10**9 + k * 10**6, _msg(k, rng))
    return 400


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_corrupted_chunk_is_named_by_check_and_the_reader(tmp_path: Path, compression: str, capsys):
    bag = tmp_path / "b"
    total = _bag_with_chunks(bag, compression)
    with BagReader(bag) as r:
        chunks = [c for c in r.chunks]
        per_chunk = {c.index: c for c in chunks}
    assert len(chunks) >= 4
    target = per_chunk[1]
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    mid = target.offset + target.length // 2  # inside the chunk's (compressed) payload
    for i in range(16):  # 16 flipped bytes, as in the audit
        data[mid + i] ^= 0xFF
    mcap.write_bytes(bytes(data))

    rep = check(bag)
    assert not rep.ok
    bad = [p for p in rep.problems if "chunk 1 at offset" in p]
    assert len(bad) == 1, rep.problems
    assert ("CRC-32" in bad[0]) or ("does not decompress" in bad[0]) or ("bytes after decompression" in bad[0])
    assert main_check([str(bag)]) == 1
    assert "chunk 1 at offset" in capsys.readouterr().out
    # the reader raises at the bad chunk (never returns its wrong values) ...
    with BagReader(bag) as r, pytest.raises(BagError, match="chunk 1 at offset"):
        for _ in r.raw_messages():
            pass
    # ... and, once told, reads every other chunk
    with BagReader(bag) as r:
        assert len(r.verify_chunks()) == 1
        n = sum(1 for _ in r.raw_messages())
    assert 0 < n < total


def test_intact_bag_verifies(tmp_path: Path):
    _bag_with_chunks(tmp_path / "ok", "zstd")
    with BagReader(tmp_path / "ok") as r:
        assert r.verify_chunks() == []
    assert check(tmp_path / "ok").ok


# --------------------------------------------------------------------------- malformed metadata
@pytest.mark.parametrize(("mutate", "says"), [
    (lambda t: b"\x00\xff\xfe\x89binary" + t, "not UTF-8 text"),
    (lambda t: t.replace(b"custom_data:", b"custom_data: [a, b]\n  old_custom_data:"), "custom_data is a list"),
    (lambda t: b"[1, 2]\n", "no 'rosbag2_bagfile_information' mapping"),
    (lambda t: t.replace(b"relative_file_paths:", b"relative_file_paths: 7\n  x:"), "relative_file_paths is a int"),
    (lambda t: t + b"\n  : [unclosed\n", "not valid YAML"),
])
def test_malformed_metadata_is_one_line_error(tmp_path: Path, mutate, says, capsys):
    bag = tmp_path / "m"
    _bag_with_chunks(bag, "zstd")
    meta = bag / "metadata.yaml"
    meta.write_bytes(mutate(meta.read_bytes()))
    with pytest.raises(BagError) as e:
        BagReader(bag)
    assert says in str(e.value) and "\n" not in str(e.value) and str(meta) in str(e.value)
    assert main_check([str(bag)]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and out.startswith("error: ") and "Traceback" not in out

