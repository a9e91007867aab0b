"""``popbench run ...`` and ``popbench plot ...``: the harness commands.

Lists are comma-separated (``--datasets intel,mit --robots 3,7``). Finished cells are cached
under ``OUT/cells``, keyed by the cell's options and by what it was computed from (the sha256
of the graph file, a fingerprint of the code, the actor checkpoint's sha256 for prop-v1/v2):
re-running a command recomputes nothing that finished with the same inputs, so an interrupted
run resumes where it stopped; ``--fresh`` recomputes every cell.
"""

from __future__ import annotations

from pathlib import Path

import typer

from popbench.errors import ValueRangeError
from popbench.harness.executors import ADDRESS_HELP, EXECUTOR_HELP, JOBS_HELP, THREADS_HELP

run_app = typer.Typer(
    help="Run the paper's experiments; write CSV, markdown, LaTeX and figures.",
    no_args_is_help=True,
)
plot_app = typer.Typer(help="Plot trajectories and learning curves.", no_args_is_help=True)

CACHE_HELP = (
    "Cache: finished cells are kept in OUT/cells/ (one JSON file each), so an interrupted run "
    "resumes where it stopped. A cell is reused only if its options, the sha256 of its graph "
    "file, the code (package version + a hash of the popbench, baselines, agents and envs "
    "sources) and, for prop-v1/prop-v2, the actor checkpoint's sha256 are unchanged; --fresh "
    "recomputes every cell. Delete OUT/cells/ to reclaim the space of old cells."
)


PARALLEL_HELP = (
    "Parallel: --jobs N cells at once (default: this machine's cores), each in its own worker "
    "process pinned to --threads threads (default 1), every finished cell cached at once; "
    "--executor ray [--address HEAD:6379] submits one Ray task per cell to a cluster (or a local "
    "Ray instance). Non-time columns do not depend on the executor; manifest.json records it."
)


def _epilog(*examples: str) -> str:
    return (
        "Examples:\n\n"
        + "\n\n".join(f"  {line}" for line in examples)
        + "\n\n"
        + CACHE_HELP
        + "\n\n"
        + PARALLEL_HELP
    )


FRESH_HELP = "Recompute every cell, ignoring (and overwriting) the cached ones in OUT/cells/."


def _names(text: str, allowed: tuple[str, ...] | None, what: str) -> tuple[str, ...]:
    items = tuple(item.strip() for item in text.split(",") if item.strip())
    if not items:
        raise ValueRangeError(what, text, "a comma-separated, non-empty list")
    if allowed is not None:
        for item in items:
            if item not in allowed:
                raise ValueRangeError(what, item, " | ".join(allowed))
    return items


def _integers(text: str, what: str, low: int = 1) -> tuple[int, ...]:
    try:
        values = tuple(int(item) for item in _names(text, None, what))
    except ValueError:
        raise ValueRangeError(what, text, "comma-separated integers") from None
    for value in values:
        if value < low:
            raise ValueRangeError(what, value, f"integers ≥ {low}")
    return values


def _rates(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(item) for item in _names(text, None, "rate"))
    except ValueError:
        raise ValueRangeError("rate", text, "comma-separated fractions in [0, 1]") from None
    for value in values:
        if not 0.0 <= value <= 1.0:
            raise ValueRangeError("rate", value, "fractions in [0, 1] (0.1 = 10 %)")
    return values


def _init(value: str) -> str:
    from popbench.initial import check_start

    return check_start(value, "--init")


def _execution(jobs: int | None, executor: str, address: str | None, threads: int):
    """The Execution of the --jobs, --executor, --address and --threads options."""
    from popbench.harness.executors import EXECUTORS, Execution

    name = _names(executor, EXECUTORS, "--executor")[0]
    if address is not None and name != "ray":
        raise ValueRangeError("--address", address, "only with --executor ray")
    return Execution(jobs=jobs, executor=name, address=address, threads=threads)


def _methods(text: str) -> tuple[str, ...]:
    from popbench.methods import METHODS

    return _names(text, tuple(METHODS), "method")


