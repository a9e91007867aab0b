"""Planar pose graphs: poses, edges with measurements, information and kinds.

Conventions (g2o): an edge ``p → q`` (tail ``p``, head ``q``) measures ``z ≈ x_p⁻¹ ∘ x_q``, the
pose of ``q`` in the frame of ``p``; its information matrix is 3×3 in ``(x, y, θ)`` order.
"""

from __future__ import annotations

import dataclasses
from enum import IntEnum

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from popbench import se2


class EdgeKind(IntEnum):
    """The origin label of an edge (paper §III-A)."""

    ODOMETRY = 0  # consecutive poses of one robot
    LOOP = 1  # intra-robot loop closure
    INTER_RELATIVE = 2  # consecutive poses owned by two robots (a cut odometry edge)
    INTER_LOOP = 3  # loop closure between two robots


@dataclasses.dataclass(frozen=True, eq=False)
class PoseGraph:
    """A planar pose graph.

    Attributes:
        poses: ``(N, 3)`` current estimate, ``(x [m], y [m], θ [rad])`` per vertex.
        tails: ``(M,)`` int64 tail vertex ``p`` of each edge.
        heads: ``(M,)`` int64 head vertex ``q`` of each edge.
        measurements: ``(M, 3)`` measured relative pose ``z̃ = (t̃x, t̃y, θ̃)`` of ``q`` in ``p``.
        information: ``(M, 3, 3)`` symmetric positive-definite information, ``(x, y, θ)`` order.
        kinds: ``(M,)`` int8 :class:`EdgeKind` per edge.
        ground_truth: ``(N, 3)`` true poses, or ``None`` (real data).
        robots: ``(N,)`` int64 robot owning each vertex, or ``None`` (single robot).
        name: a label for reports (dataset name or file stem).
        vertex_ids: ``(N,)`` uint64 id of each vertex as written in its file, or ``None`` (the
            ids are ``0 … N−1``). Internal indices are always contiguous ``0 … N−1``.
        fixed: ``(K,)`` int64 internal indices of the poses held fixed (g2o ``FIX`` lines), or
            ``None`` (no ``FIX`` line: vertex 0 is the gauge).
    """

    poses: np.ndarray
    tails: np.ndarray
    heads: np.ndarray
    measurements: np.ndarray
    information: np.ndarray
    kinds: np.ndarray
    ground_truth: np.ndarray | None = None
    robots: np.ndarray | None = None
    name: str = "graph"
    vertex_ids: np.ndarray | None = None
    fixed: np.ndarray | None = None

    @property
    def num_poses(self) -> int:
        return int(self.poses.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.tails.shape[0])

    @property
    def num_robots(self) -> int:
        return 1 if self.robots is None else int(self.robots.max()) + 1

    def replace(self, **changes: object) -> PoseGraph:
        """A copy with some fields replaced (``graph.replace(poses=new_poses)``)."""
        return dataclasses.replace(self, **changes)

    def edge_subset(self, keep: np.ndarray) -> PoseGraph:
        """The same vertices with only the edges where ``keep`` (``(M,)`` bool) is True."""
        return self.replace(
            tails=self.tails[keep],
            heads=self.heads[keep],
            measurements=self.measurements[keep],
            information=self.information[keep],
            kinds=self.kinds[keep],
        )

    def odometry_initial(self) -> np.ndarray:
        """The odometry-composition estimate of this graph's measurements (see
        :func:`odometry_composition`)."""
        return odometry_composition(self.num_poses, self.tails, self.heads, self.measurements)


def make_graph(
    poses: np.ndarray,
    tails: np.ndarray,
    heads: np.ndarray,
    measurements: np.ndarray,
    information: np.ndarray,
    kinds: np.ndarray | None = None,
    **fields: object,
) -> PoseGraph:
    """Build a :class:`PoseGraph` with canonical dtypes; kinds default to
    :func:`single_robot_kinds`."""
    tails = np.asarray(tails, dtype=np.int64)
    heads = np.asarray(heads, dtype=np.int64)
    if kinds is None:
        kinds = single_robot_kinds(tails, heads)
    return PoseGraph(
        poses=np.asarray(poses, dtype=np.float64),
        tails=tails,
        heads=heads,
        measurements=np.asarray(measurements, dtype=np.float64),
        information=np.asarray(information, dtype=np.float64),
        kinds=np.asarray(kinds, dtype=np.int8),
        **fields,
    )


