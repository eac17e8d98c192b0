"""The ROS 2 nodes of the dem_ros graph, one per file, each a thin adapter over the core.

``plant_sim``   simulated DEM (swap in a hardware driver honouring the same topics)
``hw_driver``   the rig's I/O board over the device link, honouring plant_sim's topics
``estimator``   EKF on the plant model (or pass-through)
``controller``  the control laws of :mod:`dem_ros.core.controllers`
``reference``   the reference model M(s) driven by the command schedule
``recorder``    records every topic of the contract to a rosbag2 MCAP bag

Every node has ``main(args=None)`` (console script / ``dem-ros node NAME``).
"""

__all__ = ["NODES"]

#: every node that ``dem-ros node NAME`` and ``ros2 run dem_ros NAME`` run (module ``dem_ros.nodes.NAME``,
#: function ``main(args=None)``; ``container`` runs the loop's nodes in one process). The one list:
#: the CLI, ``tools/node_main.py`` and ``setup.py`` read it.
NODES = ("plant_sim", "hw_driver", "estimator", "controller", "reference", "recorder", "container")

from ..core.numba_cache import configure as _configure_numba_cache  # noqa: E402

_configure_numba_cache()  # a node process: the kernels' cache of this version of the core (shared with the CLI)
