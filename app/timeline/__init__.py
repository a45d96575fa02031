"""A weld run over time: the pool geometry of each frame, from its label or its proposal."""
