"""The team of :func:`popbench.consensus.admm.admm_consensus` and its x-update linear system.

The robots' half-weighted local graphs stacked into one disjoint graph (:class:`_Team`), the fixed
sparse block-diagonal structure of every robot's damped Gauss–Newton system (:class:`_TeamSystem`)
and its per-robot SuperLU solve (:func:`_solve_blocks`).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.sparse as sp

from popbench.graph import PoseGraph
from popbench.objective import weights
from popbench.problems.distributed import DistributedProblem
from popbench.problems.partition import adjacency
from popbench.sparse import nested_dissection, spd_lu

# ----- the team: every robot's local graph in one disjoint graph -----------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class _Team:
    """The robots' half-weighted local graphs stacked into one disjoint graph of ``V`` vertices
    (robot by robot, each in ``local_vertices(r)`` order) and their separator copies.

    Attributes:
        graph: the disjoint union: edges of robot ``r`` join rows ``offsets[r]:offsets[r+1]``;
            inter-robot edges at half information.
        offsets: ``(R + 1,)`` first row of each robot.
        vertex_robot: ``(V,)`` robot of each row; ``edge_robot``: ``(M_T,)`` of each edge.
        copy_rows: ``(C,)`` rows of the separator copies, robot by robot (the copy order).
        copy_robot: ``(C,)``; ``separator_of``: ``(C,)`` index of each copy's separator.
        fixed_row: the row of vertex 0 in its owner's graph (the gauge, held fixed).
        kappa, tau: ``(M_T,)`` eq. 1 weights of the team edges.
    """

    graph: PoseGraph
    offsets: np.ndarray
    vertex_robot: np.ndarray
    edge_robot: np.ndarray
    copy_rows: np.ndarray
    copy_robot: np.ndarray
    separator_of: np.ndarray
    fixed_row: int
    kappa: np.ndarray
    tau: np.ndarray

    @property
    def num_robots(self) -> int:
        return self.offsets.size - 1


def _team(problem: DistributedProblem, local_poses: list[np.ndarray]) -> _Team:
    """Stack ``problem``'s local graphs at ``local_poses`` into a :class:`_Team`."""
    locals_ = problem.local_graphs
    sizes = np.array([local.num_vertices for local in locals_])
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    half = np.ones(problem.graph.num_edges)
    half[problem.inter_robot_edges] = 0.5
    edge_ids = np.concatenate([local.edge_ids for local in locals_])
    shift = np.concatenate(
        [np.full(local.graph.num_edges, offsets[r]) for r, local in enumerate(locals_)]
    )
    graph = problem.graph
    team = PoseGraph(
        poses=np.concatenate(local_poses),
        tails=np.concatenate([local.graph.tails for local in locals_]) + shift,
        heads=np.concatenate([local.graph.heads for local in locals_]) + shift,
        measurements=graph.measurements[edge_ids],
        information=graph.information[edge_ids] * half[edge_ids, None, None],
        kinds=graph.kinds[edge_ids],
        name=f"{graph.name}/team",
    )
    global_ids = np.concatenate([local.global_ids for local in locals_])
    vertex_robot = np.repeat(np.arange(sizes.size), sizes)
    copy_rows = np.flatnonzero(np.isin(global_ids, problem.separators))
    fixed = np.flatnonzero((global_ids == 0) & (problem.robots[global_ids] == vertex_robot))
    kappa, tau = weights(team.information)
    return _Team(
        team,
        offsets,
        vertex_robot,
        vertex_robot[team.tails],
        copy_rows,
        vertex_robot[copy_rows],
        np.searchsorted(problem.separators, global_ids[copy_rows]),
        int(fixed[0]),
        kappa,
        tau,
    )


# ----- the x-update's linear system -----------------------------------------------------------


def _vertex_order(team: _Team) -> np.ndarray:
    """``(V,)`` position of every team row but the gauge (−1): robot by robot, each robot's rows
    in a METIS nested-dissection order of its local graph (fill-reducing)."""
    graph = team.graph
    position = np.full(graph.num_poses, -1, dtype=np.int64)
    placed = 0
    for robot in range(team.num_robots):
        first, last = team.offsets[robot], team.offsets[robot + 1]
        inside = team.edge_robot == robot
        local = graph.replace(
            poses=graph.poses[first:last],
            tails=graph.tails[inside] - first,
            heads=graph.heads[inside] - first,
        )
        order = np.arange(last - first)
        if order.size > 2:
            starts, neighbours = adjacency(local)
            order, _ = nested_dissection(starts, neighbours)
        order = np.asarray(order, dtype=np.int64) + first
        order = order[order != team.fixed_row]
        position[order] = placed + np.arange(order.size)
        placed += order.size
    return position


