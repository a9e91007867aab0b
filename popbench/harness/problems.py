"""Problems and optima shared by the experiments, built once per process.

The initial estimate of a table (``init``) is applied to every method alike: the problem's
``graph.poses`` holds it and every method is run with ``init="problem"``.
"""

from __future__ import annotations

from functools import lru_cache

from popbench import datasets
from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph

INITS = ("odometry", "chordal")


@lru_cache(maxsize=16)
def load_graph(dataset: str) -> PoseGraph:
    """The dataset's graph (a registered name or a path), its poses the file's estimate."""
    return datasets.load(dataset)


@lru_cache(maxsize=16)
def initial_poses(dataset: str, init: str):  # noqa: ANN201 - (N, 3) ndarray
    """The ``init`` estimate of a dataset: ``odometry`` composition or ``chordal``."""
    graph = load_graph(dataset)
    if init == "odometry":
        return graph.odometry_initial()
    if init == "chordal":
        from popbench.solvers.chordal import chordal_initialisation

        return chordal_initialisation(graph)
    raise ValueRangeError("initial estimate", init, " | ".join(INITS))


@lru_cache(maxsize=32)
def distributed_problem(
    dataset: str, robots: int, init: str, partition: str = "metis", seed: int = 0
) -> DistributedProblem:
    """The dataset split among ``robots`` robots, starting from the ``init`` estimate."""
    graph = load_graph(dataset).replace(poses=initial_poses(dataset, init))
    return DistributedProblem.from_graph(
        graph, robots, partition=partition, seed=seed, initial=init
    )


@lru_cache(maxsize=16)
def optimum(dataset: str) -> float:
    """F* of a dataset: the best F that the project's LM reaches from chordal initialisation."""
    from popbench.solvers.lm import reference_optimum

    return float(reference_optimum(load_graph(dataset)).F)
