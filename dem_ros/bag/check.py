"""``dem-ros bag check BAG``: what a bag holds, and what is missing or broken.

:func:`check` never raises for a damaged bag (it reports); it raises
:class:`BagError` only when there is nothing to read at all (missing path,
not an MCAP file).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dem_ros.contract import TOPICS

from .errors import BagError
from .reader import JOINT_STATE, BagReader

__all__ = ["CheckReport", "TopicReport", "check", "main_check", "verify_summary"]

_CONTRACT = {t.name: t for t in TOPICS}
#: A stamp step longer than this many nominal periods counts as a gap.
GAP_FACTOR = 1.5


@dataclass
class TopicReport:
    """One topic: type, counts, time range (log time, ns) and header-stamp gaps."""

    name: str
    type: str
    count: int
    count_metadata: int | None = None
    first_ns: int | None = None
    last_ns: int | None = None
    period_ns: int | None = None
    gaps: int = 0
    missing_samples: int = 0
    largest_gap_ns: int = 0
    largest_gap_at_ns: int | None = None
    backwards: int = 0


@dataclass
class CheckReport:
    """Result of :func:`check`; ``ok`` is False if any problem was found."""

    path: Path
    files: list[str] = field(default_factory=list)
    metadata_yaml: str = "n/a"  # "complete", "provisional", "missing", "n/a" (bare .mcap)
    complete: bool = True
    topics: list[TopicReport] = field(default_factory=list)
    chunks: int = 0
    compression: list[str] = field(default_factory=list)
    start_ns: int | None = None
    end_ns: int | None = None
    message_count: int = 0
    truncation: str | None = None
    run_metadata: dict[str, Any] | None = None
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def format(self) -> str:
        """Human-readable text, as ``dem-ros bag check`` prints it."""
        lines = [f"bag:          {self.path}"]
        lines.append(f"files:        {', '.join(self.files) or '-'}")
        lines.append(f"metadata.yaml: {self.metadata_yaml}")
        lines.append(f"summary:      {'present' if self.complete else 'MISSING (file truncated)'}")
        lines.append(f"chunks:       {self.chunks} ({', '.join(self.compression) or 'none'})")
        if self.start_ns is not None and self.end_ns is not None:
            lines.append(f"time range:   {_ts(self.start_ns)} .. {_ts(self.end_ns)} "
                         f"({(self.end_ns - self.start_ns) / 1e9:.3f} s)")
        lines.append(f"messages:     {self.message_count}")
        if self.run_metadata is not None:
            keys = ", ".join(f"{k}={self.run_metadata[k]}" for k in
                             ("scenario", "controller", "transport", "version") if k in self.run_metadata)
            lines.append(f"run metadata: present{' (' + keys + ')' if keys else ''}")
        else:
            lines.append("run metadata: none")
        lines.append("topics:")
        w = max([len(t.name) for t in self.topics] + [5])
        for t in self.topics:
            meta = ("" if t.count_metadata is None or t.count_metadata == t.count
                    else f" (metadata.yaml: {t.count_metadata})")
            rate = ""
            if t.first_ns is not None and t.last_ns is not None and t.count > 1 and t.last_ns > t.first_ns:
                rate = f"  {(t.count - 1) / ((t.last_ns - t.first_ns) / 1e9):8.1f} Hz"
            gaps = f"  gaps: {t.gaps} ({t.missing_samples} samples missing)" if t.gaps else ""
            lines.append(f"  {t.name:<{w}}  {t.type:<38} {t.count:>9}{meta}{rate}{gaps}")
        if self.truncation:
            lines.append(f"TRUNCATED:    {self.truncation}")
        for p in self.problems:
            lines.append(f"PROBLEM: {p}")
        for wmsg in self.warnings:
            lines.append(f"warning: {wmsg}")
        lines.append("result:       " + ("OK" if self.ok else f"{len(self.problems)} problem(s)"))
        return "\n".join(lines)


def _ts(ns: int) -> str:
    t = _dt.datetime.fromtimestamp(ns / 1e9, tz=_dt.timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def check(path: Path | str) -> CheckReport:
    """Inspect a bag directory or ``.mcap`` file.

    Raises:
        BagError: nothing readable at ``path`` (missing, not MCAP).
    """
    path = Path(path)
    rep = CheckReport(path)
    if path.is_dir() and not (path / "metadata.yaml").exists():
        rep.metadata_yaml = "missing"
        rep.problems.append("metadata.yaml is missing: `ros2 bag info/play` will not open the directory "
                            "(open the .mcap file directly, or rewrite the bag)")
    with BagReader(path) as r:
        rep.files = [str(f.relative_to(path)) if path.is_dir() else f.name for f in r.files]
        md = r.metadata_yaml
        status = ""
        if md is not None:
            cd0 = md.get("custom_data") or {}
            status = str(cd0.get("dem_ros.status"))
            rep.metadata_yaml = {"recording": "provisional (writer did not close)",
                                 "failed": "final, recording FAILED"}.get(status, "complete")
            if status == "recording":
                rep.problems.append("metadata.yaml is provisional: the writer was killed before close()")
            elif status == "failed":
                rep.problems.append(f"recording stopped early: {cd0.get('dem_ros.failure', 'reason not recorded')}")
        if path.is_dir() and any(path.glob(".*.reserve")):
            rep.warnings.append("a space-reserve file is left in the bag directory (the writer did not close); "
                                "it holds no data and may be deleted")
        rep.problems.extend(r.verify_chunks())  # bad chunks named; the rest of the bag is still read
        for f in r.files:
            if f.suffix == ".mcap":
                rep.problems.extend(verify_summary(f))
        topics = r.topics
        rep.chunks = len(r.chunks)
        rep.compression = sorted({c.compression or "none" for c in r.chunks})
        rep.complete = all(m.has_summary for m in r.mcap_files)
        for m in r.mcap_files:
            if m.truncation is not None:
                last = m.chunks[-1] if m.chunks else None
                n_ok = sum(sum(c.counts.values()) for c in m.chunks) + len(m.loose_messages)
                where = (f"after chunk {len(m.chunks)} at t={_ts(last.end_ns)} ({last.end_ns} ns)"
                         if last else "before the first complete chunk")
                rep.truncation = (f"{m.path.name} truncated {where}, {n_ok} messages recoverable; "
                                  f"{m.file_size_unread()} bytes from offset {m.truncation.offset} unreadable "
                                  f"({m.truncation.reason})")
                rep.problems.append(rep.truncation)
            elif not m.has_summary:
                rep.warnings.append(f"{m.path.name} has a footer but no usable summary (read by scanning)")
        md_counts: dict[str, int] = {}
        if md is not None:
            for t in md.get("topics_with_message_count") or []:
                md_counts[t["topic_metadata"]["name"]] = int(t["message_count"])
        # per-topic time range and stamp gaps
        first: dict[str, int] = {}
        last_t: dict[str, int] = {}
        for topic, lt, _pt, _d in r.raw_messages():
            if topic not in first:
                first[topic] = lt
            last_t[topic] = lt
        for name, info in topics.items():
            tr = TopicReport(name, info.type, info.count, md_counts.get(name),
                             first.get(name), last_t.get(name))
            if tr.count_metadata is not None and tr.count_metadata != tr.count and status != "recording":
                # (a provisional metadata.yaml has the counts of its writing, not the file's: said above)
                rep.problems.append(f"{name}: metadata.yaml says {tr.count_metadata} messages, "
                                    f"the MCAP holds {tr.count}")
            if info.type == JOINT_STATE and info.count > 2:
                _gaps(r, tr, rep)
            rep.topics.append(tr)
        for name in md_counts.keys() - topics.keys():
            rep.problems.append(f"{name}: listed in metadata.yaml but has no channel in the MCAP")
        if not set(topics) & set(_CONTRACT):
            rep.problems.append("none of the dem_ros contract topics is in this bag "
                                f"(found {sorted(topics) or 'no topics'})")
        rep.message_count = sum(t.count for t in rep.topics)
        starts = [v for v in first.values()]
        ends = [v for v in last_t.values()]
        rep.start_ns = min(starts) if starts else None
        rep.end_ns = max(ends) if ends else None
        try:
            rep.run_metadata = r.run_metadata()
        except BagError as exc:
            rep.warnings.append(f"run metadata unreadable: {exc}")
        cd = (md or {}).get("custom_data") or {}
        if "dem_ros.recorder_counters" in cd:
            try:
                counters = json.loads(cd["dem_ros.recorder_counters"])
                for name, c in counters.items():
                    if c.get("dropped"):
                        rep.warnings.append(f"{name}: recorder dropped {c['dropped']} of {c['received']} messages")
            except (ValueError, AttributeError):
                rep.warnings.append("custom_data dem_ros.recorder_counters is not valid JSON")
    return rep


_MAGIC = b"\x89MCAP0\r\n"
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_CHUNK_INDEX, _OP_FOOTER = 0x06, 0x07, 0x08, 0x02


def verify_summary(path: Path) -> list[str]:
    """The problems of an MCAP file's summary section: its CRC (the footer's ``summary_crc``: CRC32 of the summary
    section through the footer's ``summary_offset_start``, MCAP spec) and its chunk index (each ``ChunkIndex``
    must point at a ``Chunk`` record of its length, times, compression and sizes, and at ``MessageIndex`` records
    of its channels). A file without footer or summary has nothing to verify here (the truncation is reported
    elsewhere)."""
    import struct
    import zlib

    data = path.read_bytes()
    name = path.name
    footer_at = len(data) - len(_MAGIC) - 29  # opcode, u64 length, summary_start, summary_offset_start, crc
    if footer_at < len(_MAGIC) or data[-len(_MAGIC):] != _MAGIC or data[footer_at] != _OP_FOOTER:
        return []
    summary_start, offset_start, crc = struct.unpack_from("<QQI", data, footer_at + 9)
    if summary_start == 0:
        return []
    problems: list[str] = []
    if not len(_MAGIC) <= summary_start <= footer_at:
        return [f"{name}: the footer's summary_start {summary_start} is outside the file"]
    if crc:
        computed = zlib.crc32(data[summary_start:footer_at + 9 + 16])
        if computed != crc:
            problems.append(f"{name}: summary section damaged (summary CRC {crc}, computed {computed})")
    end = offset_start if offset_start else footer_at
    pos, n_index = summary_start, 0
    while pos + 9 <= end:
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        body = data[pos + 9:pos + 9 + length]
        if pos + 9 + length > end:
            problems.append(f"{name}: summary record at {pos} runs past the summary section")
            break
        if op == _OP_CHUNK_INDEX:
            n_index += 1
            problems.extend(_verify_chunk_index(data, body, f"{name}: chunk index {n_index}"))
        pos += 9 + length
    return problems


def _verify_chunk_index(data: bytes, body: bytes, what: str) -> list[str]:
    import struct

    try:
        t0, t1, start, length = struct.unpack_from("<QQQQ", body, 0)
        (map_len,) = struct.unpack_from("<I", body, 32)
        entries = [struct.unpack_from("<HQ", body, 36 + i) for i in range(0, map_len, 10)]
        off = 36 + map_len
        _mi_len, comp_len = struct.unpack_from("<QI", body, off)
        compression = body[off + 12:off + 12 + comp_len].decode()
        csize, usize = struct.unpack_from("<QQ", body, off + 12 + comp_len)
    except (struct.error, UnicodeDecodeError) as exc:
        return [f"{what}: unreadable ({exc})"]
    if start + 9 > len(data) or data[start] != _OP_CHUNK:
        return [f"{what}: no chunk at offset {start}"]
    (clen,) = struct.unpack_from("<Q", data, start + 1)
    if clen + 9 != length:
        return [f"{what}: chunk at {start} is {clen + 9} bytes, the index says {length}"]
    ct0, ct1, cusize, _ucrc, ccomp_len = struct.unpack_from("<QQQII", data, start + 9)
    ccomp = data[start + 41:start + 41 + ccomp_len].decode(errors="replace")
    (crec,) = struct.unpack_from("<Q", data, start + 41 + ccomp_len)
    problems = []
    if (ct0, ct1) != (t0, t1):
        problems.append(f"{what}: times {t0}..{t1} ns, the chunk at {start} says {ct0}..{ct1}")
    if ccomp != compression or crec != csize or cusize != usize:
        problems.append(f"{what}: compression/sizes {compression!r} {csize}/{usize}, the chunk at {start} says "
                        f"{ccomp!r} {crec}/{cusize}")
    for channel, mi in entries:
        if mi + 11 > len(data) or data[mi] != _OP_MESSAGE_INDEX or struct.unpack_from("<H", data, mi + 9)[0] != channel:
            problems.append(f"{what}: no message index of channel {channel} at offset {mi}")
            break
    return problems


def _gaps(r: BagReader, tr: TopicReport, rep: CheckReport) -> None:
    """Count header-stamp gaps of a JointState topic against its nominal rate."""
    try:
        stamps = r.joint_state_arrays(tr.name)["stamp_ns"]
    except BagError as exc:
        rep.warnings.append(f"{tr.name}: cannot extract stamps ({exc})")
        return
    d = np.diff(stamps)
    contract = _CONTRACT.get(tr.name)
    if contract is not None and contract.rate_hz:
        period = round(1e9 / contract.rate_hz)
    else:
        pos = d[d > 0]
        if not len(pos):
            return
        period = int(np.median(pos))
    tr.period_ns = period
    tr.backwards = int((d <= 0).sum())
    big = d > GAP_FACTOR * period
    tr.gaps = int(big.sum())
    if tr.gaps:
        tr.missing_samples = int((np.rint(d[big] / period) - 1).sum())
        i = int(np.argmax(d))
        tr.largest_gap_ns = int(d[i])
        tr.largest_gap_at_ns = int(stamps[i])
        rep.warnings.append(
            f"{tr.name}: {tr.gaps} gap(s) in {1e9 / period:g} Hz header stamps, ~{tr.missing_samples} samples "
            f"missing; largest {tr.largest_gap_ns / 1e6:.1f} ms after stamp {tr.largest_gap_at_ns} ns")
    if tr.backwards:
        rep.warnings.append(f"{tr.name}: header stamp does not increase {tr.backwards} time(s)")


def main_check(argv: Sequence[str] | None = None) -> int:
    """CLI body of ``dem-ros bag check BAG``: prints the report.

    Returns 0 if the bag is fine, 1 if it has problems, 2 if it cannot be read.
    """
    ap = argparse.ArgumentParser(prog="dem-ros bag check", description=__doc__.splitlines()[0])
    ap.add_argument("bag", help="bag directory or .mcap file")
    args = ap.parse_args(argv)
    try:
        rep = check(args.bag)
    except BagError as exc:
        print(f"error: {exc}")
        return 2
    print(rep.format())
    return 0 if rep.ok else 1