def single_robot_kinds(tails: np.ndarray, heads: np.ndarray) -> np.ndarray:
    """Label edges between consecutive vertex ids odometry, all others loop closures."""
    consecutive = np.abs(heads - tails) == 1
    return np.where(consecutive, EdgeKind.ODOMETRY, EdgeKind.LOOP).astype(np.int8)


def robot_kinds(tails: np.ndarray, heads: np.ndarray, robots: np.ndarray) -> np.ndarray:
    """Label edges from a vertex → robot assignment: consecutive ids are odometry within a robot
    and inter-robot relative across robots; other edges are (inter-robot) loop closures."""
    consecutive = np.abs(heads - tails) == 1
    crossing = robots[tails] != robots[heads]
    kinds = np.where(consecutive, EdgeKind.ODOMETRY, EdgeKind.LOOP)
    kinds = np.where(crossing & consecutive, EdgeKind.INTER_RELATIVE, kinds)
    kinds = np.where(crossing & ~consecutive, EdgeKind.INTER_LOOP, kinds)
    return kinds.astype(np.int8)


def unconnected_vertices(num_poses: int, tails: np.ndarray, heads: np.ndarray) -> np.ndarray:
    """Ids (ascending) of the vertices that no path of edges joins to vertex 0 (the gauge):
    their poses are not determined by the measurements. Empty for a connected graph."""
    adjacency = coo_matrix(
        (np.ones(tails.size), (tails, heads)), shape=(num_poses, num_poses)
    ).tocsr()
    _, labels = connected_components(adjacency, directed=False)
    return np.flatnonzero(labels != labels[0])


def odometry_composition(
    num_poses: int, tails: np.ndarray, heads: np.ndarray, measurements: np.ndarray
) -> np.ndarray:
    """Initial estimate by composing measurements from vertex 0 (at the origin).

    With a complete chain ``k → k+1`` this is the cumulative odometry (vectorised prefix sums).
    Otherwise measurements are composed along a breadth-first spanning tree, preferring chain
    edges, level by level; vertices unreachable from 0 stay at the origin.

    Returns:
        ``(N, 3)`` poses.
    """
    tails = np.asarray(tails, dtype=np.int64)
    heads = np.asarray(heads, dtype=np.int64)
    chain = heads == tails + 1
    if num_poses > 1 and np.count_nonzero(np.bincount(tails[chain], minlength=num_poses)) == (
        num_poses - 1
    ):
        first = np.zeros(num_poses - 1, dtype=np.int64)
        first[tails[chain][::-1]] = np.flatnonzero(chain)[::-1]  # first chain edge per tail
        steps = measurements[first]
        headings = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
        moves = se2.rotate(headings[:-1], steps[:, :2])
        translations = np.vstack([[0.0, 0.0], np.cumsum(moves, axis=0)])
        return np.column_stack([translations, se2.wrap(headings)])
    return _spanning_tree_composition(num_poses, tails, heads, measurements)


def _spanning_tree_composition(
    num_poses: int, tails: np.ndarray, heads: np.ndarray, measurements: np.ndarray
) -> np.ndarray:
    # Each undirected edge appears in both directions; the reverse direction carries z⁻¹.
    edge_ids = np.arange(tails.size)
    rows = np.concatenate([tails, heads])
    cols = np.concatenate([heads, tails])
    codes = np.concatenate([edge_ids + 1, -(edge_ids + 1)])  # sign = direction, 0 = none
    adjacency = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(num_poses, num_poses))
    order, parents = breadth_first_order(adjacency.tocsr(), 0, directed=False)
    keys, first = np.unique(rows * num_poses + cols, return_index=True)
    poses = np.zeros((num_poses, 3))
    depth = np.full(num_poses, -1)
    depth[0] = 0
    for vertex in order[1:]:  # BFS order: a parent's depth is known before its children's
        depth[vertex] = depth[parents[vertex]] + 1
    inverse_measurements = se2.inverse(measurements)
    for level in range(1, int(depth.max()) + 1):
        children = np.flatnonzero(depth == level)
        slots = np.searchsorted(keys, parents[children] * num_poses + children)
        codes_here = codes[first[slots]]
        steps = np.where(
            (codes_here > 0)[:, None],
            measurements[np.abs(codes_here) - 1],
            inverse_measurements[np.abs(codes_here) - 1],
        )
        poses[children] = se2.compose(poses[parents[children]], steps)
    return poses
