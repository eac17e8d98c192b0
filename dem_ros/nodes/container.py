"""``container``: the graph's nodes in one process, on one executor (composition).

What a ROS 2 component container with intra-process communication does for
C++ nodes: ``plant_sim``, ``estimator``, ``controller``, ``reference`` (and the
``recorder`` with ``--bag``) keep their own names, parameters, services and
topics, so ``ros2 node list``, ``ros2 param`` and ``ros2 topic echo`` see the
same graph, but one thread runs them all and, on the dds transport, messages
between them are handed over in memory instead of crossing DDS (see
:mod:`dem_ros.transport.dds.executor`). The 1 kHz loop then costs no socket,
no context switch and no (de)serialisation, the usual way to close a hard
real-time loop in ROS 2 (cf. ros2_control's controller manager). Swap in a
hardware driver by leaving ``plant_sim`` out (``--nodes``) and running the
driver beside the container.

Usage: ``dem-ros node container [--nodes a,b,...] [--bag DIR [--meta FILE]] [--ros-args ...]``,
``ros2 run dem_ros container --ros-args --params-file config/dem_ros.yaml``.
A global ``-p name:=value`` goes to the nodes that declare ``name``. The
process ends when the plant finishes its run (``duration``), or on Ctrl-C / SIGTERM.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from ..transport import Node, run_nodes
from .controller import ControllerNode
from .estimator import EstimatorNode
from .plant_sim import PlantSimNode
from .recorder import RecorderNode, parse_recorder_args, split_ros_args
from .reference import ReferenceNode

__all__ = ["LOOP_NODES", "main"]

#: set-up order = intra-process delivery order on a shared topic (estimator before reference)
LOOP_NODES = {"estimator": EstimatorNode, "controller": ControllerNode, "reference": ReferenceNode,
              "plant_sim": PlantSimNode}


def main(args=None) -> int:
    argv, ros_args = split_ros_args(list(sys.argv[1:] if args is None else args))
    p = argparse.ArgumentParser(prog="container", description="run the dem_ros nodes in one process")
    p.add_argument("--nodes", default=",".join(LOOP_NODES),
                   help=f"comma-separated subset of {', '.join(LOOP_NODES)} (default: all)")
    p.add_argument("--transport", default="auto", choices=["auto", "rclpy", "dds"])
    a, meta = parse_recorder_args(p, argv)
    names = [n.strip() for n in a.nodes.split(",") if n.strip()]
    unknown = [n for n in names if n not in LOOP_NODES]
    if unknown or not names or len(set(names)) != len(names):
        p.exit(2, f"error: container: --nodes {a.nodes!r}: use distinct names from {', '.join(LOOP_NODES)}\n")
    specs: list[tuple[str, Callable[[Node], object]]] = [(n, LOOP_NODES[n]) for n in LOOP_NODES if n in names]
    rec: list[RecorderNode] = []
    if a.bag is not None:  # first, so it sees every sample the others publish
        specs.insert(0, ("recorder", lambda node: rec.append(RecorderNode(node, Path(a.bag), meta))))
    # the recorder is best-effort: its callbacks run after the loop's chain in every round
    code = run_nodes(specs, args=ros_args, transport=a.transport,
                     stop_with="plant_sim" if "plant_sim" in names else None, background=("recorder",))
    if rec:
        rec[0].close()
    return code


if __name__ == "__main__":
    sys.exit(main())
