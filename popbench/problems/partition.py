"""Split a pose graph's vertices among robots.

* ``"metis"`` (default): METIS multilevel k-way partitioning (pymetis) of the unweighted,
  undirected, deduplicated vertex adjacency — balanced parts with few cut edges (the multilevel
  partitioner of ML-PGO, Li et al. 2024).
* ``"contiguous"``: equal blocks of consecutive vertex ids (trajectory segments); the first
  ``N mod n`` robots get one extra pose, as MM-PGO's ``read_g2o`` does.

Robot ids are canonical in both cases: robot 0 holds vertex 0 and robots are numbered in the order
of their smallest vertex id, so the gauge (robot 0's first pose) is vertex 0.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pymetis

from popbench.choices import PARTITIONS
from popbench.errors import PopbenchError, ValueRangeError
from popbench.graph import PoseGraph, robot_kinds

METHODS = PARTITIONS


def check_robots(robots: int, num_poses: int) -> int:
    """``robots`` as an int, or a :class:`ValueRangeError` unless ``1 ≤ robots ≤ num_poses``."""
    if isinstance(robots, bool) or not isinstance(robots, int | np.integer):
        raise ValueRangeError("robots", robots, f"an integer from 1 to {num_poses}")
    if not 1 <= robots <= num_poses:
        raise ValueRangeError("robots", robots, f"1 to {num_poses} (the number of poses)")
    return int(robots)


def adjacency(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    """CSR ``(starts (N+1,), neighbours)`` of the undirected vertex adjacency, without self loops
    or duplicate edges (parallel and reversed edges count once)."""
    n = graph.num_poses
    keep = graph.tails != graph.heads
    rows = np.concatenate([graph.tails[keep], graph.heads[keep]])
    cols = np.concatenate([graph.heads[keep], graph.tails[keep]])
    keys = np.unique(rows * n + cols)  # sorted by row, then column
    rows, cols = np.divmod(keys, n)
    starts = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
    return starts.astype(np.int64), cols.astype(np.int64)


def canonical_labels(parts: np.ndarray) -> np.ndarray:
    """Relabel parts so that part 0 holds vertex 0 and parts are ordered by smallest vertex id."""
    labels, first = np.unique(parts, return_index=True)
    order = np.argsort(first)
    relabel = np.empty(labels.size, dtype=np.int64)
    relabel[order] = np.arange(labels.size)
    return relabel[np.searchsorted(labels, parts)]


def contiguous(num_poses: int, robots: int) -> np.ndarray:
    """``(N,)`` blocks of consecutive ids; the first ``N mod n`` robots get one extra pose."""
    sizes = np.full(robots, num_poses // robots)
    sizes[: num_poses % robots] += 1
    return np.repeat(np.arange(robots, dtype=np.int64), sizes)


def metis(graph: PoseGraph, robots: int, seed: int = 0) -> np.ndarray:
    """``(N,)`` METIS k-way partition of the unweighted vertex adjacency, canonically labelled.

    Raises:
        PopbenchError: METIS left a robot without poses.
    """
    if robots == 1:
        return np.zeros(graph.num_poses, dtype=np.int64)
    starts, neighbours = adjacency(graph)
    result = pymetis.part_graph(
        robots,
        adjacency=pymetis.CSRAdjacency(adj_starts=starts, adjacent=neighbours),
        options=pymetis.Options(seed=int(seed)),
    )
    parts = np.asarray(result.vertex_part, dtype=np.int64)
    used = np.unique(parts).size
    if used != robots:
        raise PopbenchError(
            f"METIS split {graph.name!r} ({graph.num_poses} poses) into {used} non-empty parts, "
            f"not robots={robots}: use fewer robots or partition='contiguous'"
        )
    return canonical_labels(parts)


def partition(graph: PoseGraph, robots: int, method: str = "metis", seed: int = 0) -> np.ndarray:
    """The robot owning each vertex, ``(N,)`` int64 in ``[0, robots)``.

    Args:
        graph: the pose graph to split.
        robots: number of robots ``n``, ``1 ≤ n ≤ N``.
        method: ``"metis"`` or ``"contiguous"``.
        seed: METIS random seed (ignored by ``"contiguous"``).

    Raises:
        ValueRangeError: ``robots`` outside ``[1, N]`` or an unknown ``method``.
        PopbenchError: METIS returned an empty part.
    """
    robots = check_robots(robots, graph.num_poses)
    if method == "metis":
        return metis(graph, robots, seed)
    if method == "contiguous":
        return contiguous(graph.num_poses, robots)
    raise ValueRangeError("partition method", method, " or ".join(METHODS))


class PartitionReport(NamedTuple):
    """Quality of a vertex → robot assignment."""

    cut_edges: int  # edges whose endpoints belong to different robots
    sizes: np.ndarray  # (n,) poses per robot
    imbalance: float  # largest part / mean part size (1.0 = perfectly balanced)


def partition_report(graph: PoseGraph, robots: np.ndarray) -> PartitionReport:
    """Cut edges and part sizes of the assignment ``robots`` ``(N,)``."""
    robots = np.asarray(robots, dtype=np.int64)
    sizes = np.bincount(robots)
    cut = int(np.count_nonzero(robots[graph.tails] != robots[graph.heads]))
    return PartitionReport(cut, sizes, float(sizes.max() / sizes.mean()))


def assign(graph: PoseGraph, robots: np.ndarray) -> PoseGraph:
    """``graph`` with ``robots`` ``(N,)`` set and its edge kinds relabelled under it
    (:func:`popbench.graph.robot_kinds`).

    Raises:
        ValueRangeError: ``robots`` has the wrong shape, a negative id or an unused robot id.
    """
    robots = np.asarray(robots)
    if robots.shape != (graph.num_poses,) or not np.issubdtype(robots.dtype, np.integer):
        raise ValueRangeError(
            "robot assignment", f"shape {robots.shape}", f"({graph.num_poses},) integers"
        )
    robots = robots.astype(np.int64)
    if robots.min() < 0 or np.unique(robots).size != robots.max() + 1:
        raise ValueRangeError(
            "robot assignment", "with gaps or negative ids", "every id in 0..n-1 used"
        )
    return graph.replace(robots=robots, kinds=robot_kinds(graph.tails, graph.heads, robots))
