"""Shared sample data for the bag tests: one stream per contract topic."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from dem_ros.bag import BagWriter
from dem_ros.contract import TOPICS
from dem_ros.transport.dds.fastcdr import joint_state_bytes

STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types
T0 = 1_700_000_000_000_000_000  # log time origin [ns]
RUN_INFO = {"config": {"plant": {"m": 1.2, "R": 2.5}}, "scenario": "S1", "controller": "mrac",
            "transport": "dds", "version": "0.1.0"}


def stamp(ns: int) -> Any:
    return T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def joint_state(k: int, topic_index: int) -> Any:
    ns = k * 1_000_000
    return T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](stamp=stamp(ns), frame_id=""),
        name=["magnet_1", "magnet_2"],
        position=np.array([0.010 + 1e-6 * k, 0.011 + topic_index * 1e-3]),
        velocity=np.array([] if topic_index == 0 else [1e-3 * k, -1e-3 * k]),
        effort=np.array([1.0 + topic_index, 2.0 + k * 1e-4]),
    )


def joint_state_cdr(names: list[str], position: list[float], velocity: list[float], effort: list[float],
                    stamp_ns: int = 0) -> bytes:
    """CDR bytes of a ``sensor_msgs/msg/JointState`` stamped ``stamp_ns`` [ns], by the package's one codec."""
    return joint_state_bytes(stamp_ns // 10**9, stamp_ns % 10**9, "", names, position, velocity, effort)


def diagnostics(k: int) -> Any:
    kv = T["diagnostic_msgs/msg/KeyValue"](key="cycles", value=str(k))
    st = T["diagnostic_msgs/msg/DiagnosticStatus"](level=0, name="controller", message="ok",
                                                   hardware_id="sim", values=[kv])
    return T["diagnostic_msgs/msg/DiagnosticArray"](
        header=T["std_msgs/msg/Header"](stamp=stamp(k * 10**9), frame_id=""), status=[st])


def param_event(k: int) -> Any:
    pv = T["rcl_interfaces/msg/ParameterValue"](
        type=3, bool_value=False, integer_value=0, double_value=0.5 * k, string_value="",
        byte_array_value=np.array([], np.uint8), bool_array_value=np.array([], bool),
        integer_array_value=np.array([], np.int64), double_array_value=np.array([]), string_array_value=[])
    p = T["rcl_interfaces/msg/Parameter"](name="gain", value=pv)
    return T["rcl_interfaces/msg/ParameterEvent"](stamp=stamp(k), node="/controller", new_parameters=[],
                                                  changed_parameters=[p], deleted_parameters=[])


def string_msg(text: str) -> Any:
    return T["std_msgs/msg/String"](data=text)


def sample_stream(n_fast: int = 600) -> list[tuple[str, int, Any, str]]:
    """(topic, log_time_ns, msg, type) for every contract topic, in log-time order."""
    out = []
    by_name = {t.name: t for t in TOPICS}
    out.append(("/dem/run_info", T0, string_msg(json.dumps(RUN_INFO)), by_name["/dem/run_info"].type))
    fast = [t for t in TOPICS if t.rate_hz == 1000.0]
    for k in range(n_fast):
        for i, t in enumerate(fast):
            out.append((t.name, T0 + k * 1_000_000 + i * 1000 + 1, joint_state(k, i), t.type))
        if k % 200 == 0:
            out.append(("/diagnostics", T0 + k * 1_000_000 + 500_000, diagnostics(k), by_name["/diagnostics"].type))
        if k % 250 == 0:
            out.append(("/parameter_events", T0 + k * 1_000_000 + 600_000, param_event(k),
                        by_name["/parameter_events"].type))
    return out


def write_bag(path: Path, stream: list[tuple[str, int, Any, str]], **kw: Any) -> Path:
    kw.setdefault("chunk_size", 16 * 1024)
    kw.setdefault("metadata", RUN_INFO)
    with BagWriter(path, **kw) as w:
        for t in TOPICS:
            w.add_topic(t.name, t.type, t.qos)
        for topic, lt, msg, typ in stream:
            w.write(topic, lt, bytes(STORE.serialize_cdr(msg, typ)))
    return path


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 192 KiB tmpfs mounted for the test (root only; skipped with the reason otherwise)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=192k", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs to fill (needs root/CAP_SYS_ADMIN): {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


@pytest.fixture(scope="session")
def stream() -> list[tuple[str, int, Any, str]]:
    return sample_stream()


@pytest.fixture(scope="session")
def bag(tmp_path_factory: pytest.TempPathFactory, stream: list[tuple[str, int, Any, str]]) -> Path:
    return write_bag(tmp_path_factory.mktemp("bags") / "roundtrip", stream)
