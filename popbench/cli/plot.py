"""``popbench plot trajectories | curves``: the paper's figures outside the experiments."""

from __future__ import annotations

from pathlib import Path

import typer

from popbench.cli import options
from popbench.errors import ValueRangeError

app = typer.Typer(help="Plot trajectories and learning curves.", no_args_is_help=True)


@app.command(
    "trajectories",
    epilog="Examples:\n\n"
    "  popbench plot trajectories intel --robots 7\n\n"
    "  popbench plot trajectories my.g2o --methods mm-pgo --iterations 200 --out fig/my",
)
def trajectories_command(
    dataset: str = typer.Argument(..., help="Dataset name or .g2o path."),
    robots: int = typer.Option(7, min=1, help="Team size."),
    methods: str = typer.Option("mm-pgo,prop-v1,prop-v2", help="Methods to plot."),
    iterations: int = typer.Option(1000, min=1, help="Rounds for the iterative methods."),
    init: str = typer.Option("odometry", help="Initial estimate: odometry | chordal | given."),
    out: Path = typer.Option(
        None,
        help="Output stem: writes STEM.png and STEM.pdf "
        "(default: results/figures/trajectories_DATASET).",
        show_default=False,
    ),
) -> None:
    """The paper's Fig. 4: initial and optimised estimates, one colour per robot."""
    from popbench.harness.figures import plot_trajectories

    stem = out or Path("results/figures") / f"trajectories_{Path(dataset).stem}"
    paths = plot_trajectories(
        dataset, robots, options.methods(methods), stem, iterations, options.start(init)
    )
    typer.echo(" ".join(str(p) for p in paths))


@app.command(
    "curves",
    epilog="Examples:\n\n"
    "  popbench plot curves agents/checkpoints/actor-V2-n7.metrics.csv\n\n"
    "  popbench plot curves runs/a/metrics.csv runs/b/metrics.csv --out results/figures/ab",
)
def curves_command(
    csv: list[Path] = typer.Argument(..., help="Training CSV files (popbench train writes them)."),
    out: Path = typer.Option(
        Path("results/figures/learning_curves"), help="Output stem: writes STEM.png and STEM.pdf."
    ),
) -> None:
    """Learning curves from training CSVs, one line per file."""
    from popbench.harness.figures import plot_learning_curves

    for path in csv:
        if not path.exists():
            raise ValueRangeError("CSV file", str(path), "an existing file")
    paths = plot_learning_curves(csv, out)
    typer.echo(" ".join(str(p) for p in paths))
