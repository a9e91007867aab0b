"""``popbench plot trajectories | curves``: the paper's figures outside the experiments."""

from __future__ import annotations

from pathlib import Path

import typer

from popbench.cli import options
from popbench.errors import ValueRangeError
from popbench.harness import defaults

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
    init: str = typer.Option(defaults.INIT, help="Initial estimate: odometry | chordal | given."),
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
    "  popbench plot curves results/checkpoint-training/actor-V2-n7.metrics.csv\n\n"
    "  popbench plot curves runs/a/metrics.csv runs/b/metrics.csv --out results/figures/ab\n\n"
    "  popbench plot curves runs/cmp/* --problems 25 --out results/algorithms/curves "
    "--reference results/heldout-residual-s0,results/heldout-residual-s1",
)
def curves_command(
    paths: list[Path] = typer.Argument(
        ...,
        help="Training CSV files (one line each), or training run folders (popbench train "
        "--out; scored on held-out problems and averaged over seeds).",
    ),
    out: Path = typer.Option(
        Path("results/figures/learning_curves"), help="Output stem: writes STEM.png and STEM.pdf."
    ),
    problems: int = typer.Option(
        25,
        min=1,
        help="Run folders: the held-out problems each actor snapshot is scored on (the first "
        "PROBLEMS of popbench run heldout's; cached in RUN/curve.csv).",
    ),
    reference: str = typer.Option(
        "",
        help="Run folders: popbench run heldout folders (comma-separated, one per seed) whose "
        "gn-sweep, imitation and local-lm rows join the final table; their gn-sweep row is the "
        "zero of the normalised score (1: each problem's optimum F*).",
    ),
) -> None:
    """Learning curves: of training CSVs (every numeric column against frames, one line per
    file), or of run folders: each run's actor snapshots scored on held-out problems (median F,
    mean ATE, with --reference the normalised score), one line per algorithm and start with a
    95 % band over seeds; run folders also write STEM.csv (every score), STEM.md (the final
    table; with --reference the IQM and P(A > B) of the final actors, problems as tasks, drawn
    in STEM-comparison.png), STEM.marl-eval.json (the final actors, every problem a task) and
    STEM.learning.marl-eval.json (the snapshots), in marl-eval's raw-data layout. Two runs of
    the same algorithm, start and seed are refused; training CSVs of the same name are named by
    their folders."""
    for path in paths:
        if not path.exists():
            raise ValueRangeError("curves input", str(path), "an existing CSV file or run folder")
    folders = [path.is_dir() for path in paths]
    if any(folders) and not all(folders):
        raise ValueRangeError("curves inputs", "files and folders", "all CSV files or all folders")
    if all(folders):
        from popbench.harness.curves import write_curves

        references = [Path(name) for name in reference.split(",") if name]
        written = write_curves(paths, out, problems, references)
    else:
        from popbench.plotting import plot_learning_curves

        written = plot_learning_curves(paths, out)
    typer.echo(" ".join(str(p) for p in written))
