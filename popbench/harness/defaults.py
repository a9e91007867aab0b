"""The experiments' default settings, each stated once and free of NumPy: the configs of
:mod:`popbench.harness.table1`, :mod:`~popbench.harness.outliers` and
:mod:`~popbench.harness.scalability` take their defaults from here, and so do the command line's
options and their help (``popbench --help`` imports no NumPy)."""

from __future__ import annotations

ITERATIONS = 1000  # rounds of the iterative methods (the paper's 1000)
INIT = "odometry"  # every method's initial estimate (popbench.solvers.initial.STARTS)
PARTITION = "metis"  # how poses are split among robots (popbench.choices.PARTITIONS)

TABLE1_DATASETS = ("m3500", "m3500b", "m3500c", "city10k", "grid1000", "intel", "mit", "csail")
TABLE1_ROBOTS = (3, 7, 35)
TABLE1_OUT = "results/table1"
# --quick: a small subset that finishes in about a minute, written beside the committed table
TABLE1_QUICK = {
    "datasets": ("mit",),
    "robots": (3,),
    "iterations": 100,
    "out": "results/table1-quick",
}

OUTLIERS_DATASETS = ("intel", "mit", "csail")
OUTLIERS_METHODS = ("prop-v1", "mm-pgo", "gnc")  # the paper's Table II and GNC
OUTLIERS_RATES = (0.1,)
OUTLIERS_ROBOTS = 7
OUTLIERS_SEEDS = (0, 1, 2, 3, 4)
OUTLIERS_OUT = "results/outliers"

SCALABILITY_DATASET = "m3500"
SCALABILITY_ROBOTS = (1, 2, 3, 5, 7, 10, 14, 20, 28, 35, 50, 70)
SCALABILITY_METHODS = ("mm-pgo", "prop-v1", "prop-v2")  # the paper's Fig. 5
SCALABILITY_OUT = "results/scalability"


def joined(values: tuple[object, ...]) -> str:
    """``values`` as the command line writes a list: ``"3,7,35"``."""
    return ",".join(map(str, values))
