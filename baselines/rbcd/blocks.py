"""The blocks of RBCD: robots coloured so that each colour class (no two robots sharing an edge)
updates at once, and each class's rows of ``Q`` with its cached preconditioner ``Q_cc + λI``
(dpgo's preconditioner, Tian et al. 2021, for every robot of the class at once).

Robot α owns the rows of its poses (``graph.robots``); robots that share no edge have decoupled
local problems, so the robot adjacency is coloured greedily and each colour class (an independent
set) is one block. A class's robots update as one block-diagonal batch or one by one
(:func:`batch_groups`; measured: docs/rbcd.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from baselines.rbcd.relaxation import flat
from popbench.graph import PoseGraph
from popbench.sparse import CholeskyFactor

PRECONDITIONER_SHIFT = 0.1  # λ in Q_αα + λI (dpgo)


class CholeskyPreconditioner:
    """``(Q_cc + λI)⁻¹`` of one colour class by a cached sparse Cholesky factor (CHOLMOD via
    cholespy, fill-reducing ordering chosen by CHOLMOD); the class's ``Q_cc`` is block diagonal
    (one block per robot), so this is every robot's dpgo preconditioner at once."""

    def __init__(self, hessian: sp.csr_matrix, shift: float) -> None:
        self._factor = CholeskyFactor((hessian + shift * sp.identity(hessian.shape[0])).tocsr())

    def solve(self, v: np.ndarray) -> np.ndarray:
        """``(Q_cc + λI)⁻¹ v`` for ``v`` ``(n, 3, r)``, returned ``(n, 3, r)``."""
        return self._factor.solve(flat(v)).reshape(v.shape)


@dataclasses.dataclass(frozen=True, eq=False)
class ClassBlock:
    """The robots of one colour class (no two share an edge), updated together.

    Attributes:
        robots: ``(k,)`` robot ids of the class.
        poses: ``(n_c,)`` global ids of their poses, robot by robot (ascending within a robot).
        robot_of_pose: ``(n_c,)`` index ``0..k−1`` into ``robots`` of each pose's owner.
        hessian: ``Q_cc`` ``(3n_c, 3n_c)`` CSR, block diagonal with the robots' ``Q_αα``.
        preconditioner: the cached factor of ``Q_cc + λI``.
        reach_rows: ``(m,)`` rows of ``Q`` with a nonzero in the class's columns (its own rows and
            its neighbours' separator rows).
        reach: ``Q[reach_rows, class rows]`` ``(m, 3n_c)`` CSR: how a change of the class's
            poses changes ``QX``.
        own_in_reach: ``(3n_c,)`` positions of the class's own rows in ``reach_rows``
            (``reach[own_in_reach] = Q_cc``).
        separators: number of the class's poses with an edge to another robot.
        robot_nnz: ``(k,)`` nonzeros of each robot's ``Q_αα``: the work weight of one of its
            Hessian–vector products (see :func:`robot_shares`).
    """

    robots: np.ndarray
    poses: np.ndarray
    robot_of_pose: np.ndarray
    hessian: sp.csr_matrix
    preconditioner: CholeskyPreconditioner
    reach_rows: np.ndarray
    reach: sp.csr_matrix
    own_in_reach: np.ndarray
    separators: int
    robot_nnz: np.ndarray

    @property
    def num_robots(self) -> int:
        return self.robots.size

    @property
    def per_robot(self) -> PerRobot:
        return PerRobot(self.robot_of_pose, self.num_robots)


def pose_rows(poses: np.ndarray) -> np.ndarray:
    """Rows of ``X.reshape(3N, r)`` of the given poses, ``(3n,)``."""
    return (3 * poses[:, None] + np.arange(3)).ravel()


