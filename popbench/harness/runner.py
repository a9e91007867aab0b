"""Run a list of table cells with a progress bar, skipping the cells already finished."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from popbench.harness.cache import CellCache

Spec = Mapping[str, Any]
Row = dict[str, Any]


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


def run_cells(
    specs: Sequence[Spec],
    compute: Callable[[Spec], Row],
    cache: CellCache,
    *,
    console: Console | None = None,
    progress: bool = True,
    fresh: bool = False,
) -> list[Row]:
    """Rows of all ``specs`` in order: cached rows are reused, the others computed and cached
    one by one (so an interrupted run loses at most the cell in flight). ``fresh`` ignores the
    cache: every cell is recomputed and its cached file overwritten."""
    rows: list[Row | None] = [None if fresh else cache.get(spec) for spec in specs]
    todo = [k for k, row in enumerate(rows) if row is None]
    console = console or Console(stderr=True)
    if len(todo) < len(specs):
        console.print(
            f"[dim]{len(specs) - len(todo)} of {len(specs)} cells already finished "
            f"(cached in {cache.folder})[/dim]"
        )
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console, disable=not progress or not todo) as bar:
        task = bar.add_task("cells", total=len(todo))
        for k in todo:
            bar.update(task, description=describe(specs[k]))
            row = compute(specs[k])
            cache.put(specs[k], row)
            rows[k] = row
            bar.advance(task)
    return [row for row in rows if row is not None]
