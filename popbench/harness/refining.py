"""Cells of a method that refines another (:attr:`popbench.methods.MethodRecord.refines`) start
from the refined method's cached result of the same cell instead of recomputing it.

The refined method's cell is the refiner's specification with ``method`` (and the provenance of
that method: code, dataset and checkpoint) replaced (:func:`refined_spec`): the same dataset,
robots, seed, start, iterations and options, i.e. exactly the key its own table cell has. A cell
of a method that some record refines stores its whole :class:`~popbench.methods.Result` beside
its row (:meth:`popbench.harness.cache.CellCache.put_result`); the refiner's cell reads it, and
when it is missing computes that cell first, in the same worker, and caches its row and result.
The refiner's solve function gets it as ``refined=`` and reports its time as the refined
method's time plus the refinement's own (``wall_s`` and ``parallel_s``), so its row reads as if
it had run from scratch.

The cache a cell may use is the one :func:`popbench.harness.executors.run_cell` installs while it
computes (:func:`cell_cache`): the run's cell folder where the worker sees it (serial, process
and local Ray runs), none elsewhere (a Ray node without the driver's disk, or a cell computed
outside a run): then the refined method is computed in-process and not cached. The runner
submits a refiner's cell only after the refined method's cell of the same run has finished
(:func:`popbench.harness.runner.run_cells`, ``depends``), so parallel workers never compute it
twice.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from popbench.harness.cache import CellCache, provenance
from popbench.methods import METHODS, Budget, Result, get_method
from popbench.problems.distributed import DistributedProblem

Spec = Mapping[str, Any]
RowOf = Callable[[Spec, DistributedProblem, Result], dict[str, Any]]

# The cache (and the timing record stored beside its rows) of the cell being computed.
_CURRENT: contextvars.ContextVar[tuple[CellCache, Mapping[str, Any] | None] | None] = (
    contextvars.ContextVar("popbench_cell_cache", default=None)
)


@contextlib.contextmanager
def using_cache(
    cache: CellCache | None, measured: Mapping[str, Any] | None = None
) -> Iterator[None]:
    """While the block runs, :func:`cell_cache` is ``cache`` (None: no cache) and the rows it
    stores are recorded as ``measured`` (:meth:`popbench.harness.executors.Execution.record`)."""
    token = _CURRENT.set(None if cache is None else (cache, measured))
    try:
        yield
    finally:
        _CURRENT.reset(token)


def cell_cache() -> tuple[CellCache, Mapping[str, Any] | None] | None:
    """The cache installed by :func:`using_cache` and its timing record, or None."""
    return _CURRENT.get()


def is_refined(method: str) -> bool:
    """Whether some registered method refines ``method`` (so its cells keep their Result)."""
    return any(record.refines == method for record in METHODS.values())


def refined_spec(spec: Spec) -> Spec | None:
    """The specification of the cell that ``spec``'s method refines (same everything, the
    refined method and its provenance), or None when its method refines nothing."""
    method = spec.get("method")
    if method not in METHODS or METHODS[method].refines is None:
        return None
    refined = METHODS[method].refines
    inputs = provenance(spec["dataset"], refined, spec.get("training_seed", 0))
    spec_inputs = {key: value for key, value in spec.items() if key != "checkpoint_sha256"}
    return {**spec_inputs, **inputs, "method": refined}


def solve_cell(
    spec: Spec,
    problem: DistributedProblem,
    budget: Budget,
    options: Mapping[str, Any],
    row_of: RowOf,
) -> Result:
    """Run ``spec["method"]`` on ``problem`` with ``options``; a refiner starts from the refined
    method's result of the same cell (cached, or computed and cached here, with its row
    ``row_of(spec, problem, result)``); a refined method's result is cached beside its row."""
    method = spec["method"]
    current = cell_cache()
    extra: dict[str, Any] = {}
    dependency = refined_spec(spec)
    if dependency is not None:
        found = current[0].result(dependency) if current is not None else None
        if found is None:
            found = solve_cell(dependency, problem, budget, options, row_of)
            if current is not None:
                current[0].put(dependency, row_of(dependency, problem, found), measured=current[1])
        extra["refined"] = found
    result = get_method(method)(problem, budget, **options, **extra)
    if current is not None and is_refined(method):
        current[0].put_result(spec, result)
    return result
