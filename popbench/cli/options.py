"""Option definitions and value parsers shared by the commands.

Lists are comma-separated (``--datasets intel,mit --robots 3,7``); every parser raises
:class:`~popbench.errors.ValueRangeError` (one line, exit status 2) on a bad value. The
``Annotated`` aliases (:data:`Jobs`, :data:`Executor`, :data:`Address`, :data:`Threads`,
:data:`Fresh`, :data:`Iterations`, :data:`Out`, :data:`Init`, :data:`TeamSizes`) give every
experiment the same option with the same help; :func:`runs_cells` gives an experiment command
the run options at once, as one :class:`~popbench.harness.executors.Run`.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from popbench.errors import ValueRangeError
from popbench.harness.executors import (
    ADDRESS_HELP,
    EXECUTOR_HELP,
    JOBS_HELP,
    THREADS_HELP,
    Run,
)

CACHE_HELP = (
    "Cache: finished cells are kept in OUT/cells/ (one JSON file each), so an interrupted run "
    "resumes where it stopped. A cell is reused only if its options, the sha256 of its graph "
    "file, the code (package version + a hash of the popbench, baselines, agents and envs "
    "sources) and, for a method whose record names a checkpoint (prop-v1/prop-v2), the "
    "checkpoint's sha256 are unchanged; --fresh recomputes every cell. Delete OUT/cells/ to "
    "reclaim the space of old cells."
)
PARALLEL_HELP = (
    "Parallel: --jobs N cells at once (default: this machine's cores), each in its own worker "
    "process pinned to --threads threads (default 1), every finished cell cached at once; "
    "--executor ray [--address HEAD:6379] submits one Ray task per cell to a cluster (or a local "
    "Ray instance). Non-time columns do not depend on the executor; manifest.json records it."
)
FRESH_HELP = "Recompute every cell, ignoring (and overwriting) the cached ones in OUT/cells/."
COMMAND_THREADS_HELP = (
    "BLAS / OpenMP / torch threads, pinned whatever OMP_NUM_THREADS says (default 1: an "
    "unpinned torch pool competing for a busy core made prop-v1 16-53x slower)."
)

Jobs = Annotated[
    int | None, typer.Option("--jobs", "-j", min=1, help=JOBS_HELP, show_default=False)
]
Executor = Annotated[str, typer.Option(help=escape(EXECUTOR_HELP))]  # keep its "[ray]"
Address = Annotated[str | None, typer.Option(help=ADDRESS_HELP, show_default=False)]
Threads = Annotated[int, typer.Option(min=1, help=THREADS_HELP)]
CommandThreads = Annotated[int, typer.Option(min=1, help=COMMAND_THREADS_HELP)]
Fresh = Annotated[bool, typer.Option("--fresh", help=FRESH_HELP)]
Iterations = Annotated[int, typer.Option(min=1, help="Rounds for the iterative methods.")]
Out = Annotated[Path, typer.Option(help="Output folder.")]
Init = Annotated[
    str, typer.Option(help="Initial estimate for every method: odometry | chordal | given.")
]
TeamSizes = Annotated[str, typer.Option(help="Team sizes (comma list).")]


# The options of how an experiment's cells run, in --help's order, with their defaults.
RUN_OPTIONS = (
    ("fresh", Fresh, False),
    ("jobs", Jobs, None),
    ("executor", Executor, "process"),
    ("address", Address, None),
    ("threads", Threads, 1),
)


def runs_cells(command: Callable[..., None]) -> Callable[..., None]:
    """An experiment command (keyword-only parameters) with the options of :data:`RUN_OPTIONS`
    (--fresh, --jobs, --executor, --address, --threads) in place of its parameter ``run``, which
    receives them as one :class:`~popbench.harness.executors.Run` (typer reads the new
    ``__signature__``)."""
    signature = inspect.signature(command, eval_str=True)
    shared = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=kind)
        for name, kind, default in RUN_OPTIONS
    ]
    parameters = []
    for parameter in signature.parameters.values():
        parameters.extend(shared if parameter.name == "run" else [parameter])

    @functools.wraps(command)
    def with_run(**values: Any) -> None:
        fresh = values.pop("fresh")
        how = execution(
            values.pop("jobs"), values.pop("executor"), values.pop("address"), values.pop("threads")
        )
        command(**values, run=Run(execution=how, fresh=fresh))

    with_run.__signature__ = signature.replace(parameters=parameters)  # type: ignore[attr-defined]
    with_run.__annotations__ = {p.name: p.annotation for p in parameters}
    return with_run


def epilog(*examples: str) -> str:
    """An experiment's ``--help`` epilog: its examples, then the cache and the parallel notes."""
    lines = "\n\n".join(f"  {line}" for line in examples)
    return f"Examples:\n\n{lines}\n\n{CACHE_HELP}\n\n{PARALLEL_HELP}"


def names(text: str, allowed: tuple[str, ...] | None, what: str) -> tuple[str, ...]:
    """The comma-separated items of ``text``, each one of ``allowed`` (None: any)."""
    items = tuple(item.strip() for item in text.split(",") if item.strip())
    if not items:
        raise ValueRangeError(what, text, "a comma-separated, non-empty list")
    if allowed is not None:
        for item in items:
            if item not in allowed:
                raise ValueRangeError(what, item, " | ".join(allowed))
    return items


def integers(text: str, what: str, low: int = 1) -> tuple[int, ...]:
    """The comma-separated integers of ``text``, each ≥ ``low``."""
    try:
        values = tuple(int(item) for item in names(text, None, what))
    except ValueError:
        raise ValueRangeError(what, text, "comma-separated integers") from None
    for value in values:
        if value < low:
            raise ValueRangeError(what, value, f"integers ≥ {low}")
    return values


def rates(text: str) -> tuple[float, ...]:
    """The comma-separated outlier rates of ``text``, fractions in [0, 1]."""
    try:
        values = tuple(float(item) for item in names(text, None, "rate"))
    except ValueError:
        raise ValueRangeError("rate", text, "comma-separated fractions in [0, 1]") from None
    for value in values:
        if not 0.0 <= value <= 1.0:
            raise ValueRangeError("rate", value, "fractions in [0, 1] (0.1 = 10 %)")
    return values


def start(value: str) -> str:
    """``--init``: one of :data:`popbench.solvers.initial.STARTS`."""
    from popbench.solvers.initial import check_start

    return check_start(value, "--init")


def methods(text: str) -> tuple[str, ...]:
    """The comma-separated registered methods of ``text`` (:data:`popbench.methods.METHODS`)."""
    from popbench.methods import METHODS

    return names(text, tuple(METHODS), "method")


def execution(jobs: int | None, executor: str, address: str | None, threads: int):
    """The :class:`~popbench.harness.executors.Execution` of the --jobs, --executor, --address
    and --threads options."""
    from popbench.harness.executors import EXECUTORS, Execution

    name = names(executor, EXECUTORS, "--executor")[0]
    if address is not None and name != "ray":
        raise ValueRangeError("--address", address, "only with --executor ray")
    return Execution(jobs=jobs, executor=name, address=address, threads=threads)
