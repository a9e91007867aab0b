"""Problems and optima shared by the experiments, built once per process.

The initial estimate of a table (its ``init`` option, a name of
:data:`popbench.solvers.initial.STARTS`) is applied to every method alike: the problem carries it
(:func:`popbench.solvers.initial.with_start`) and every method starts from the problem's poses.

Each result is remembered per dataset *and* the sha256 of its file, so a graph file edited
while the process runs is read again rather than served from memory.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import lru_cache

from popbench import datasets
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.harness.cache import dataset_sha256
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.initial import check_start, with_start


def _sha(dataset: str) -> str | None:
    """The file's sha256, or None when there is no such file (the loader then says why)."""
    try:
        return dataset_sha256(dataset)
    except OSError:
        return None


def load_graph(dataset: str) -> PoseGraph:
    """The dataset's graph (a registered name or a path), its poses the file's estimate."""
    return _load_graph(dataset, _sha(dataset))


def distributed_problem(
    dataset: str, robots: int, init: str, partition: str = "metis", seed: int = 0
) -> DistributedProblem:
    """The dataset split among ``robots`` robots, carrying the ``init`` start (a name of
    :data:`popbench.solvers.initial.STARTS`; ValueRangeError otherwise)."""
    check_start(init, "initial estimate")
    return _distributed_problem(dataset, _sha(dataset), robots, init, partition, seed)


def optimum(dataset: str) -> float:
    """F* of a dataset: the best F that the project's LM reaches from chordal initialisation."""
    return _optimum(dataset, _sha(dataset))


def chordal_optimum(dataset: str) -> float:
    """F_chordal* of a dataset (:func:`popbench.solvers.lm.chordal_optimum`)."""
    return _chordal_optimum(dataset, _sha(dataset))


def check_inputs(names: Iterable[str], robots: Iterable[int], option: str = "--robots") -> None:
    """Before anything is computed: load every dataset with the loader the cells use (raising
    its one-line DatasetError or DataFormatError) and check that every team size is at most
    the dataset's number of poses (ValueRangeError)."""
    poses = {name: load_graph(name).num_poses for name in names}  # every file first
    most = max(robots)
    for name, count in poses.items():
        if most > count:
            raise ValueRangeError(option, most, f"integers ≤ {count} (the poses of {name})")


@lru_cache(maxsize=16)
def _load_graph(dataset: str, sha256: str | None) -> PoseGraph:
    return datasets.load(dataset)


@lru_cache(maxsize=16)
def _started_graph(dataset: str, sha256: str | None, init: str) -> PoseGraph:
    return with_start(_load_graph(dataset, sha256), init)


@lru_cache(maxsize=32)
def _distributed_problem(
    dataset: str, sha256: str | None, robots: int, init: str, partition: str, seed: int
) -> DistributedProblem:
    graph = _started_graph(dataset, sha256, init)
    return DistributedProblem.from_graph(graph, robots, partition=partition, seed=seed, start=init)


@lru_cache(maxsize=16)
def _optimum(dataset: str, sha256: str | None) -> float:
    from popbench.solvers.lm import reference_optimum

    return float(reference_optimum(_load_graph(dataset, sha256)).F)


@lru_cache(maxsize=16)
def _chordal_optimum(dataset: str, sha256: str | None) -> float:
    from popbench.solvers.lm import chordal_optimum

    return chordal_optimum(_load_graph(dataset, sha256))
