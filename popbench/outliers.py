"""Outlier injection and detection scores (paper §IV-B).

Candidates: the loop-closure and inter-robot edges, i.e. kinds LOOP, INTER_RELATIVE and
INTER_LOOP (on a single-robot graph only LOOP edges exist among these).
``round(rate · #candidates)`` of them, chosen uniformly without replacement, get their
measurement replaced by ``θ ~ U(−π, π)`` and ``t ~ N(0, (0.5·L_avg)² I₂)`` [m], where
``L_avg`` is the mean measured translation length ``‖t̃‖`` over all edges of the uncorrupted
graph. Their information matrix is kept: an outlier looks exactly as confident as the inlier it
replaced. The estimate ``graph.poses`` is left unchanged.
"""

from __future__ import annotations

import numpy as np

from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph

CANDIDATE_KINDS = (EdgeKind.LOOP, EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP)
TRANSLATION_SCALE = 0.5  # σ_t = 0.5 · L_avg


def candidate_edges(graph: PoseGraph) -> np.ndarray:
    """Ids of the edges that may be corrupted (loop closures and inter-robot edges)."""
    return np.flatnonzero(np.isin(graph.kinds, np.array(CANDIDATE_KINDS, dtype=np.int8)))


def inject_outliers(
    problem_or_graph: DistributedProblem | PoseGraph, rate: float, seed: int = 0
) -> tuple[PoseGraph, np.ndarray]:
    """Corrupt a fraction of the candidate edges (see the module docstring).

    Args:
        problem_or_graph: a problem (its graph is used) or a graph; kinds decide the candidates.
        rate: fraction of candidates to corrupt, in ``[0, 1]``.
        seed: seed of ``np.random.default_rng``.

    Returns:
        ``(graph, mask)``: the corrupted graph and the ``(M,)`` bool ground-truth outlier mask.

    Raises:
        ValueRangeError: ``rate`` outside ``[0, 1]``.
    """
    graph = (
        problem_or_graph.graph
        if isinstance(problem_or_graph, DistributedProblem)
        else problem_or_graph
    )
    if not 0.0 <= rate <= 1.0:
        raise ValueRangeError("outlier rate", rate, "0 to 1")
    rng = np.random.default_rng(seed)
    candidates = candidate_edges(graph)
    chosen = rng.choice(candidates, size=int(round(rate * candidates.size)), replace=False)
    mean_length = float(np.mean(np.linalg.norm(graph.measurements[:, :2], axis=1)))
    measurements = graph.measurements.copy()
    measurements[chosen, :2] = rng.normal(0.0, TRANSLATION_SCALE * mean_length, (chosen.size, 2))
    measurements[chosen, 2] = rng.uniform(-np.pi, np.pi, chosen.size)
    mask = np.zeros(graph.num_edges, dtype=bool)
    mask[chosen] = True
    return graph.replace(measurements=measurements), mask


def with_outliers(problem: DistributedProblem, rate: float, seed: int = 0) -> DistributedProblem:
    """``problem`` with outliers injected (:func:`inject_outliers`) and ``outlier_mask`` set.

    The problem's start is made again from the corrupted measurements
    (:func:`popbench.initial.with_start`; a corrupted inter-robot relative edge is part of the
    odometry chain), except a ``"given"`` start, whose poses are kept.
    """
    from popbench.initial import with_start

    graph, mask = inject_outliers(problem, rate, seed)
    corrupted = DistributedProblem(graph, problem.start, mask)
    return corrupted if problem.start == "given" else with_start(corrupted, problem.start)


def precision_recall(flagged_outlier: np.ndarray, true_outlier: np.ndarray) -> tuple[float, float]:
    """Outlier-detection precision and recall of ``flagged_outlier`` against ``true_outlier``
    (both ``(M,)`` bool).

    ``precision = TP / #flagged`` and ``recall = TP / #true``. Empty sets: precision is 1.0 when
    nothing is flagged (no false alarm was raised) and recall is 1.0 when there are no true
    outliers (none was missed).
    """
    flagged = np.asarray(flagged_outlier, dtype=bool)
    truth = np.asarray(true_outlier, dtype=bool)
    if flagged.shape != truth.shape:
        raise ValueRangeError("flagged_outlier shape", flagged.shape, f"{truth.shape}")
    hits = int(np.count_nonzero(flagged & truth))
    num_flagged, num_true = int(flagged.sum()), int(truth.sum())
    precision = hits / num_flagged if num_flagged else 1.0
    recall = hits / num_true if num_true else 1.0
    return precision, recall
