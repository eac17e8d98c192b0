"""Exit codes say what happened (the verdict, dem_ros.tools.verdict): a failed simulation or run exits 1, a
truncated or degraded recording 3, with the reason on stderr; an intact run exits 0 (the same checks must not flag
a good bag); ``bag check`` / ``bag info`` exit 1 on a bag with problems."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from dem_ros.bag import BagReader, BagWriter
from dem_ros.contract import CONTROLLER_STATE, MEASUREMENT, REFERENCE, TOPICS
from dem_ros.tools.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_S1"


def test_sim_with_the_paper_controller_exits_1_with_the_failure_line(capsys):
    assert main(["sim", "--controller", "paper", "--duration", "0.3"]) == 1
    err = capsys.readouterr().err
    assert "dem-ros sim: FAILED at t = " in err and "rail contact or drop" in err


def test_replay_of_the_intact_sample_bag_exits_0(capsys):
    assert main(["replay", str(SAMPLE)]) == 0
    assert "PROBLEM" not in capsys.readouterr().out


def _copy(tmp_path: Path, skip) -> Path:
    """The sample bag rewritten, without the messages for which ``skip(topic, stamp_ns)`` is true."""
    out = tmp_path / "copy"
    tmp_path.mkdir(parents=True, exist_ok=True)
    with BagReader(SAMPLE) as r:
        meta = r.run_metadata()
        types = {t.name: t for t in TOPICS}
        from dem_ros.transport.dds import fastcdr, msgs

        topics = r.topics  # (a property that parses every channel's QoS: read it once)
        with BagWriter(out, metadata=meta) as w:
            for name, info in topics.items():
                w.add_topic(name, info.type, types[name].qos)
            for topic, lt, pt, data in r.raw_messages():
                if topics[topic].type == "sensor_msgs/msg/JointState":
                    st = fastcdr.decode(msgs.JointState, bytes(data)).header.stamp
                    if skip(topic, st.sec * 10**9 + st.nanosec):
                        continue
                w.write(topic, lt, bytes(data), pt)
    return out


def test_replay_flags_stretches_without_a_reference_as_degraded_exit_3(tmp_path, capsys):
    with BagReader(SAMPLE) as r:
        ref = r.joint_state_arrays(REFERENCE.name)["stamp_ns"]
    cut0, cut1 = ref[len(ref) // 2], ref[len(ref) // 2 + 250]  # 250 samples: the reference node down 0.25 s
    # a reference node down: no reference, and the controller's state says it lacked it (or is absent)
    down = (REFERENCE.name, CONTROLLER_STATE.name)
    bag = _copy(tmp_path, lambda topic, st: topic in down and cut0 <= st < cut1)
    assert main(["replay", str(bag)]) == 3
    out, err = capsys.readouterr()
    assert "250 sample(s) without a reference in 1 stretch(es); longest 250 samples" in out
    assert "recorder lost" not in out and "missing from the bag" not in out
    assert "replay: degraded: 250 sample(s)" in err
    assert out.splitlines()[0].split()[:4] == ["verdict", "degraded:", "250", "sample(s)"]  # the first line


def test_replay_tells_samples_the_recorder_lost_from_a_reference_outage(tmp_path, capsys):
    """A recorder that fell behind the writers' keep-last history loses samples with no trace on its side:
    the bag shows them as holes in the plant's stamps, or as references the controller did receive."""
    with BagReader(SAMPLE) as r:
        ref = r.joint_state_arrays(REFERENCE.name)["stamp_ns"]
    cut0, cut1 = ref[len(ref) // 2], ref[len(ref) // 2 + 250]
    bag = _copy(tmp_path / "a", lambda topic, st: topic == REFERENCE.name and cut0 <= st < cut1)
    assert main(["replay", str(bag)]) == 3
    out, _ = capsys.readouterr()
    assert "the recorder lost 250 reference sample(s) the controller received" in out
    assert "without a reference" not in out
    bag = _copy(tmp_path / "b", lambda topic, st: cut0 <= st < cut0 + 40 * 10**6)  # every topic, 40 ms
    assert main(["replay", str(bag)]) == 3
    out, _ = capsys.readouterr()
    assert "40 plant sample(s) missing from the bag in 1 stretch(es), longest 40 ms (lost by a recorder" in out


def test_replay_flags_a_truncated_bag_as_degraded_exit_3(tmp_path, capsys):
    """The bag ends early because its writer was killed: the record is short; what the run did after is not in
    the bag, so the verdict is degraded (the record), not failed (the run)."""
    bag = tmp_path / "trunc"
    shutil.copytree(SAMPLE, bag)
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.6)])  # writer killed at 60 %
    (bag / "metadata.yaml").unlink()  # as a SIGKILL before the first metadata refresh leaves it
    assert main(["replay", str(bag)]) == 3
    out, err = capsys.readouterr()
    assert "bag truncated" in out and "before the planned end" in out and "of 8 s): the recording stopped" in out
    assert out.startswith("  verdict") and "replay: degraded:" in err


