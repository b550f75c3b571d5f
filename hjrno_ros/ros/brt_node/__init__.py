"""brt_node: the safety filter node.  It imports the core, its value sources and itself, nothing else."""
