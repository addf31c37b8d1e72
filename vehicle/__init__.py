"""Ground vehicle on mapped routes (seed 004): map geometry, world (truth, sensors), navigator (filters)."""
