"""Multi-robot problems: a pose graph whose vertices are assigned to robots."""

from __future__ import annotations

import dataclasses

import numpy as np

from popbench.graph import PoseGraph


@dataclasses.dataclass(frozen=True, eq=False)
class DistributedProblem:
    """A pose graph split among robots; every method solves one.

    Attributes:
        graph: the global graph. ``graph.poses`` is the initial estimate, ``graph.robots`` the
            ``(N,)`` vertex → robot assignment and ``graph.kinds`` the edge labels under it.
        initial: how ``graph.poses`` was made (``"odometry"``, ``"chordal"``, ``"file"``, ...).
        outlier_mask: ``(M,)`` bool, True for injected outlier edges, or None.
    """

    graph: PoseGraph
    initial: str = "odometry"
    outlier_mask: np.ndarray | None = None

    @property
    def num_robots(self) -> int:
        return self.graph.num_robots

    @classmethod
    def single_robot(cls, graph: PoseGraph, initial: str = "odometry") -> DistributedProblem:
        """The whole graph on one robot."""
        return cls(graph.replace(robots=np.zeros(graph.num_poses, dtype=np.int64)), initial)