class _TeamSystem:
    """Fixed sparse structure of every robot's x-update system at once.

    Unknowns: the additive increments of all team rows but the gauge, ``3(V − 1)``, robot by
    robot (robot ``r``: ``bounds[r]:bounds[r + 1]``), each robot's in a nested-dissection order
    (fill-reducing for SuperLU's natural-order factorisation). The matrix is block diagonal — no
    edge couples two robots' rows — so each robot's block is its own system. Per edge the four
    3×3 blocks ``(p,p), (p,q), (q,p), (q,q)`` and per copy its 3×3 penalty block go to
    precomputed CSC slots (``np.bincount``); entries of the gauge row go to one discarded slot.

    Batched execution. The robots' x-updates are independent given ``z`` and ``u``, so they run
    together: the half-weighted local graphs are stacked into one disjoint *team* graph (robot by
    robot, each in ``local_vertices(r)`` order), and per Gauss–Newton step one vectorised pass over
    the team's edges gives every robot's residuals, Jacobian blocks, gradient and objective
    (``np.bincount`` by robot). The team's normal equations are block diagonal (no entry couples
    two robots; tested), assembled into a CSC pattern fixed once (per-edge 3×3 blocks scattered to
    precomputed slots), with each robot's unknowns contiguous and in a METIS nested-dissection
    order of its local graph. Each robot still pending a step gets its own block (a CSC slice)
    factorised by :func:`popbench.sparse.spd_lu` in that order (measured: docs/sparse.md), so each
    robot's damping and step acceptance stay its own. Timings and the variants not kept:
    docs/consensus.md.
    """

    def __init__(self, team: _Team) -> None:
        graph = team.graph
        position = _vertex_order(team)
        size = 3 * (graph.num_poses - 1)
        t, h, c = position[graph.tails], position[graph.heads], position[team.copy_rows]
        block_rows = np.concatenate([t, t, h, h, c])
        block_cols = np.concatenate([t, h, t, h, c])
        k = np.arange(3)
        rows = (3 * block_rows[:, None, None] + k[:, None]).repeat(3, 2).ravel()
        cols = (3 * block_cols[:, None, None] + k[None, :]).repeat(3, 1).ravel()
        keys = np.where((rows >= 0) & (cols >= 0), cols * size + rows, -1)  # CSC order
        unique, slots = np.unique(keys, return_inverse=True)
        if unique.size and unique[0] == -1:  # gauge entries -> one extra slot, discarded
            unique = unique[1:]
            slots = np.where(slots == 0, unique.size, slots - 1)
        self.size, self.nnz, self.slots = size, unique.size, slots
        self.indices = (unique % size).astype(np.int32)
        self.indptr = np.searchsorted(unique // size, np.arange(size + 1)).astype(np.int32)
        diagonal = np.arange(size)
        self.diagonal_slots = np.searchsorted(unique, diagonal * size + diagonal)
        free = position >= 0
        self.free_dof = np.empty(size, dtype=np.int64)  # renumbered dof -> flat (V, 3) index
        self.free_dof[(3 * position[free, None] + k).ravel()] = (
            3 * np.flatnonzero(free)[:, None] + k
        ).ravel()
        self.dof_robot = team.vertex_robot[self.free_dof // 3]  # sorted: robot by robot
        self.bounds = np.searchsorted(self.dof_robot, np.arange(team.num_robots + 1))
        ends = np.concatenate([t, h, c])
        self.gradient_dof = np.where(ends[:, None] >= 0, 3 * ends[:, None] + k, size).ravel()

    def values(self, blocks: tuple, weight: np.ndarray) -> np.ndarray:
        """CSC values ``(nnz,)`` of ``Σ_e 2JᵀJ + ρΛ`` from the edge blocks (tail-tail, tail-head,
        head-head) and the copies' penalty weights ``weight`` ``(C, 3, 3)``."""
        tt, th, hh = blocks
        stacked = np.concatenate([tt, th, np.swapaxes(th, 1, 2), hh, weight])
        return np.bincount(self.slots, stacked.ravel(), self.nnz + 1)[: self.nnz]

    def gradient(self, g_tail: np.ndarray, g_head: np.ndarray, g_copy: np.ndarray) -> np.ndarray:
        """The gradient ``(3(V − 1),)`` in renumbered unknowns from per-edge / per-copy terms."""
        stacked = np.concatenate([g_tail, g_head, g_copy]).ravel()
        return np.bincount(self.gradient_dof, stacked, self.size + 1)[: self.size]

    def matrix(self, values: np.ndarray, shift: np.ndarray) -> sp.csc_matrix:
        """The CSC matrix of ``values`` plus ``diag(shift)`` (``shift``: ``(3(V − 1),)``)."""
        data = values.copy()
        data[self.diagonal_slots] += shift
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def increments(self, step: np.ndarray, num_vertices: int) -> np.ndarray:
        """``(V, 3)`` increments from a renumbered ``step`` (zero on the gauge row)."""
        out = np.zeros(3 * num_vertices)
        out[self.free_dof] = step
        return out.reshape(num_vertices, 3)


def _solve_blocks(
    matrix: sp.csc_matrix,
    rhs: np.ndarray,
    robots: np.ndarray,
    bounds: np.ndarray,
    seconds: np.ndarray,
) -> np.ndarray:
    """``matrix⁻¹ rhs`` on the diagonal blocks of ``robots`` (bool ``(R,)``), zero elsewhere.

    Robot ``r``'s unknowns are the contiguous range ``bounds[r]:bounds[r + 1]`` and its block
    is a CSC slice (no copy of the pattern); each block is factorised by SuperLU in its natural
    (nested-dissection) order with diagonal pivots, and the time of each robot's factorisation
    and solve is added to ``seconds`` ``(R,)`` [s].
    """
    x = np.zeros_like(rhs)
    for robot in np.flatnonzero(robots):
        tic = time.perf_counter()
        first, last = bounds[robot], bounds[robot + 1]
        start, stop = matrix.indptr[first], matrix.indptr[last]
        block = sp.csc_matrix(
            (
                matrix.data[start:stop],
                matrix.indices[start:stop] - first,
                matrix.indptr[first : last + 1] - start,
            ),
            shape=(last - first,) * 2,
        )
        x[first:last] = spd_lu(block).solve(rhs[first:last])
        seconds[robot] += time.perf_counter() - tic
    return x
