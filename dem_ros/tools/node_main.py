"""Run one node: ``python -m dem_ros.tools.node_main NAME [--transport T] [node args] [--ros-args ...]``."""

from __future__ import annotations

import importlib
import sys

from ..nodes import __doc__ as _doc  # noqa: F401

NODES = ("plant_sim", "estimator", "controller", "reference", "recorder", "container")


def run(name: str, rest: list[str], transport: str = "auto") -> int:
    if name not in NODES:
        print(f"error: unknown node {name!r}; known: {', '.join(NODES)}", file=sys.stderr)
        return 2
    import os

    os.environ.setdefault("DEM_ROS_TRANSPORT", transport)
    mod = importlib.import_module(f"dem_ros.nodes.{name}")
    if name in ("recorder", "container"):
        return mod.main(["--transport", transport, *rest])
    from ..transport import run_node

    cls = {"plant_sim": "PlantSimNode", "estimator": "EstimatorNode", "controller": "ControllerNode", "reference": "ReferenceNode"}[name]
    return run_node(name, getattr(mod, cls), args=rest, transport=transport)


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
