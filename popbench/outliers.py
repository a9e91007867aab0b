"""Outlier injection and detection scores (paper §IV-B).

**Candidates** (the edges that may be corrupted), by ``candidates=``:

* ``"loops"`` (default): the loop closures, kinds LOOP and INTER_LOOP (intra- and inter-robot):
  the false data associations of a front end, as in Sünderhauf's Vertigo benchmarks and the
  GNC literature. Odometry, including the cut odometry edges (kind INTER_RELATIVE: consecutive
  poses of one trajectory owned by two robots), is never corrupted, so the odometry start
  composed from the corrupted graph equals the clean one.
* ``"paper"``: the paper's literal set, loop closures and every inter-robot edge (LOOP,
  INTER_RELATIVE, INTER_LOOP). A corrupted INTER_RELATIVE edge is a link of the odometry chain:
  the odometry start composed from the corrupted measurements is then wrong by a random rigid
  motion (θ ~ U(−π, π), t of the outlier's size) from that edge on, for every pose after it, so
  a method is scored on recovering from a broken start as much as on rejecting outliers.

On a single-robot graph both sets are the LOOP edges. ``round(rate · #candidates)`` of them,
chosen uniformly without replacement, get their measurement replaced by ``θ ~ U(−π, π)`` and
``t ~ N(0, (0.5·L_avg)² I₂)`` [m], where ``L_avg`` is the mean measured translation length
``‖t̃‖`` over all edges of the uncorrupted graph. Their information matrix is kept: an outlier
looks exactly as confident as the inlier it replaced. The estimate ``graph.poses`` is left
unchanged.

**Scores** (:func:`precision_recall`) are computed over the candidate set's edges (``among=``):
an edge that could not be an outlier is neither a hit nor a false alarm.
"""

from __future__ import annotations

import numpy as np

from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph

CANDIDATE_SETS: dict[str, tuple[EdgeKind, ...]] = {
    "loops": (EdgeKind.LOOP, EdgeKind.INTER_LOOP),
    "paper": (EdgeKind.LOOP, EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP),
}
TRANSLATION_SCALE = 0.5  # σ_t = 0.5 · L_avg


def candidate_mask(graph: PoseGraph, candidates: str = "loops") -> np.ndarray:
    """``(M,)`` bool: the edges of the candidate set ``candidates`` (see the module docstring).

    Raises:
        ValueRangeError: an unknown candidate set.
    """
    if candidates not in CANDIDATE_SETS:
        raise ValueRangeError("outlier candidates", candidates, " | ".join(CANDIDATE_SETS))
    return np.isin(graph.kinds, np.array(CANDIDATE_SETS[candidates], dtype=np.int8))


def candidate_edges(graph: PoseGraph, candidates: str = "loops") -> np.ndarray:
    """Ids of the edges that may be corrupted, ``(K,)`` int64 (see :func:`candidate_mask`)."""
    return np.flatnonzero(candidate_mask(graph, candidates))


def inject_outliers(
    problem_or_graph: DistributedProblem | PoseGraph,
    rate: float,
    seed: int = 0,
    candidates: str = "loops",
) -> tuple[PoseGraph, np.ndarray]:
    """Corrupt a fraction of the candidate edges (see the module docstring).

    Args:
        problem_or_graph: a problem (its graph is used) or a graph; kinds decide the candidates.
        rate: fraction of candidates to corrupt, in ``[0, 1]``.
        seed: seed of ``np.random.default_rng``.
        candidates: ``"loops"`` (loop closures only) or ``"paper"`` (plus the cut odometry).

    Returns:
        ``(graph, mask)``: the corrupted graph and the ``(M,)`` bool ground-truth outlier mask.

    Raises:
        ValueRangeError: ``rate`` outside ``[0, 1]`` or an unknown candidate set.
    """
    graph = (
        problem_or_graph.graph
        if isinstance(problem_or_graph, DistributedProblem)
        else problem_or_graph
    )
    if not 0.0 <= rate <= 1.0:
        raise ValueRangeError("outlier rate", rate, "0 to 1")
    rng = np.random.default_rng(seed)
    pool = candidate_edges(graph, candidates)
    chosen = rng.choice(pool, size=int(round(rate * pool.size)), replace=False)
    mean_length = float(np.mean(np.linalg.norm(graph.measurements[:, :2], axis=1)))
    measurements = graph.measurements.copy()
    measurements[chosen, :2] = rng.normal(0.0, TRANSLATION_SCALE * mean_length, (chosen.size, 2))
    measurements[chosen, 2] = rng.uniform(-np.pi, np.pi, chosen.size)
    mask = np.zeros(graph.num_edges, dtype=bool)
    mask[chosen] = True
    return graph.replace(measurements=measurements), mask


def with_outliers(
    problem: DistributedProblem, rate: float, seed: int = 0, candidates: str = "loops"
) -> DistributedProblem:
    """``problem`` with outliers injected (:func:`inject_outliers`) and ``outlier_mask`` set.

    The problem's start is made again from the corrupted measurements
    (:func:`popbench.initial.with_start`: the odometry start is unchanged with ``"loops"``;
    with ``"paper"`` a corrupted cut odometry edge is part of the odometry chain), except a
    ``"given"`` start, whose poses are kept.
    """
    from popbench.initial import with_start

    graph, mask = inject_outliers(problem, rate, seed, candidates)
    corrupted = DistributedProblem(graph, problem.start, mask)
    return corrupted if problem.start == "given" else with_start(corrupted, problem.start)


def precision_recall(
    flagged_outlier: np.ndarray, true_outlier: np.ndarray, among: np.ndarray | None = None
) -> tuple[float, float]:
    """Outlier-detection precision and recall of ``flagged_outlier`` against ``true_outlier``
    (both ``(M,)`` bool), counted over the edges ``among`` (``(M,)`` bool, e.g.
    :func:`candidate_mask`; default all edges).

    ``precision = TP / #flagged`` and ``recall = TP / #true``. Empty sets: precision is 1.0 when
    nothing is flagged (no false alarm was raised) and recall is 1.0 when there are no true
    outliers (none was missed).
    """
    flagged = np.asarray(flagged_outlier, dtype=bool)
    truth = np.asarray(true_outlier, dtype=bool)
    if flagged.shape != truth.shape:
        raise ValueRangeError("flagged_outlier shape", flagged.shape, f"{truth.shape}")
    if among is not None:
        among = np.asarray(among, dtype=bool)
        if among.shape != truth.shape:
            raise ValueRangeError("among shape", among.shape, f"{truth.shape}")
        flagged, truth = flagged & among, truth & among
    hits = int(np.count_nonzero(flagged & truth))
    num_flagged, num_true = int(flagged.sum()), int(truth.sum())
    precision = hits / num_flagged if num_flagged else 1.0
    recall = hits / num_true if num_true else 1.0
    return precision, recall
