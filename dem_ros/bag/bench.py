"""Recording throughput benchmark: ``bench_record(seconds)``.

Two measurements on JointState-sized messages (~150 B CDR):

* unpaced: :class:`BagWriter` writes as fast as it can -> ``msgs_per_s``,
  ``mb_per_s`` (CDR payload), and ``cpu_percent_at_load``: the share of one
  core that the target load (``topics`` x ``rate_hz``) would cost at that speed;
* paced, in real time: a :class:`Recorder` is fed ``topics`` x ``rate_hz``
  messages against absolute 1 ms deadlines for ``seconds``; ``cpu_percent`` is
  the process CPU time (all threads, including the feeding loop) over wall
  time, i.e. an upper bound for the recorder's cost.
"""

from __future__ import annotations

import struct
import tempfile
import time
from pathlib import Path
from typing import Any

from dem_ros.contract import QOS_STREAM, Topic
from dem_ros.transport.dds.fastcdr import joint_state_bytes  # middleware-free: the one JointState codec

from .recorder import Recorder
from .writer import BagWriter

__all__ = ["bench_record"]


def _payloads(topics: int) -> list[bytearray]:
    names = ["magnet_1", "magnet_2", "y_1", "y_2", "dy_1", "dy_2"]
    return [bytearray(joint_state_bytes(0, 0, "", names, [0.01 * i] * 6, [0.0] * 2, [1.0] * 2)) for i in range(topics)]


def bench_record(seconds: float = 5.0, *, topics: int = 7, rate_hz: float = 1000.0,
                 compression: str = "zstd", unpaced_messages: int = 200_000) -> dict[str, Any]:
    """Measure recording throughput and CPU cost (see module docstring)."""
    payloads = _payloads(topics)
    size = sum(len(p) for p in payloads) / topics
    stamp = struct.Struct("<iI")
    out: dict[str, Any] = {"message_bytes": size, "topics": topics, "rate_hz": rate_hz}
    with tempfile.TemporaryDirectory(prefix="dem_ros_bench_") as tmp:
        # unpaced
        names = [f"/bench/js_{i}" for i in range(topics)]
        w = BagWriter(Path(tmp) / "unpaced", compression=compression)
        for n in names:
            w.add_topic(n, "sensor_msgs/msg/JointState", QOS_STREAM)
        c0, t0 = time.process_time(), time.perf_counter()
        for k in range(unpaced_messages):
            i = k % topics
            w.write(names[i], 1_000_000 * k, payloads[i])
        w.close()
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        out["msgs_per_s"] = unpaced_messages / wall
        out["mb_per_s"] = unpaced_messages * size / wall / 1e6
        out["cpu_percent_at_load"] = 100.0 * topics * rate_hz * (cpu / unpaced_messages)
        out["bag_mb_unpaced"] = sum(f.stat().st_size for f in (Path(tmp) / "unpaced").iterdir()) / 1e6

        # paced, real time, through the Recorder
        contract = [Topic(n, "sensor_msgs/msg/JointState", QOS_STREAM, rate_hz, "bench", (), "") for n in names]
        rec = Recorder(Path(tmp) / "paced", contract, {"bench": True}, compression=compression)
        period = 1.0 / rate_hz
        ticks = int(seconds * rate_hz)
        c0, t0 = time.process_time(), time.perf_counter()
        for k in range(ticks):
            deadline = t0 + k * period
            delay = deadline - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            now_ns = time.time_ns()
            for i in range(topics):
                p = payloads[i]
                stamp.pack_into(p, 4, k // int(rate_hz), (k % int(rate_hz)) * int(1e9 / rate_hz))
                rec.on_message(names[i], now_ns, bytes(p))
        wall = time.perf_counter() - t0
        counters = rec.close()
        cpu = time.process_time() - c0
        out["cpu_percent"] = 100.0 * cpu / wall
        out["paced_msgs_per_s"] = ticks * topics / wall
        out["paced_written"] = sum(c.written for c in counters.values())
        out["paced_dropped"] = sum(c.dropped for c in counters.values())
        out["max_queue_depth"] = rec.max_queue_depth
    return out


if __name__ == "__main__":  # pragma: no cover
    import json
    import sys

    print(json.dumps(bench_record(float(sys.argv[1]) if len(sys.argv) > 1 else 5.0), indent=2))
