"""The rclpy transport: dem_ros nodes as rclpy nodes, at the dds transport's speed.

:mod:`.node` (the node), :mod:`.executor` (its executor on an rcl wait set), :mod:`.take`
(serialized takes with the writer's GID). Only importable where ``import rclpy`` works
(``pip install -e '.[ros]'`` brings ROS 2 Jazzy's rclpy on Fast DDS from the package index).
"""

from .executor import RclpyExecutor, init_context
from .node import RclpyNode, RclpyPublisher, ros_type, to_qos_profile

__all__ = ["RclpyExecutor", "RclpyNode", "RclpyPublisher", "init_context", "ros_type", "to_qos_profile"]
