"""hjrno_ros: Hamilton-Jacobi reachability with neural operators, as a ROS 2 safety filter.

The core (dynamics, geometry, solver, ...) imports no ROS; ``brt_node`` is the ROS 2 shell.
"""

__version__ = "0.1.0"
