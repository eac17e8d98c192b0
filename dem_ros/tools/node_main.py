"""Run one node: ``python -m dem_ros.tools.node_main NAME [--transport T] [node args] [--ros-args ...]``."""

from __future__ import annotations

import importlib
import sys

from ..transport import run_node

__all__ = ["NODES", "main", "run"]

#: what ``dem-ros node NAME`` can run: the graph's nodes and ``container`` (all of them in one process)
NODES = ("plant_sim", "hw_driver", "estimator", "controller", "reference", "recorder", "container")
#: nodes whose ``main`` parses its own arguments (``--transport``, ``--bag``, ...)
_OWN_ARGS = ("recorder", "container")
_CLASSES = {"plant_sim": "PlantSimNode", "hw_driver": "HwDriverNode", "estimator": "EstimatorNode", "controller": "ControllerNode",
            "reference": "ReferenceNode"}


def run(name: str, rest: list[str], transport: str = "auto") -> int:
    if name not in NODES:
        print(f"error: unknown node {name!r}; known: {', '.join(NODES)}", file=sys.stderr)
        return 2
    mod = importlib.import_module(f"dem_ros.nodes.{name}")
    if name in _OWN_ARGS:
        return int(mod.main(["--transport", transport, *rest]))
    return run_node(name, getattr(mod, _CLASSES[name]), args=rest, transport=transport)


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
