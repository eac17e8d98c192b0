"""``recorder``: every topic of the contract into a rosbag2 MCAP bag (no ROS needed).

Subscriptions deliver the CDR bytes as received (no decode); the
:class:`~dem_ros.bag.Recorder` writes them on its own thread and counts
received / written / dropped per topic. The run's metadata (configuration,
scenario, controller, transport, version) goes into the bag and onto the
latched ``/dem/run_info`` topic. SIGINT / SIGTERM finalise the bag.

Usage: ``dem-ros node recorder --bag DIR [--meta FILE.json] [--ros-args ...]``
(``ros2 run dem_ros recorder --bag DIR`` under ROS).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from .. import __version__, contract, runstate
from ..bag import Recorder
from ..realtime import ENV as RT_ENV
from ..transport import Node, run_node, serialize
from .common import Diagnostics

__all__ = ["RecorderNode", "main", "parse_recorder_args"]

#: reader history of the recorder's subscriptions (samples per topic; 3 s at 1 kHz): as deep as the 1 kHz
#: streams' writers (contract.QOS_STREAM.writer_depth), so that what they resend after a stall of this
#: process is not pushed out of the reader's history before this node's thread takes it
RECORDER_DEPTH = 3000
#: a recorder process's DEM_ROS_RT_PRIORITY unless set: 0, off the loop's path (normal scheduling at nice -10,
#: dem_ros.realtime): at SCHED_FIFO its ~20 % of a core came out of the CPUs' real-time budget, which one process
#: per node on the rig then overran (the kernel stopped every real-time thread for up to 50 ms)
RECORDER_PRIORITY = 0


class RecorderNode:
    """Subscribes to every contract topic (raw CDR) and writes them to ``bag``."""

    def __init__(self, node: Node, bag: Path, meta: dict):
        self.node = node
        meta = dict(meta)
        meta.setdefault("transport", node.transport)
        topics = list(contract.TOPICS)
        # a deeper reader history than the contract's: a recorder stalled for a while (a busy host)
        # must not lose a burst of samples that its history would otherwise overwrite
        deep = [replace(t, qos=replace(t.qos, depth=max(t.qos.depth, RECORDER_DEPTH))) for t in topics]
        # /diagnostics (status "recorder: bag") once a second: received / written / dropped, WARN when samples
        # were dropped. A write failure (disk full) stops recording: logged at once from the writer thread,
        # latched as ERROR and published by a timer on the node's own thread within 0.1 s
        self._failure: str | None = None
        self.diag = Diagnostics(node, contract.RECORDER_STATUS, warn_on=("dropped", "plant_samples_lost"),
                                values=self._totals)
        node.timer(0.1, self._report_failure)
        # the controller's state is the last message of a loop cycle: write while the loop sleeps
        self.rec = Recorder(bag, topics, meta, kick_on=contract.CONTROLLER_STATE.name, on_error=self._on_error)
        now = node.now_ns
        if node.intra_process:
            # sharing the process with the loop: take the message objects (no copy) and let the
            # writer thread serialize them, so the loop's thread does no recording work
            on_object = self.rec.on_object

            def objects_of(name: str) -> Callable[[Any], object]:
                return lambda msg: on_object(name, now(), msg, serialize)

            for t in deep:
                node.subscribe(t, objects_of(t.name))
        else:
            on_message = self.rec.on_message

            def bytes_of(name: str) -> Callable[[bytes], object]:
                return lambda data: on_message(name, now(), data)

            for t in deep:
                node.subscribe_raw(t, bytes_of(t.name))
        String = node.msg("std_msgs/msg/String")
        info = String()
        info.data = json.dumps(meta)
        node.publisher(contract.RUN_INFO).publish(info)
        node.logger.info(f"recording {len(topics)} topics to {bag}")
        node.logger.info("ready")

    def _on_error(self, reason: str) -> None:  # writer thread: log only, publishing is the node thread's
        self._failure = reason
        self.node.logger.error(f"recording stopped: {reason}")

    def _totals(self) -> dict[str, int]:
        counts = self.rec.counters().values()
        c_meas = self.rec.counters().get(contract.MEASUREMENT.name)
        return {"received": sum(c.received for c in counts), "written": sum(c.written for c in counts),
                "dropped": sum(c.dropped for c in counts),
                # the plant's samples the bag lacks (the /dem/measurement stamp grid), however they went missing
                "plant_samples_lost": c_meas.lost if c_meas is not None else 0}

    def _report_failure(self) -> None:
        if self._failure is not None:
            self.diag.fault(f"recording stopped: {self._failure}")

    def close(self) -> dict:
        """Finalise the bag; per-topic counters, also printed as a ``RECORDER {json}`` line and told to a launcher
        (its run-state event ``recorded``: :mod:`dem_ros.runstate`)."""
        counters = self.rec.close()
        summary = {name: {"received": c.received, "written": c.written, "dropped": c.dropped,
                          **({"lost": c.lost} if name in self.rec.grids else {})}
                   for name, c in counters.items()}
        print("RECORDER " + json.dumps(summary), flush=True)
        if self.rec.failure is not None:
            print(f"RECORDER_FAILED {self.rec.failure}", flush=True)
        runstate.announce("recorded", "recorder", counts=summary, failure=self.rec.failure)
        return summary


def parse_recorder_args(p: argparse.ArgumentParser, argv: list[str]) -> tuple[argparse.Namespace, dict]:
    """``--bag DIR [--meta FILE]`` (added to ``p``) -> (args, metadata); exits 2 on a bad bag path."""
    p.add_argument("--bag", required=p.prog == "recorder", help="bag directory to create")
    p.add_argument("--meta", default=None, help="JSON file with the run's metadata")
    a = p.parse_args(argv)
    meta = {"dem_ros_version": __version__}
    if a.bag is not None:
        if Path(a.bag).exists():
            p.exit(2, f"error: {p.prog}: {a.bag} exists; choose a new bag directory\n")
        if a.meta:
            try:
                meta.update(json.loads(Path(a.meta).read_text()))
            except (OSError, ValueError) as exc:
                p.exit(2, f"error: {p.prog}: --meta {a.meta}: {exc}\n")
    return a, meta


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        return argv[:i], argv[i:]
    return argv, []


def main(args=None) -> int:
    # a process of its own: not on the loop's path, so below the loop's nodes (RECORDER_PRIORITY)
    own_priority = RT_ENV["priority"] not in os.environ
    if own_priority:
        os.environ[RT_ENV["priority"]] = str(RECORDER_PRIORITY)
    argv, ros_args = split_ros_args(list(sys.argv[1:] if args is None else args))
    p = argparse.ArgumentParser(prog="recorder", description="record the dem_ros graph to a rosbag2 MCAP bag")
    p.add_argument("--transport", default="auto", choices=["auto", "rclpy", "dds"])
    a, meta = parse_recorder_args(p, argv)
    rec: list[RecorderNode] = []
    try:
        code = run_node("recorder", lambda node: rec.append(RecorderNode(node, Path(a.bag), meta)),
                        args=ros_args, transport=a.transport)
    finally:
        if own_priority:
            del os.environ[RT_ENV["priority"]]
    if rec:
        rec[0].close()
    return code


if __name__ == "__main__":
    sys.exit(main())
