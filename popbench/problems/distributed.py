"""Multi-robot problems: a pose graph whose vertices are assigned to robots.

Local graphs (paper Fig. 1): robot ``r`` owns the vertices assigned to it and holds every edge with
at least one endpoint it owns, so an inter-robot edge appears in both robots' local graphs. The
non-owned endpoints of its edges are *separator copies*: duplicated poses that a consensus step
(:mod:`popbench.consensus.admm`) reconciles. A local graph lists its vertices as the owned ids
(ascending) followed by the separator copies (ascending global id).

Derived views are computed once per problem (``functools.cached_property`` works on this frozen,
slot-less dataclass because it writes to the instance ``__dict__`` directly).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from popbench.graph import PoseGraph


@dataclasses.dataclass(frozen=True, eq=False)
class LocalGraph:
    """One robot's view of a :class:`DistributedProblem`.

    Attributes:
        robot: the robot id ``r``.
        graph: the local pose graph with local vertex ids ``0..n_r-1`` (owned first, then
            separator copies): poses, ground truth and ``robots`` (the global owner of each local
            vertex) are slices of the global ones; edges keep their global kinds and information.
        global_ids: ``(n_r,)`` global id of each local vertex.
        owned_count: number of owned vertices; ``global_ids[:owned_count]`` are owned.
        edge_ids: ``(m_r,)`` global id of each local edge (ascending).
    """

    robot: int
    graph: PoseGraph
    global_ids: np.ndarray
    owned_count: int
    edge_ids: np.ndarray

    @property
    def owned_ids(self) -> np.ndarray:
        """``(owned_count,)`` global ids of the owned vertices."""
        return self.global_ids[: self.owned_count]

    @property
    def separator_ids(self) -> np.ndarray:
        """Global ids of the separator copies (non-owned local vertices)."""
        return self.global_ids[self.owned_count :]

    @property
    def num_vertices(self) -> int:
        return int(self.global_ids.size)


@dataclasses.dataclass(frozen=True, eq=False)
class DistributedProblem:
    """A pose graph split among robots; every method solves one.

    Attributes:
        graph: the global graph. ``graph.poses`` is the initial estimate, ``graph.robots`` the
            ``(N,)`` vertex → robot assignment (robot 0 owns vertex 0, the gauge) and
            ``graph.kinds`` the edge labels under it.
        start: the name of the start ``graph.poses`` holds (one of
            :data:`popbench.solvers.initial.STARTS`; :func:`popbench.solvers.initial.with_start`
            makes it). Every method starts from ``graph.poses``; the name is recorded, not used to
            recompute.
        outlier_mask: ``(M,)`` bool, True for injected outlier edges, or None.
    """

    graph: PoseGraph
    start: str = "odometry"
    outlier_mask: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.graph.robots is None:  # an unassigned graph is a single-robot problem
            robots = np.zeros(self.graph.num_poses, dtype=np.int64)
            object.__setattr__(self, "graph", self.graph.replace(robots=robots))

    @property
    def num_robots(self) -> int:
        return self.graph.num_robots

    @classmethod
    def single_robot(cls, graph: PoseGraph, start: str = "odometry") -> DistributedProblem:
        """The whole graph on one robot (its poses the ``start`` estimate, by name)."""
        return cls(graph.replace(robots=np.zeros(graph.num_poses, dtype=np.int64)), start)

    @classmethod
    def from_graph(
        cls,
        graph: PoseGraph,
        robots: int | np.ndarray,
        partition: str = "metis",
        seed: int = 0,
        start: str = "odometry",
        outlier_mask: np.ndarray | None = None,
    ) -> DistributedProblem:
        """Split ``graph`` among robots and relabel its edge kinds.

        Args:
            graph: the global pose graph (its poses are the initial estimate).
            robots: a number of robots ``n`` (``1 ≤ n ≤ N``), split by ``partition``, or an
                explicit ``(N,)`` vertex → robot assignment (then ``partition``/``seed`` are
                unused).
            partition: ``"metis"`` (default) or ``"contiguous"``
                (see :mod:`popbench.problems.partition`).
            seed: METIS seed.
            start: the name of the start ``graph.poses`` holds (see
                :func:`popbench.solvers.initial.with_start`, which makes it).
            outlier_mask: ``(M,)`` ground-truth outlier flags, if any.

        Raises:
            ValueRangeError: ``robots`` outside ``[1, N]``, an unknown partition method or a
                malformed assignment.
        """
        from popbench.problems import partition as partitioning

        if isinstance(robots, np.ndarray):
            assignment = robots
        else:
            assignment = partitioning.partition(graph, robots, partition, seed)
        return cls(partitioning.assign(graph, assignment), start, outlier_mask)

    # ----- derived views (computed once) -------------------------------------------------------

    @property
    def robots(self) -> np.ndarray:
        """``(N,)`` owning robot of each vertex."""
        return self.graph.robots

    def owned(self, robot: int) -> np.ndarray:
        """Global ids owned by ``robot``, ascending."""
        return self.local_graph(robot).owned_ids

    def local_edges(self, robot: int) -> np.ndarray:
        """Ids of the edges with at least one endpoint owned by ``robot``, ascending."""
        return self.local_graph(robot).edge_ids

    def local_vertices(self, robot: int) -> np.ndarray:
        """Global ids of ``robot``'s local vertices: owned ids, then separator copies."""
        return self.local_graph(robot).global_ids

    def local_graph(self, robot: int) -> LocalGraph:
        """``robot``'s local graph (see :class:`LocalGraph`)."""
        return self.local_graphs[robot]

    @functools.cached_property
    def inter_robot_edges(self) -> np.ndarray:
        """Ids of the edges whose endpoints belong to different robots."""
        robots = self.graph.robots
        return np.flatnonzero(robots[self.graph.tails] != robots[self.graph.heads])

    @functools.cached_property
    def separators(self) -> np.ndarray:
        """Global ids present in more than one local graph (endpoints of inter-robot edges)."""
        edges = self.inter_robot_edges
        return np.unique(np.concatenate([self.graph.tails[edges], self.graph.heads[edges]]))

    @functools.cached_property
    def local_graphs(self) -> tuple[LocalGraph, ...]:
        """Every robot's local graph, indexed by robot id."""
        graph = self.graph
        robots = graph.robots
        n = self.num_robots
        owner_tail, owner_head = robots[graph.tails], robots[graph.heads]
        edge_ids = np.arange(graph.num_edges)
        crossing = owner_tail != owner_head
        # (robot, edge) membership: every edge for its tail's owner, crossing edges also for the
        # head's owner; sorted by robot, then edge id.
        member_robot = np.concatenate([owner_tail, owner_head[crossing]])
        member_edge = np.concatenate([edge_ids, edge_ids[crossing]])
        order = np.lexsort((member_edge, member_robot))
        edges_per_robot = np.split(
            member_edge[order], np.cumsum(np.bincount(member_robot, None, n))[:-1]
        )
        vertex_order = np.argsort(robots, kind="stable")
        owned_per_robot = np.split(vertex_order, np.cumsum(np.bincount(robots, None, n))[:-1])
        return tuple(
            self._build_local(robot, owned_per_robot[robot], edges_per_robot[robot])
            for robot in range(n)
        )

    def _build_local(self, robot: int, owned: np.ndarray, edges: np.ndarray) -> LocalGraph:
        graph = self.graph
        endpoints = np.concatenate([graph.tails[edges], graph.heads[edges]])
        copies = np.unique(endpoints[graph.robots[endpoints] != robot])
        global_ids = np.concatenate([owned, copies])
        local_of = np.full(graph.num_poses, -1, dtype=np.int64)
        local_of[global_ids] = np.arange(global_ids.size)
        local = PoseGraph(
            poses=graph.poses[global_ids],
            tails=local_of[graph.tails[edges]],
            heads=local_of[graph.heads[edges]],
            measurements=graph.measurements[edges],
            information=graph.information[edges],
            kinds=graph.kinds[edges],
            ground_truth=None if graph.ground_truth is None else graph.ground_truth[global_ids],
            robots=graph.robots[global_ids],
            name=f"{graph.name}/robot{robot}",
        )
        return LocalGraph(robot, local, global_ids, int(owned.size), edges)

    # ----- moving estimates between the global and local views ---------------------------------

    def split(self, poses: np.ndarray | None = None) -> list[np.ndarray]:
        """Local copies ``[(n_r, 3)]`` of a global estimate (default: the initial estimate)."""
        poses = self.graph.poses if poses is None else poses
        return [poses[local.global_ids] for local in self.local_graphs]

    def assemble(self, local_poses: list[np.ndarray]) -> np.ndarray:
        """Global ``(N, 3)`` estimate from local ones, each vertex taken from its owner.

        Args:
            local_poses: one ``(n_r, 3)`` array per robot, rows in ``local_vertices(r)`` order.
        """
        poses = np.empty((self.graph.num_poses, 3))
        for local, estimate in zip(self.local_graphs, local_poses, strict=True):
            poses[local.owned_ids] = estimate[: local.owned_count]
        return poses
