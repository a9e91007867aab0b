"""What the baseline benchmarks measure against: the published optima and GTSAM LM's time.

Imported by the benchmark scripts, which run as ``python benchmarks/<script>.py`` (so this
folder is on ``sys.path``).
"""

from __future__ import annotations

import time

import numpy as np

from popbench import datasets

PUBLISHED_OPTIMA = {  # F_chordal*, SE-Sync convention (REFERENCES §6.2, certified or recomputed)
    "intel": 393.6525,
    "mit": 61.1541,
    "csail": 31.7037,
    "m3500": 193.8623,
    "city10k": 638.6246,
}


def gtsam_lm_seconds(name: str) -> tuple[float, float]:
    """Wall and CPU seconds of one GTSAM Levenberg–Marquardt run (default parameters) on dataset
    ``name``, from the file's initial estimate, pose 0 held by a tight prior (σ = 1e-6)."""
    import gtsam

    graph, initial = gtsam.readG2o(str(datasets.dataset_path(name)), False)
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-6))
    graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), prior))
    wall, cpu = time.perf_counter(), time.process_time()
    gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
    return time.perf_counter() - wall, time.process_time() - cpu
