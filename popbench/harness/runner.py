"""Run a list of table cells with a progress bar, skipping the cells already finished."""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from popbench.harness.cache import CellCache, cell_key, code_fingerprint
from popbench.harness.executors import (
    CellTask,
    Execution,
    Row,
    Run,
    SerialExecutor,
    Spec,
    make_executor,
)
from popbench.harness.manifest import write_manifest
from popbench.harness.refining import refined_spec

RUNNING_SHOWN = 3  # running cells named in the progress bar; more are counted


Table = TypeVar("Table")


def describe(spec: Spec) -> str:
    """A short label of a cell for the progress bar (``intel n=7 mm-pgo seed 0``)."""
    parts = [
        str(spec.get("dataset", "")),
        f"n={spec['robots']}" if "robots" in spec else "",
        str(spec.get("method", "")),
        f"seed {spec['seed']}" if "seed" in spec else "",
    ]
    if "rate" in spec:
        parts.insert(1, f"{100 * spec['rate']:g}%")
    return " ".join(part for part in parts if part)


def _running(labels: list[str]) -> str:
    shown = ", ".join(labels[:RUNNING_SHOWN])
    more = len(labels) - RUNNING_SHOWN
    return shown + (f" +{more}" if more > 0 else "") if labels else "cells"


def run_cells(
    specs: Sequence[Spec],
    compute: Callable[[Spec], Row],
    cache: CellCache,
    *,
    execution: Execution | None = None,
    console: Console | None = None,
    progress: bool = True,
    fresh: bool = False,
    depends: Callable[[Spec], Spec | None] | None = None,
) -> list[Row]:
    """Rows of all ``specs`` in order: cached rows are reused, the others computed by the
    ``execution``'s executor (default: serially in this process) and cached as each finishes
    (so an interrupted run loses at most the cells in flight). ``fresh`` ignores the cache:
    every cell is recomputed and its cached file overwritten.

    For the process and Ray executors ``compute`` must be a module-level function (it is sent
    to the workers by name). Each cached file also records how its time was measured
    (:meth:`Execution.record`: executor, jobs, cores, threads).

    ``depends(spec)``, if given, is the cell that ``spec``'s cell starts from (a refining
    method's, :func:`popbench.harness.refining.refined_spec`) or None: such a cell is submitted
    only after that cell, if it is one of ``specs``, has finished; with ``fresh``, the cached
    ones that are not among ``specs`` are discarded, so they are recomputed too.
    """
    execution = execution or Execution.serial()
    rows: list[Row | None] = [None if fresh else cache.get(spec) for spec in specs]
    todo = deque(k for k, row in enumerate(rows) if row is None)
    keys = [cell_key(spec) for spec in specs]
    needs: dict[int, str] = {}  # cell -> key of the cell of this run it starts from
    for k, spec in enumerate(specs):
        dependency = depends(spec) if depends is not None else None
        if dependency is None:
            continue
        if cell_key(dependency) in keys:
            needs[k] = cell_key(dependency)
        elif fresh:
            cache.discard(dependency)
    computed = len(todo)
    console = console or Console(stderr=True)
    if len(todo) < len(specs):
        console.print(
            f"[dim]{len(specs) - len(todo)} of {len(specs)} cells already finished "
            f"(cached in {cache.folder})[/dim]"
        )
    if not todo:
        return [row for row in rows if row is not None]
    executor = make_executor(execution, len(todo))
    serial = isinstance(executor, SerialExecutor)
    measured = execution.record(executor.workers)
    code = None if serial else code_fingerprint()
    folder = cache.folder if executor.writes_cache else None
    unfinished = {keys[k] for k in todo}

    def ready(k: int) -> bool:
        return needs.get(k) not in unfinished

    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    pending: dict[Any, int] = {}
    started = time.perf_counter()
    failed = True
    try:
        with Progress(*columns, console=console, disable=not progress) as bar:
            task = bar.add_task("cells", total=len(todo))
            while todo or pending:
                while len(pending) < executor.workers:
                    k = next((j for j in todo if ready(j)), None)
                    if k is None:
                        break
                    todo.remove(k)
                    labels = [describe(specs[j]) for j in pending.values()]
                    bar.update(task, description=_running([*labels, describe(specs[k])]))
                    cell = CellTask(
                        compute, specs[k], folder, execution.threads, code, measured, cache.folder
                    )
                    pending[executor.submit(cell)] = k
                for handle in executor.wait(list(pending)):
                    k = pending.pop(handle)
                    row = executor.result(handle)
                    if not executor.writes_cache:
                        cache.put(specs[k], row, measured=measured)
                    rows[k] = row
                    unfinished.discard(keys[k])
                    bar.advance(task)
                    bar.update(
                        task, description=_running([describe(specs[j]) for j in pending.values()])
                    )
        failed = False
    finally:
        executor.close(cancel=failed)
    if not serial:
        console.print(
            f"[dim]{computed} cells, {executor.workers} at once "
            f"({execution.executor}): {time.perf_counter() - started:.1f} s[/dim]"
        )
    return [row for row in rows if row is not None]


def execution_summary(execution: Execution, cache: CellCache, specs: Sequence[Spec]) -> dict:
    """The manifest's ``execution`` block: how this invocation ran (executor, jobs, threads,
    cores, address) and how the times of the table's cells were measured — ``beside_others``
    counts the cells timed while other cells ran at once on the same machine or cluster
    (``jobs`` > 1), whose wall and parallel times include that contention; ``unrecorded`` the
    cells cached before this was recorded."""
    jobs = 1 if execution.executor == "serial" else execution.jobs or os.cpu_count() or 1
    records = [cache.measured(spec) for spec in specs]
    beside = sum(1 for record in records if record is not None and record.get("jobs", 1) > 1)
    return {
        **execution.record(jobs),
        "cells": len(specs),
        "beside_others": beside,
        "unrecorded": sum(1 for record in records if record is None),
        "note": f"{beside} of {len(specs)} cells were timed while other cells ran at once "
        "(jobs > 1): their wall_s and parallel_s include that contention",
    }


def run_experiment(
    out: Path,
    cells: Callable[[], Sequence[Spec]],
    compute: Callable[[Spec], Row],
    write: Callable[[list[Row]], Table],
    run: Run | None = None,
    depends: Callable[[Spec], Spec | None] | None = refined_spec,
) -> Table:
    """Run an experiment into the folder ``out`` and return its table: ``cells()`` checks the
    inputs and lists the cells, which are computed or reused as ``run`` says (:func:`run_cells`,
    cached under ``out/cells``; ``depends`` as there, by default a refining method's cell waits
    for the refined method's, :func:`popbench.harness.refining.refined_spec`, so that no two
    workers compute it); ``write(rows)`` writes the outputs into
    ``out`` (created first) and returns the table; ``manifest.json`` records the wall time of
    all of it and how the cells ran (:func:`execution_summary`)."""
    run = run or Run()
    started = time.perf_counter()
    specs = cells()
    cache = CellCache(out / "cells")
    rows = run_cells(
        specs,
        compute,
        cache,
        execution=run.execution,
        progress=run.progress,
        fresh=run.fresh,
        depends=depends,
    )
    ran = execution_summary(run.execution, cache, specs)
    out.mkdir(parents=True, exist_ok=True)
    table = write(rows)
    write_manifest(out, wall_s=time.perf_counter() - started, execution=ran)
    return table
