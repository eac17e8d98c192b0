"""dem_ros: adaptive control of a double-electromagnet (DEM) maglev suspension.

Layout:
    dem_ros.core       numpy/numba math, no middleware: plant, reference model,
                       controllers, estimator, scenarios, metrics, offline simulator
    dem_ros.nodes      the ROS 2 nodes (one per file), thin adapters over the core
    dem_ros.transport  the small node interface and its rclpy and DDS implementations
    dem_ros.bag        rosbag2-compatible MCAP recording, reading and checking
    dem_ros.tools      the ``dem-ros`` command line: sim, report, bench, launch, replay
"""

__version__ = "0.1.0"
