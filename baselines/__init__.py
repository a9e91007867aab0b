"""popbench baselines."""
