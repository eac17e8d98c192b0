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
import sys
from pathlib import Path

from .. import __version__, contract
from ..bag import Recorder
from ..transport import Node, run_node

__all__ = ["main"]


def main(args=None) -> int:
    argv = list(sys.argv[1:] if args is None else args)
    ros_args = []
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        argv, ros_args = argv[:i], argv[i:]
    p = argparse.ArgumentParser(prog="recorder", description="record the dem_ros graph to a rosbag2 MCAP bag")
    p.add_argument("--bag", required=True, help="bag directory to create")
    p.add_argument("--meta", default=None, help="JSON file with the run's metadata")
    p.add_argument("--transport", default="auto", choices=["auto", "rclpy", "dds"])
    a = p.parse_args(argv)
    meta = {"dem_ros_version": __version__}
    if a.meta:
        meta.update(json.loads(Path(a.meta).read_text()))
    bag = Path(a.bag)
    if bag.exists():
        print(f"error: recorder: {bag} exists; choose a new bag directory", file=sys.stderr)
        return 2
    topics = [t for t in contract.TOPICS]
    rec: list[Recorder] = []

    def setup(node: Node) -> None:
        meta.setdefault("transport", node.transport)
        r = Recorder(bag, topics, meta)
        rec.append(r)
        for t in topics:
            node.subscribe_raw(t, lambda data, name=t.name: r.on_message(name, node.now_ns(), data))
        String = node.msg("std_msgs/msg/String")
        info = String()
        info.data = json.dumps(meta)
        pub = node.publisher(contract.RUN_INFO)
        pub.publish(info)
        node.logger.info(f"recording {len(topics)} topics to {bag}")
        node.logger.info("ready")

    code = run_node("recorder", setup, args=ros_args, transport=a.transport)
    if rec:
        counters = rec[0].close()
        summary = {name: {"received": c.received, "written": c.written, "dropped": c.dropped} for name, c in counters.items()}
        print("RECORDER " + json.dumps(summary), flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
