"""Read rosbag2 MCAP bags: ours, or ``ros2 bag record -s mcap`` ones.

``BagReader(path)`` accepts a bag directory (``metadata.yaml`` + ``*.mcap``,
or just ``*.mcap`` files) or a bare ``.mcap`` file. Messages are decoded with
rosbags' typestore, so no ROS install is needed; types unknown to the store
are registered from the schema text stored in the bag.

A file whose writer was killed (no footer/summary) is read up to its last
complete chunk; :attr:`BagReader.truncated` then says where it stops.
"""

from __future__ import annotations

import functools
import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from dem_ros import typestore
from dem_ros.contract import QoS
from dem_ros.core.params import ConfigError, read_yaml

from . import _rosfmt
from ._mcap import McapFile, Truncation
from .errors import BagError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = ["JOINT_STATE", "BagReader", "TopicInfo", "read_metadata_yaml"]

JOINT_STATE = "sensor_msgs/msg/JointState"


@dataclass
class TopicInfo:
    """A topic in the bag: ROS type, message count, offered QoS."""

    name: str
    type: str
    count: int
    qos: list[QoS] = field(default_factory=list)
    message_encoding: str = "cdr"


class BagReader:
    """Read a bag directory or a bare ``.mcap`` file.

    Raises:
        BagError: missing path, no MCAP in the directory, not an MCAP file,
            malformed metadata.yaml.
    """

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path} does not exist")
        self.metadata_yaml: dict[str, Any] | None = None
        if self.path.is_dir():
            self.files = self._files_of_dir()
        else:
            self.files = [self.path]
        self._mcaps: list[McapFile] = []
        try:
            for f in self.files:
                self._mcaps.append(McapFile(f))
        except BagError:
            self.close()
            raise
        for m in self._mcaps:
            if m.profile != "ros2" and not any(c.message_encoding == "cdr" for c in m.channels.values()):
                self.close()
                raise BagError(
                    f"{m.path} is an MCAP file but not a ROS 2 one "
                    f"(profile {m.profile!r}, no 'cdr' channels)"
                )
        self._store: Typestore | None = None

    def _files_of_dir(self) -> list[Path]:
        meta = self.path / "metadata.yaml"
        if meta.exists():
            self.metadata_yaml = read_metadata_yaml(meta)
            sid = self.metadata_yaml.get("storage_identifier")
            if sid != "mcap":
                raise BagError(f"{self.path} uses storage {sid!r}; only 'mcap' bags are supported")
            files = [self.path / p for p in self.metadata_yaml.get("relative_file_paths", [])]
            missing = [str(p) for p in files if not p.exists()]
            if missing:
                raise BagError(f"{self.path}: metadata.yaml lists missing file(s) {missing}")
            if files:
                return files
        files = sorted(self.path.glob("*.mcap"))
        if not files:
            raise BagError(f"{self.path} is a directory without metadata.yaml or any .mcap file")
        return files

    # -- summary ---------------------------------------------------------
    @property
    def truncated(self) -> Truncation | None:
        """Where the (first) incomplete file stops, or None if all are complete."""
        for m in self._mcaps:
            if m.truncation is not None:
                return m.truncation
        return None

    @functools.cached_property
    def topics(self) -> dict[str, TopicInfo]:
        """Topic name -> :class:`TopicInfo` (counts from statistics, or by scan); read once per reader (each
        channel's QoS is YAML: reading a run's five series asked for it 23 times, 30 s on a loaded machine)."""
        out: dict[str, TopicInfo] = {}
        for m in self._mcaps:
            counts = self._counts(m)
            for ch in m.channels.values():
                schema = m.schemas.get(ch.schema_id)
                ti = out.get(ch.topic)
                if ti is None:
                    qos = _rosfmt.qos_from_string(ch.metadata.get("offered_qos_profiles", ""))
                    ti = out[ch.topic] = TopicInfo(ch.topic, schema.name if schema else "", 0, qos,
                                                   ch.message_encoding)
                ti.count += counts.get(ch.id, 0)
        return out

    @staticmethod
    def _counts(m: McapFile) -> dict[int, int]:
        if m.statistics is not None:
            return dict(m.statistics.channel_message_counts)
        counts: dict[int, int] = {}
        for ch in m.chunks:
            for cid, n in ch.counts.items():
                counts[cid] = counts.get(cid, 0) + n
        for cid in m.loose_channel_ids():
            counts[cid] = counts.get(cid, 0) + 1
        return counts

    def verify_chunks(self) -> list[str]:
        """Decompress and CRC-check every chunk of every file; one line per bad chunk (empty: all good).

        Afterwards the reported chunks are skipped when messages are read;
        before, reading a bad chunk raises :class:`BagError` naming it.
        """
        return [p for m in self._mcaps for p in m.verify_chunks()]

    @property
    def chunks(self) -> list[Any]:
        return [c for m in self._mcaps for c in m.chunks]

    @property
    def mcap_files(self) -> list[McapFile]:
        return list(self._mcaps)

    # -- messages --------------------------------------------------------
    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, int, memoryview]]:
        """Yield ``(topic, log_time_ns, publish_time_ns, cdr_bytes)`` in file order."""
        wanted = None if topics is None else set([topics] if isinstance(topics, str) else topics)
        if wanted is not None:
            unknown = wanted - self.topics.keys()
            if unknown:
                raise BagError(f"topic(s) {sorted(unknown)} not in {self.path}; "
                               f"it has {sorted(self.topics)}")
        for m in self._mcaps:
            ids = {c.id: c.topic for c in m.channels.values() if wanted is None or c.topic in wanted}
            for cid, lt, pt, data in m.iter_raw(set(ids)):
                yield ids[cid], lt, pt, data

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, Any]]:
        """Yield ``(topic, log_time_ns, msg)`` decoded with rosbags' typestore."""
        types = {name: t.type for name, t in self.topics.items()}
        for name, t in self.topics.items():
            if t.message_encoding != "cdr" and (topics is None or name in set(topics)):
                raise BagError(f"topic {name!r} has encoding {t.message_encoding!r}, not 'cdr'")
        store = self._typestore()
        for topic, lt, _pt, data in self.raw_messages(topics):
            try:
                msg = store.deserialize_cdr(data, types[topic])
            except Exception as exc:  # rosbags raises assorted errors on bad CDR
                raise BagError(f"{self.path}: cannot decode a {types[topic]} message on {topic} "
                               f"at t={lt} ns: {exc}") from None
            yield topic, lt, msg

    def _typestore(self) -> Typestore:
        """The one typestore's types plus any type defined only in this bag's ``ros2msg`` schemas."""
        if self._store is None:
            self._store = typestore.extended(
                (sc.name, sc.data.decode("utf-8")) for m in self._mcaps for sc in m.schemas.values()
                if sc.encoding == "ros2msg")
        return self._store

    # -- run metadata ----------------------------------------------------
    def run_metadata(self) -> dict[str, Any] | None:
        """The run configuration recorded with the bag, or None.

        Looked up in order: metadata.yaml ``custom_data["dem_ros.run_info"]``,
        the MCAP ``rosbag2`` record's custom_data, the MCAP ``dem_ros`` record,
        the last message on ``/dem/run_info`` (std_msgs/String holding JSON).
        """
        sources: list[dict[str, str]] = []
        if self.metadata_yaml and isinstance(self.metadata_yaml.get("custom_data"), dict):
            sources.append(self.metadata_yaml["custom_data"])
        for m in self._mcaps:
            for name, rec in reversed(m.metadata):
                if name == "rosbag2" and "serialized_metadata" in rec:
                    try:
                        cd = (yaml.safe_load(rec["serialized_metadata"]) or {}).get("custom_data")
                    except yaml.YAMLError:
                        cd = None
                    if isinstance(cd, dict):
                        sources.append(cd)
                elif name == "dem_ros":
                    sources.append(rec)
        for src in sources:
            if "dem_ros.run_info" in src:
                return self._json(src["dem_ros.run_info"], "custom_data dem_ros.run_info")
        if "/dem/run_info" in self.topics and self.topics["/dem/run_info"].count:
            last = None
            for _t, _lt, msg in self.messages(["/dem/run_info"]):
                last = msg
            if last is not None:
                return self._json(last.data, "/dem/run_info")
        return None

    def _json(self, text: str, where: str) -> dict[str, Any]:
        try:
            out = json.loads(text)
        except ValueError as exc:
            raise BagError(f"{self.path}: {where} is not JSON: {exc}") from None
        if not isinstance(out, dict):
            raise BagError(f"{self.path}: {where} is JSON but not an object")
        return out

    # -- numpy -----------------------------------------------------------
    def joint_state_arrays(self, topic: str) -> dict[str, Any]:
        """All ``sensor_msgs/JointState`` messages of ``topic`` as arrays.

        Returns:
            dict with ``stamp_ns`` (N,) int64 header stamps [ns],
            ``log_time_ns`` (N,) int64 receive times [ns], ``name`` list[str]
            (k), ``position`` (N, k), ``velocity`` (N, kv), ``effort`` (N, ke)
            float64 (kv, ke may be 0). Rows whose array length differs from
            the first message's are NaN-padded / truncated to that width;
            ``skipped``: messages left out because they are not a JointState or
            name other joints than the topic's (a foreign or corrupt writer).

        Raises:
            BagError: topic missing, not JointState, or no message parses.
        """
        info = self.topics.get(topic)
        if info is None:
            raise BagError(f"topic {topic!r} not in {self.path}; it has {sorted(self.topics)}")
        if info.type != JOINT_STATE:
            raise BagError(f"topic {topic!r} is {info.type}, not {JOINT_STATE}")
        datas: list[bytes] = []
        log = []
        for _t, lt, _pt, data in self.raw_messages([topic]):
            datas.append(bytes(data))
            log.append(lt)
        return _joint_state_arrays(datas, np.asarray(log, dtype=np.int64), topic)

    # -- closing ---------------------------------------------------------
    def close(self) -> None:
        for m in self._mcaps:
            m.close()
        self._mcaps = []

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


