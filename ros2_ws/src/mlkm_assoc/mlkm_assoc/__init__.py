"""Live association graph: association_node, scorer_node (and the mlkm CLI entry point)."""