@run_app.command(
    "table1",
    epilog=_epilog(
        "popbench run table1 --quick                      # mit, n = 3, 100 rounds",
        "popbench run table1 --jobs 1                     # one cell at a time",
        "popbench run table1 --executor ray --address HEAD:6379",
        "popbench run table1 --datasets intel,my.g2o --robots 3,7 --methods mm-pgo "
        "--out results/mine",
    ),
)
def table1_command(
    datasets: str = typer.Option(
        None,
        help="Datasets, registered names or .g2o paths (default: the paper's eight; --quick: mit).",
        show_default=False,
    ),
    robots: str = typer.Option(
        None, help="Team sizes (default: 3,7,35; --quick: 3).", show_default=False
    ),
    methods: str = typer.Option(
        None,
        help="Methods (default: every registered method that is not centralised: "
        "cc-pgo, ml-pgo, mm-pgo, prop-v1, prop-v2, local-lm).",
        show_default=False,
    ),
    iterations: int = typer.Option(
        None,
        min=1,
        help="Rounds for the iterative methods (default: 1000; --quick: 100).",
        show_default=False,
    ),
    seeds: str = typer.Option("0", help="Seeds (partition, lifting, sampling)."),
    init: str = typer.Option(
        "odometry", help="Initial estimate for every method: odometry | chordal | given."
    ),
    partition: str = typer.Option("metis", help="metis | contiguous."),
    out: Path = typer.Option(
        None,
        help="Output folder (default: results/table1; --quick: results/table1-quick).",
        show_default=False,
    ),
    quick: bool = typer.Option(
        False,
        "--quick",
        help="A small subset (mit, n = 3, 100 iterations) that finishes in about a minute; "
        "--datasets, --robots, --iterations and the other options given replace its defaults.",
    ),
    fresh: bool = typer.Option(False, "--fresh", help=FRESH_HELP),
    jobs: int = typer.Option(None, "--jobs", "-j", min=1, help=JOBS_HELP, show_default=False),
    executor: str = typer.Option("process", help=EXECUTOR_HELP),
    address: str = typer.Option(None, help=ADDRESS_HELP, show_default=False),
    threads: int = typer.Option(1, min=1, help=THREADS_HELP),
) -> None:
    """The paper's Table I: datasets × robots × methods, with F* and the gap F/F* − 1.

    Writes OUT/table1.csv (one row per cell), table1.md, table1.tex (ours beside the paper's
    numbers) and table1.png/.pdf. Every dataset is loaded and every team size checked before
    anything is computed.
    """
    from popbench.harness.table1 import Table1Config, run_table1

    options: dict = {
        "seeds": _integers(seeds, "seed", 0),
        "init": _init(init),
        "partition": _names(partition, ("metis", "contiguous"), "partition")[0],
    }
    if methods is not None:
        options["methods"] = _methods(methods)
    if datasets is not None:
        options["datasets"] = _names(datasets, None, "dataset")
    if robots is not None:
        options["robots"] = _integers(robots, "robots")
    if iterations is not None:
        options["iterations"] = iterations
    if out is not None:
        options["out"] = out
    config = Table1Config.quick(**options) if quick else Table1Config(**options)
    frame = run_table1(config, fresh=fresh, execution=_execution(jobs, executor, address, threads))
    typer.echo(
        f"{len(frame)} cells -> {config.out}/table1.csv, table1.md, table1.tex, "
        "table1.png, table1.pdf"
    )