def class_blocks(
    q: sp.csr_matrix,
    graph: PoseGraph,
    robots: np.ndarray,
    classes: list[np.ndarray],
    shift: float = PRECONDITIONER_SHIFT,
) -> list[ClassBlock]:
    """One :class:`ClassBlock` per colour class of the assignment ``robots`` ``(N,)``, with the
    preconditioner ``Q_cc + shift·I``."""
    crossing = robots[graph.tails] != robots[graph.heads]
    is_separator = np.zeros(graph.num_poses, dtype=bool)
    is_separator[graph.tails[crossing]] = True
    is_separator[graph.heads[crossing]] = True
    blocks = []
    for members in classes:
        owned = [np.flatnonzero(robots == robot) for robot in members]
        poses = np.concatenate(owned)
        robot_of_pose = np.repeat(np.arange(members.size), [p.size for p in owned])
        rows = pose_rows(poses)
        columns = q[:, rows].tocsr()  # Q symmetric: the class's columns
        reach_rows = np.flatnonzero(np.diff(columns.indptr))
        hessian = q[rows][:, rows].tocsr()  # no edge joins two robots of a class
        robot_nnz = np.bincount(
            np.repeat(robot_of_pose, 3), np.diff(hessian.indptr), minlength=members.size
        )
        blocks.append(
            ClassBlock(
                robots=members,
                poses=poses,
                robot_of_pose=robot_of_pose,
                hessian=hessian,
                preconditioner=CholeskyPreconditioner(hessian, shift),
                reach_rows=reach_rows,
                reach=columns[reach_rows],
                own_in_reach=np.searchsorted(reach_rows, rows),
                separators=int(np.count_nonzero(is_separator[poses])),
                robot_nnz=robot_nnz,
            )
        )
    return blocks


def batch_groups(members: np.ndarray, sizes: np.ndarray, batch_below: int) -> list[np.ndarray]:
    """Split a colour class ``members`` ``(k,)`` into update batches: every robot with at least
    ``batch_below`` poses (``sizes`` ``(n,)`` poses per robot) alone, the smaller ones together.

    Batching removes per-robot overhead but makes every batched robot pay for the slowest one's
    tCG iterations on the whole batch's arrays (measured: docs/rbcd.md, "Batching"). The results
    agree up to floating-point summation order.

    **Batched:** the robots of a class share no edge, so their
    problems are independent and are solved together as one block-diagonal problem (one ``Q_cc``
    product and one Cholesky solve of the class per tCG iteration), with every scalar of the
    trust-region / tCG iteration (radius, step, curvature, acceptance, stopping) kept per robot, so
    each robot follows exactly the iteration it would run alone (up to floating-point summation
    order). Only robots with fewer than ``BATCH_BELOW_POSES`` (300) poses are batched; larger ones,
    whose arrays are big enough to hide the per-call overhead, update one by one
    (:func:`batch_groups`).
    """
    small = sizes[members] < batch_below
    alone = [members[[i]] for i in np.flatnonzero(~small)]
    return alone + ([members[small]] if small.any() else [])


def colour_robots(graph: PoseGraph, robots: np.ndarray) -> list[np.ndarray]:
    """Greedy (largest degree first) colouring of the robot adjacency graph.

    Returns:
        The colour classes, each an array of robot ids no two of which share an edge.
    """
    count = int(robots.max()) + 1
    a, b = robots[graph.tails], robots[graph.heads]
    crossing = a != b
    adjacent = np.zeros((count, count), dtype=bool)
    adjacent[a[crossing], b[crossing]] = True
    adjacent |= adjacent.T
    colours = np.full(count, -1)
    for robot in np.argsort(-adjacent.sum(axis=1), kind="stable"):
        taken = set(colours[adjacent[robot]].tolist())
        colours[robot] = next(c for c in range(count) if c not in taken)
    return [np.flatnonzero(colours == c) for c in range(colours.max() + 1)]


class PerRobot:
    """Per-robot reductions and broadcasts over a class's poses (robot ``robot_of_pose[i]``
    owns pose ``i``): the vectorised tCG / RTR keep one scalar per robot."""

    def __init__(self, robot_of_pose: np.ndarray, num_robots: int) -> None:
        self.owner, self.count = robot_of_pose, num_robots

    def inner(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``⟨a_α, b_α⟩`` per robot, ``(k,)``, for ``a``, ``b`` ``(n_c, 3, r)``."""
        if self.count == 1:
            return np.array([np.vdot(a, b)])
        return np.bincount(self.owner, np.einsum("nkr,nkr->n", a, b), minlength=self.count)

    def spread(self, values: np.ndarray) -> np.ndarray:
        """Per-robot ``(k,)`` values broadcastable against ``(n_c, 3, r)`` (one robot: the
        ``(1,)`` array itself)."""
        return values if self.count == 1 else values[self.owner][:, None, None]
