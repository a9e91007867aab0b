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

**Added false loop closures** (:func:`add_false_loop_closures`, the models of
:data:`ADDED_MODELS`, after Sünderhauf & Protzel's Vertigo ``generateDataset.py``): instead of
corrupting edges, groups of new, wrong loop closures are *added* (the models: that function).

**Scores** (:func:`precision_recall`) are computed over the candidate set's edges (``among=``):
an edge that could not be an outlier is neither a hit nor a false alarm.

**Mask files** (:func:`read_outlier_mask`): a graph file that already holds false loop closures
(e.g. one of Vertigo's) is scored against a text file with one line per edge of the graph as
read, in order, holding ``1`` (false) or ``0`` (true); blank lines and ``#`` comments are skipped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from popbench import se2
from popbench.choices import DEFAULT_GROUP_SIZE
from popbench.errors import DataFormatError, ValueRangeError
from popbench.graph import EdgeKind, PoseGraph, robot_kinds, single_robot_kinds
from popbench.problems.distributed import DistributedProblem

CANDIDATE_SETS: dict[str, tuple[EdgeKind, ...]] = {
    "loops": (EdgeKind.LOOP, EdgeKind.INTER_LOOP),
    "paper": (EdgeKind.LOOP, EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP),
}
TRANSLATION_SCALE = 0.5  # σ_t = 0.5 · L_avg

CORRUPT = "corrupt"  # the paper's model: corrupt existing loop closures (inject_outliers)
ADDED_MODELS = ("vertigo-random", "vertigo-local", "vertigo-grouped")  # add_false_loop_closures
OUTLIER_MODELS = (CORRUPT, *ADDED_MODELS)
LOCAL_WINDOW = 20  # vertigo-local: 2 ≤ |a − b| ≤ 20 poses
ADDED_SIGMA_T = 0.3  # [m] per axis, the added edges' translation
ADDED_SIGMA_THETA = float(np.deg2rad(10.0))  # [rad], their rotation


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
    (:func:`popbench.solvers.initial.with_start`: the odometry start is unchanged with ``"loops"``;
    with ``"paper"`` a corrupted cut odometry edge is part of the odometry chain), except a
    ``"given"`` start, whose poses are kept.
    """
    from popbench.solvers.initial import with_start

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


def add_false_loop_closures(
    graph: PoseGraph, rate: float, model: str, seed: int = 0, group_size: int = DEFAULT_GROUP_SIZE
) -> tuple[PoseGraph, np.ndarray]:
    """Add false loop closures to ``graph``.

    **Added false loop closures** (:func:`add_false_loop_closures`, the models of
    :data:`ADDED_MODELS`, after Sünderhauf & Protzel's Vertigo ``generateDataset.py``, whose data
    the DCS, max-mixture and GNC papers use): instead of corrupting edges, ``round(rate · L / g)``
    groups of ``g`` new edges are *added*, ``L`` the graph's loop closures (kinds LOOP and
    INTER_LOOP), ``g`` the group size (1 except for ``vertigo-grouped``):

    * ``vertigo-random``: between two poses ``a, b`` drawn uniformly with ``|a − b| ≥ 2``.
    * ``vertigo-local``: ``b − a`` drawn uniformly in ``2 … LOCAL_WINDOW`` (20 poses, Vertigo's
      window), ``a`` uniformly among the poses where that fits.
    * ``vertigo-grouped``: a random pair ``(a, b)`` as ``vertigo-random``, then the ``g`` mutually
      consistent edges ``(a + k, b + k)``, ``k = 0 … g − 1``, all with the same measurement and
      information (a front end that matched a whole stretch of trajectory wrongly).

    ``|a − b| ≥ 2`` (Vertigo's rule: consecutive ids would be odometry). Each group's measurement is
    drawn around the identity, ``t ~ N(0, ADDED_SIGMA_T² I₂)`` [m] and ``θ ~ N(0,
    ADDED_SIGMA_THETA²)`` [rad] (0.3 m and 10°, Vertigo's); its information is that of a loop
    closure of the graph drawn uniformly (so the added edges' information is distributed as the true
    closures'). Nothing in the graph tells an added edge from a true closure: it is written in the
    orientation of the graph's loop closures (tail < head with the share of them that are), its kind
    is the one :func:`popbench.graph.robot_kinds` (or :func:`~popbench.graph.single_robot_kinds`)
    gives any edge between those poses, and it is inserted in the edge list where a front end would
    emit it, after the last edge that reaches its later pose.

    Args:
        graph: the clean graph; its loop closures (kinds LOOP, INTER_LOOP) set the count and
            lend their information matrices; its robots (if any) the new edges' kinds.
        rate: added edges as a fraction of the graph's loop closures, in ``[0, 1]``.
        model: one of :data:`ADDED_MODELS`.
        seed: seed of ``np.random.default_rng``.
        group_size: edges per group of ``vertigo-grouped`` (≥ 1; the other models use 1).

    Returns:
        ``(graph, mask)``: the graph with ``K`` more edges and the ``(M + K,)`` added-edge mask.

    Raises:
        ValueRangeError: an unknown model, ``rate`` outside ``[0, 1]``, ``group_size < 1`` or
            a graph too small for the pairs.
    """
    if model not in ADDED_MODELS:
        raise ValueRangeError("outlier model", model, " | ".join(ADDED_MODELS))
    if not 0.0 <= rate <= 1.0:
        raise ValueRangeError("outlier rate", rate, "0 to 1")
    if group_size < 1:
        raise ValueRangeError("group size", group_size, "integers ≥ 1")
    size = group_size if model == "vertigo-grouped" else 1
    loops = candidate_edges(graph, "loops")
    groups = int(round(rate * loops.size / size))
    if graph.num_poses - size < 2 and groups:
        raise ValueRangeError("group size", size, f"≤ {graph.num_poses - 2} for {graph.name}")
    if groups == 0:
        return graph, np.zeros(graph.num_edges, dtype=bool)
    rng = np.random.default_rng(seed)
    first, second = _pairs(rng, groups, graph.num_poses - size, model == "vertigo-local")
    forward = rng.random(groups) < np.mean(graph.tails[loops] < graph.heads[loops])
    lower, upper = np.minimum(first, second), np.maximum(first, second)
    steps = np.arange(size)
    tails = (np.where(forward, lower, upper)[:, None] + steps).ravel()
    heads = (np.where(forward, upper, lower)[:, None] + steps).ravel()
    measurement = np.column_stack(
        [
            rng.normal(0.0, ADDED_SIGMA_T, (groups, 2)),
            se2.wrap(rng.normal(0.0, ADDED_SIGMA_THETA, groups)),
        ]
    )
    lent = rng.choice(loops, size=groups)
    measurements = np.repeat(measurement, size, axis=0)
    information = np.repeat(graph.information[lent], size, axis=0)
    if graph.robots is None:
        kinds = single_robot_kinds(tails, heads)
    else:
        kinds = robot_kinds(tails, heads, graph.robots)
    # a front end emits an edge when it reaches its later pose: after the last edge reaching it
    reach = np.maximum.accumulate(np.maximum(graph.tails, graph.heads))
    later = np.maximum(tails, heads)
    order = np.argsort(later, kind="stable")
    at = np.searchsorted(reach, later[order], side="right")
    mask = np.insert(np.zeros(graph.num_edges, dtype=bool), at, True)
    added = graph.replace(
        tails=np.insert(graph.tails, at, tails[order]),
        heads=np.insert(graph.heads, at, heads[order]),
        measurements=np.insert(graph.measurements, at, measurements[order], axis=0),
        information=np.insert(graph.information, at, information[order], axis=0),
        kinds=np.insert(graph.kinds, at, kinds[order]),
    )
    return added, mask


def _pairs(
    rng: np.random.Generator, count: int, last: int, local: bool
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` pose pairs ``(a, b)`` in ``0 … last`` with ``2 ≤ |a − b|`` (``≤ LOCAL_WINDOW``
    when ``local``), drawn uniformly by rejection (a few vectorised rounds)."""
    chosen_a, chosen_b = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    while chosen_a.size < count:
        draws = 2 * (count - chosen_a.size) + 8
        a = rng.integers(0, last + 1, draws)
        if local:
            b = a + rng.integers(2, LOCAL_WINDOW + 1, draws)
            keep = b <= last
        else:
            b = rng.integers(0, last + 1, draws)
            keep = np.abs(a - b) >= 2
        chosen_a = np.concatenate([chosen_a, a[keep]])
        chosen_b = np.concatenate([chosen_b, b[keep]])
    return chosen_a[:count], chosen_b[:count]


def read_outlier_mask(path: str | Path, num_edges: int) -> np.ndarray:
    """The ``(num_edges,)`` bool outlier mask of a mask file (module docstring: one ``0``/``1``
    line per edge of the graph as read, in order; blank lines and ``#`` comments skipped).

    Raises:
        DataFormatError: a line that is not ``0`` or ``1`` (file and line), or a count that is
            not the graph's number of edges.
    """
    path = Path(path)
    values: list[bool] = []
    lineno = 0
    with path.open() as handle:
        for lineno, line in enumerate(handle, start=1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            if text not in ("0", "1"):
                raise DataFormatError(path, lineno, f"outlier mask value {text!r}: allowed 0 or 1")
            values.append(text == "1")
    if len(values) != num_edges:
        raise DataFormatError(
            path, lineno, f"{len(values)} mask value(s), the graph has {num_edges} edge(s)"
        )
    return np.array(values, dtype=bool)
