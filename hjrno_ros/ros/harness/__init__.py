"""Simulated robots and drivers that exercise brt_node over ROS 2 (never imported by the node)."""
