"""What the baseline benchmarks measure against: the published optima and GTSAM LM's time;
the problems they run on.

Imported by the benchmark scripts, which run as ``python benchmarks/<script>.py`` (so this
folder is on ``sys.path``).
"""

from __future__ import annotations

import time

import numpy as np

from popbench import datasets
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.initial import with_start

PUBLISHED_OPTIMA = {  # F_chordal*, SE-Sync convention (popbench.datasets.Dataset.chordal_optimum)
    name: entry.chordal_optimum
    for name, entry in datasets.DATASETS.items()
    if entry.chordal_optimum is not None
}

TOLERANCE = 1e-3  # a relative gap to the optimum that counts as converged


def split_problem(name: str, robots: int, init: str) -> DistributedProblem:
    """Dataset ``name`` split among ``robots`` robots (the default partition), started from
    ``init`` (:func:`popbench.solvers.initial.with_start`)."""
    return with_start(DistributedProblem.from_graph(datasets.load(name), robots), init)


def relative_gap(name: str, f_chordal: float | np.ndarray) -> float | np.ndarray:
    """``F_chordal / F_chordal* − 1`` against dataset ``name``'s published optimum."""
    return f_chordal / PUBLISHED_OPTIMA[name] - 1.0


def first_within(name: str, history: np.ndarray) -> int | None:
    """The first round whose relaxed cost (2f, a method's ``history``) is within
    :data:`TOLERANCE` of dataset ``name``'s published optimum, or None."""
    hits = np.flatnonzero(relative_gap(name, history) < TOLERANCE)
    return int(hits[0]) if hits.size else None


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


# The original C++ implementations, built from source and run on a quiet 2-core machine of this
# kind (docs/mm_pgo.md, the original C++ baselines): 1000 iterations,
# n = 7 robots, chordal start, whole-process wall seconds and final F_chordal (SE-Sync
# convention, the printed 2f). MM-PGO: MurpheyLab/DPGO `bin/dist_pgo --num_nodes 7 --iters 1000
# --loss trivial --dist_init true` (its distributed chordal start); RBCD: mit-acl/dpgo
# `build/bin/multi-robot-example 7 FILE.g2o` (rank 5, centralised chordal start, stops at
# gradient norm < 0.1).
ORIGINALS = {  # method -> dataset -> (wall s, F_chordal after 1000 iterations)
    "mm-pgo": {"m3500": (5.8, 193.8645), "city10k": (25.1, 638.6262)},
    "cc-pgo": {"m3500": (56.5, 194.23), "city10k": (121.6, 650.11)},
}
ORIGINALS_PROVENANCE = {
    "mm-pgo": "MurpheyLab/DPGO (C++), dist_pgo, AMM-PGO",
    "cc-pgo": "mit-acl/dpgo (C++), multi-robot-example, RBCD++",
}