# --------------------------------------------------------------------------
def _bad(path: Path, what: str) -> BagError:
    return BagError(f"{path} is not rosbag2 metadata: {what}")


def read_metadata_yaml(path: Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a metadata.yaml, with the fields dem_ros uses type-checked.

    Raises:
        BagError: one line naming the file and what is wrong (unreadable, not
            UTF-8, not YAML, a key repeated, a field of the wrong type).
    """
    try:
        doc = read_yaml(path)
    except ConfigError as exc:  # unreadable, not UTF-8, not YAML (or a key repeated): "<path>: <what>"
        reason = str(exc).removeprefix(f"{path}: ")
        raise (BagError(str(exc)) if reason.startswith("cannot read") else _bad(path, reason)) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("rosbag2_bagfile_information"), dict):
        raise _bad(path, "no 'rosbag2_bagfile_information' mapping at the top")
    info: dict[str, Any] = doc["rosbag2_bagfile_information"]
    checks: list[tuple[str, Any, tuple[type, ...]]] = [
        ("storage_identifier", info.get("storage_identifier"), (str,)),
        ("relative_file_paths", info.get("relative_file_paths", []), (list,)),
        ("topics_with_message_count", info.get("topics_with_message_count", []), (list, type(None))),
        ("custom_data", info.get("custom_data", {}), (dict, type(None))),
    ]
    for name, value, types in checks:
        if not isinstance(value, types):
            raise _bad(path, f"{name} is a {type(value).__name__}, expected "
                             + " or ".join("null" if t is type(None) else t.__name__ for t in types))
    for i, p in enumerate(info.get("relative_file_paths", [])):
        if not isinstance(p, str) or not p or Path(p).is_absolute() or ".." in Path(p).parts:
            raise _bad(path, f"relative_file_paths[{i}] = {p!r} is not a file name inside the bag")
    for k, v in (info.get("custom_data") or {}).items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise _bad(path, f"custom_data entry {k!r}: {v!r} is not a string pair")
    for i, t in enumerate(info.get("topics_with_message_count") or []):
        tm = t.get("topic_metadata") if isinstance(t, dict) else None
        if not isinstance(tm, dict) or not isinstance(tm.get("name"), str) \
                or isinstance(t.get("message_count"), bool) or not isinstance(t.get("message_count"), int):
            raise _bad(path, f"topics_with_message_count[{i}] needs topic_metadata.name (string) "
                             "and message_count (integer)")
    return info


# --------------------------------------------------------------------------
# JointState CDR layout (XCDR1, little endian; offsets relative to byte 4,
# after the encapsulation header): int32 sec, uint32 nanosec, string frame_id,
# sequence<string> name, then three sequence<float64> (count aligned to 4,
# doubles aligned to 8).
_U32 = struct.Struct("<I")


def _layout(d: bytes) -> tuple[list[str], list[tuple[int, int]]]:
    """Names and (byte offset, count) of position, velocity, effort in one message."""
    if len(d) < 16 or d[1] not in (0, 1):
        raise ValueError("too short or not plain CDR")
    if d[1] != 1:
        raise ValueError("big-endian CDR is not supported")
    p = 4 + 8
    (n,) = _U32.unpack_from(d, p)
    p += 4 + n  # frame_id
    p = 4 + ((p - 4 + 3) & ~3)
    (k,) = _U32.unpack_from(d, p)
    p += 4
    names = []
    for _ in range(k):
        p = 4 + ((p - 4 + 3) & ~3)
        (n,) = _U32.unpack_from(d, p)
        names.append(d[p + 4:p + 4 + n - 1].decode("utf-8"))
        p += 4 + n
    arrays = []
    for _ in range(3):
        p = 4 + ((p - 4 + 3) & ~3)
        (n,) = _U32.unpack_from(d, p)
        p += 4
        if n:
            p = 4 + ((p - 4 + 7) & ~7)
        arrays.append((p, n))
        p += 8 * n
    if p > len(d):
        raise ValueError("arrays run past the end of the message")
    return names, arrays


def _joint_state_arrays(datas: list[bytes], log: np.ndarray, topic: str) -> dict[str, Any]:
    n = len(datas)
    empty: dict[str, Any] = dict(stamp_ns=np.zeros(0, np.int64), log_time_ns=log, name=[],
                                 position=np.zeros((0, 0)), velocity=np.zeros((0, 0)), effort=np.zeros((0, 0)))
    if n == 0:
        return empty
    try:
        names, arrays = _layout(datas[0])
    except (ValueError, struct.error, UnicodeDecodeError):
        names, arrays = _common_layout(datas, topic)  # a foreign or corrupt first message: the topic's own
    length = len(datas[0])
    blob = np.frombuffer(b"".join(datas), dtype=np.uint8) if all(len(d) == length for d in datas) else None
    fields = ("position", "velocity", "effort")
    out: dict[str, Any] = {"log_time_ns": log, "name": names, "skipped": 0}
    if blob is not None:
        rows = blob.reshape(n, length)
        # Same size and same bytes outside the stamp and the float payloads => same layout.
        mask = np.ones(length, bool)
        mask[4:12] = False
        for off, cnt in arrays:
            mask[off:off + 8 * cnt] = False
        fixed = rows[:, mask]
        if (fixed == fixed[0]).all():
            sec = rows[:, 4:8].copy().view("<i4")[:, 0].astype(np.int64)
            nsec = rows[:, 8:12].copy().view("<u4")[:, 0].astype(np.int64)
            out["stamp_ns"] = sec * 1_000_000_000 + nsec
            for fname, (off, cnt) in zip(fields, arrays, strict=True):
                out[fname] = rows[:, off:off + 8 * cnt].copy().view("<f8").reshape(n, cnt)
            return out
    # Slow path: per-message parse (layouts differ between messages). A message that is not a JointState
    # or names other joints than the topic's (a foreign or corrupt writer: the bag keeps what was on the
    # wire) is left out and counted in ``skipped``; the first message's names are the topic's unless the
    # first message is itself such a one (then the most common names are).
    stamps = np.empty(n, np.int64)
    cols = {f: np.full((n, cnt), np.nan) for f, (_o, cnt) in zip(fields, arrays, strict=True)}
    keep = np.ones(n, bool)
    for i, d in enumerate(datas):
        try:
            nm, arr = _layout(d)
        except (ValueError, struct.error, UnicodeDecodeError):
            keep[i] = False
            continue
        if nm != names:
            keep[i] = False
            continue
        sec, nsec = struct.unpack_from("<iI", d, 4)
        stamps[i] = sec * 1_000_000_000 + nsec
        for fname, (off, cnt) in zip(fields, arr, strict=True):
            w = min(cnt, cols[fname].shape[1])
            cols[fname][i, :w] = np.frombuffer(d, "<f8", count=w, offset=off)
    out["stamp_ns"] = stamps[keep]
    out["log_time_ns"] = log[keep]
    out.update({f: c[keep] for f, c in cols.items()})
    out["skipped"] = int(n - keep.sum())
    return out


def _common_layout(datas: list[bytes], topic: str) -> tuple[list[str], list[tuple[int, int]]]:
    """The layout of the most common joint names among the messages that parse; BagError if none does."""
    seen: dict[tuple[str, ...], tuple[int, list[tuple[int, int]]]] = {}
    for d in datas:
        try:
            nm, arr = _layout(d)
        except (ValueError, struct.error, UnicodeDecodeError):
            continue
        count, first = seen.get(tuple(nm), (0, arr))
        seen[tuple(nm)] = (count + 1, first)
    if not seen:
        raise BagError(f"{topic}: no message is a valid JointState CDR")
    names = max(seen, key=lambda k: seen[k][0])
    return list(names), seen[names][1]