@pytest.mark.parametrize("action", ["info", "check"])
def test_bag_info_and_check_exit_1_with_problems(tmp_path, action, capsys):
    bag = tmp_path / "trunc"
    shutil.copytree(SAMPLE, bag)
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[:-100])
    assert main(["bag", action, str(bag)]) == 1
    assert ("TRUNCATED" if action == "check" else "problem(s): see dem-ros bag check") in capsys.readouterr().out
    assert main(["bag", action, str(SAMPLE)]) == 0


def test_a_foreign_message_in_the_bag_is_left_out_and_reported(tmp_path, capsys):
    """A writer that put a JointState of other joints on /dem/reference (a rogue or corrupt sample: the
    recorder keeps what was on the wire) does not stop the analysis: left out, counted, reported."""
    out = tmp_path / "foreign"
    with BagReader(SAMPLE) as r:
        meta = r.run_metadata()
        types = {t.name: t for t in TOPICS}
        topics = r.topics
        foreign = next(bytes(d) for t, _lt, _pt, d in r.raw_messages([MEASUREMENT.name]))  # magnet_1/2 names
        with BagWriter(out, metadata=meta) as w:
            for name, info in topics.items():
                w.add_topic(name, info.type, types[name].qos)
            n_ref = 0
            for topic, lt, pt, data in r.raw_messages():
                w.write(topic, lt, bytes(data), pt)
                if topic == REFERENCE.name:
                    n_ref += 1
                    if n_ref in (10, 3000):
                        w.write(topic, lt, foreign, pt)
    assert main(["replay", str(out)]) == 3
    o, err = capsys.readouterr()
    assert "2 message(s) on /dem/reference left out: not the topic's JointState layout" in o
    assert "Traceback" not in err


def test_replay_of_a_run_cut_short_is_failed_exit_1_without_figures_past_its_end(tmp_path, capsys):
    """The plant stopped at t = 3 s of the 8 planned (nothing of it after, its status neither) and the bag is
    intact (the recording closed): the run ended early. Failed, with how many of the planned samples it made;
    exit 1; the JSON says the same."""
    import json

    from dem_ros.transport.dds import fastcdr, msgs

    types = {t.name: t for t in TOPICS}
    out = tmp_path / "short"
    with BagReader(SAMPLE) as r:
        epoch = next(int(kv.value) for _, _, m in r.messages(["/diagnostics"]) for st in m.status
                     for kv in st.values if kv.key == "epoch_ns")
        cut = epoch + 3_000 * 10**6
        topics = r.topics
        log_cut = None  # the log time of the plant's first sample at the cut: nothing is logged from then on
        for topic, lt, _, data in r.raw_messages():
            if topics[topic].type == "sensor_msgs/msg/JointState" and log_cut is None:
                st = fastcdr.decode(msgs.JointState, bytes(data)).header.stamp
                if st.sec * 10**9 + st.nanosec >= cut:
                    log_cut = lt
        assert log_cut is not None
        with BagWriter(out, metadata=r.run_metadata()) as w:
            for name, info in topics.items():
                w.add_topic(name, info.type, types[name].qos)
            for topic, lt, pt, data in r.raw_messages():
                if lt < log_cut:
                    w.write(topic, lt, bytes(data), pt)
    js = tmp_path / "run.json"
    assert main(["replay", str(out), "--json", str(js)]) == 1
    text, err = capsys.readouterr()
    first = text.splitlines()[0]
    assert first.split()[:2] == ["verdict", "failed:"] and "of 8000 planned samples" in first, text
    assert "replay: failed:" in err
    d = json.loads(js.read_text())
    assert d["verdict"] == "failed" and any("of 8000 planned samples" in x for x in d["verdict_reasons"])