@run_app.command(
    "outliers",
    epilog=_epilog(
        "popbench run outliers --rate 0.025,0.05,0.1       # the paper's Table II",
        "popbench run outliers --datasets intel --seeds 0 --iterations 100 --out results/o",
    ),
)
def outliers_command(
    rate: str = typer.Option("0.1", help="Outlier rates (fractions), e.g. 0.025,0.05,0.1."),
    datasets: str = typer.Option("intel,mit,csail", help="Datasets."),
    methods: str = typer.Option("prop-v1,mm-pgo,gnc", help="Methods (need an inlier mask)."),
    robots: int = typer.Option(7, min=1, help="Team size."),
    seeds: str = typer.Option("0,1,2", help="Seeds: outlier draw and methods."),
    iterations: int = typer.Option(1000, min=1, help="Rounds for the iterative methods."),
    kernel: str = typer.Option("gm", help="mm-pgo robust kernel: huber | gm | welsch."),
    init: str = typer.Option(
        "odometry", help="odometry | chordal (made from the corrupted data) | given (the file's)."
    ),
    candidates: str = typer.Option(
        "loops",
        help="Edges that may be corrupted: loops (loop closures; odometry, incl. cut odometry, "
        "never) | paper (loop closures + every inter-robot edge: breaks the odometry start).",
    ),
    out: Path = typer.Option(Path("results/outliers"), help="Output folder."),
    fresh: bool = typer.Option(False, "--fresh", help=FRESH_HELP),
    jobs: int = typer.Option(None, "--jobs", "-j", min=1, help=JOBS_HELP, show_default=False),
    executor: str = typer.Option("process", help=EXECUTOR_HELP),
    address: str = typer.Option(None, help=ADDRESS_HELP, show_default=False),
    threads: int = typer.Option(1, min=1, help=THREADS_HELP),
) -> None:
    """The paper's Table II: F, outlier precision and recall with corrupted loop closures.

    Writes OUT/outliers.csv, outliers.md and outliers.tex. Every dataset is loaded and the team
    size checked before anything is computed.
    """
    from popbench.harness.outliers import OutliersConfig, run_outliers
    from popbench.outliers import CANDIDATE_SETS

    config = OutliersConfig(
        datasets=_names(datasets, None, "dataset"),
        rates=_rates(rate),
        methods=_methods(methods),
        robots=robots,
        seeds=_integers(seeds, "seed", 0),
        iterations=iterations,
        init=_init(init),
        kernel=_names(kernel, ("huber", "gm", "welsch"), "kernel")[0],
        candidates=_names(candidates, tuple(CANDIDATE_SETS), "candidates")[0],
        out=out,
    )
    frame = run_outliers(
        config, fresh=fresh, execution=_execution(jobs, executor, address, threads)
    )
    typer.echo(f"{len(frame)} cells -> {config.out}/outliers.csv, outliers.md, outliers.tex")


@run_app.command(
    "scalability",
    epilog=_epilog(
        "popbench run scalability                            # m3500, n = 1 … 70",
        "popbench run scalability --dataset intel --robots 1,3,7 --methods mm-pgo --out results/s",
    ),
)
def scalability_command(
    dataset: str = typer.Option("m3500", help="Dataset."),
    robots: str = typer.Option("1,2,3,5,7,10,14,20,28,35,50,70", help="Team sizes."),
    methods: str = typer.Option("mm-pgo,prop-v1,prop-v2", help="Methods."),
    iterations: int = typer.Option(1000, min=1, help="Rounds for the iterative methods."),
    init: str = typer.Option("odometry", help="Initial estimate: odometry | chordal | given."),
    out: Path = typer.Option(Path("results/scalability"), help="Output folder."),
    fresh: bool = typer.Option(False, "--fresh", help=FRESH_HELP),
    jobs: int = typer.Option(None, "--jobs", "-j", min=1, help=JOBS_HELP, show_default=False),
    executor: str = typer.Option("process", help=EXECUTOR_HELP),
    address: str = typer.Option(None, help=ADDRESS_HELP, show_default=False),
    threads: int = typer.Option(1, min=1, help=THREADS_HELP),
) -> None:
    """The paper's Fig. 5: F and time against team size, actors replicated.

    Writes OUT/scalability.csv and scalability.png/.pdf. The dataset is loaded and every team
    size checked before anything is computed.
    """
    from popbench.harness.scalability import ScalabilityConfig, run_scalability

    config = ScalabilityConfig(
        dataset=dataset,
        robots=_integers(robots, "robots"),
        methods=_methods(methods),
        iterations=iterations,
        init=_init(init),
        out=out,
    )
    frame = run_scalability(
        config, fresh=fresh, execution=_execution(jobs, executor, address, threads)
    )
    typer.echo(f"{len(frame)} cells -> {config.out}/scalability.csv, scalability.png/.pdf")


@plot_app.command(
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
    paths = plot_trajectories(dataset, robots, _methods(methods), stem, iterations, _init(init))
    typer.echo(" ".join(str(p) for p in paths))


@plot_app.command(
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
