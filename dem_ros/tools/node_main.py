"""Run one node: ``python -m dem_ros.tools.node_main NAME [--transport T] [node args] [--ros-args ...]``.

Every node of :data:`dem_ros.nodes.NODES` is run by its module's ``main(args)``;
the transport is handed over as ``DEM_ROS_TRANSPORT`` (what ``auto`` resolves to).
"""

from __future__ import annotations

import importlib
import os
import sys

from ..nodes import NODES
from ..transport import TRANSPORTS

__all__ = ["main", "run"]


def run(name: str, rest: list[str], transport: str = "auto") -> int:
    if name not in NODES:
        print(f"error: unknown node {name!r}; known: {', '.join(NODES)}", file=sys.stderr)
        return 2
    if transport not in TRANSPORTS:
        print(f"error: unknown transport {transport!r}; known: {', '.join(TRANSPORTS)}", file=sys.stderr)
        return 2
    if transport != "auto":
        os.environ["DEM_ROS_TRANSPORT"] = transport
    mod = importlib.import_module(f"dem_ros.nodes.{name}")
    return int(mod.main(list(rest)) or 0)


def main() -> int:
    argv = sys.argv[1:]
    if not argv:
        print("usage: node_main NAME [--transport auto|rclpy|dds] [--ros-args ...]", file=sys.stderr)
        return 2
    name, rest = argv[0], argv[1:]
    transport = "auto"
    if rest[:1] == ["--transport"] and len(rest) > 1:
        transport, rest = rest[1], rest[2:]
    return run(name, rest, transport)


if __name__ == "__main__":
    sys.exit(main())
