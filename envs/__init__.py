"""popbench envs."""
