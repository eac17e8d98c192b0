"""The rclpy-free transport: ROS 2 on plain Cyclone DDS (PyPI ``cyclonedds``).

Modules: :mod:`.msgs` (IDL structs with ROS names), :mod:`.wire` (naming,
discovery config, type hashes, QoS), :mod:`.fastcdr` (fast JointState codec),
:mod:`.node` (the node, parameter services, ``ros_discovery_info``),
:mod:`.client` (parameter client). No DDS-Security: this transport cannot join
an SROS2-enforced graph.
"""

__all__ = ["client", "fastcdr", "msgs", "node", "wire"]
