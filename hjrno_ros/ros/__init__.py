"""The ROS 2 layer: ``brt_node`` (the product node) and ``harness`` (simulated robots and drivers that test it)."""
