"""The ``popbench`` command line: the root app, one module per command group.

* :mod:`popbench.cli.datasets` — ``popbench datasets list | fetch | verify``
* :mod:`popbench.cli.solve` — ``popbench solve``
* :mod:`popbench.cli.train` — ``popbench train``, ``popbench train-gate``, ``popbench tasks``
  (``agents`` and ``envs`` loaded lazily, by name)
* :mod:`popbench.cli.run` — ``popbench run table1 | outliers | scalability | heldout``
* :mod:`popbench.cli.plot` — ``popbench plot trajectories | curves``
* :mod:`popbench.cli.options` — the shared options and value parsers
* :mod:`popbench.cli.errors` — every error as one line on stderr, with its exit status

Every command imports what it needs inside its body, so ``popbench --help`` loads only typer,
rich and the small core (no torch, matplotlib or solvers). ``python -m popbench`` and the
``popbench`` console script (``popbench.cli:main``) both run :func:`main`.
"""

from __future__ import annotations

from typing import Annotated

import typer

from popbench.cli import datasets, plot, run, solve, train
from popbench.cli.errors import run_safely

app = typer.Typer(
    name="popbench",
    help="Benchmark learned and classical distributed planar pose-graph optimisation (SE(2) PGO).",
    epilog=(
        "Examples:\n\n"
        "  popbench datasets list\n\n"
        "  popbench solve intel --method lm --init chordal\n\n"
        "  popbench solve my_graph.g2o --method lm --json\n\n"
        "  popbench run table1 --quick\n\n"
        "  popbench run heldout --robots 3 --problems 10 --json\n\n"
        "Data: registered datasets are read from $POPBENCH_DATA, else ~/.cache/popbench, and "
        "downloaded there (sha256-checked) when missing."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(datasets.app, name="datasets")
app.command("solve", epilog=solve.EPILOG)(solve.solve_command)
app.command("train", epilog=train.EPILOG)(train.train_command)
app.command("train-gate", epilog=train.GATE_EPILOG)(train.train_gate_command)
app.command("tasks", epilog=train.TASKS_EPILOG)(train.tasks_command)
app.add_typer(run.app, name="run")
app.add_typer(plot.app, name="plot")


def _version(value: bool) -> None:
    if value:
        from popbench import __version__

        typer.echo(f"popbench {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
) -> None:
    """Benchmark learned and classical distributed planar pose-graph optimisation (SE(2) PGO)."""


def main(argv: list[str] | None = None) -> int:
    """Run the CLI on ``argv`` (None: ``sys.argv``); every error becomes one
    ``popbench: error: …`` line on stderr (:mod:`popbench.cli.errors`)."""
    return run_safely(app, argv)
