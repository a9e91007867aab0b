"""popbench agents."""
