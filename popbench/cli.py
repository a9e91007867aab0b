"""The ``popbench`` command line.

Every command imports what it needs inside its body, so ``popbench --help`` loads only typer,
rich and the small core (no torch, matplotlib or solvers). :func:`main` turns every error into one
line on stderr, ``popbench: error: …``, with exit status 2 for bad input (a malformed file, an
unknown dataset, a wrong checksum, an option out of range, a usage error) and 1 for runtime
failures (a download that failed, an unexpected exception; ``POPBENCH_DEBUG=1`` shows its
traceback).
"""

from __future__ import annotations

import json
import os
import sys
from typing import Annotated, Any

import typer

from popbench.errors import PopbenchError, ValueRangeError
from popbench.harness.cli import plot_app, run_app

PARTITIONS = ("metis", "contiguous")
EXIT_BAD_INPUT = 2
EXIT_RUNTIME = 1

app = typer.Typer(
    name="popbench",
    help="Benchmark learned and classical distributed planar pose-graph optimisation (SE(2) PGO).",
    epilog=(
        "Examples:\n\n"
        "  popbench datasets list\n\n"
        "  popbench solve intel --method lm --init chordal\n\n"
        "  popbench solve my_graph.g2o --method lm --json\n\n"
        "  popbench run table1 --quick\n\n"
        "Data: registered datasets are read from $POPBENCH_DATA, else ~/.cache/popbench, and "
        "downloaded there (sha256-checked) when missing."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
datasets_app = typer.Typer(
    help="List, download and verify the registered datasets.",
    epilog=(
        "Examples:\n\n"
        "  popbench datasets list\n\n"
        "  popbench datasets fetch intel m3500\n\n"
        "  POPBENCH_DATA=../shared/datasets popbench datasets verify"
    ),
    no_args_is_help=True,
)
app.add_typer(datasets_app, name="datasets")
app.add_typer(run_app, name="run")
app.add_typer(plot_app, name="plot")


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


# ----- datasets -----------------------------------------------------------------------------


def _status_style(status: str) -> str:
    return {"ok": "green", "missing": "yellow"}.get(status, "red")


@datasets_app.command("list")
def datasets_list() -> None:
    """Show every registered dataset, its size and whether a verified copy is on disk."""
    from rich.console import Console
    from rich.table import Table

    from popbench import datasets

    status = dict(datasets.verify())
    table = Table(title=f"datasets (searched: {', '.join(map(str, datasets.search_dirs()))})")
    for column in ("name", "poses", "edges", "ground truth", "local", "description"):
        table.add_column(column, justify="right" if column in ("poses", "edges") else "left")
    for name, entry in datasets.DATASETS.items():
        here = status[entry.alias_of or name]
        short = here if here in ("ok", "missing") else "checksum mismatch"
        table.add_row(
            name,
            str(entry.poses),
            str(entry.edges),
            entry.ground_truth or "",
            f"[{_status_style(here)}]{short}[/]",
            entry.description,
        )
    Console().print(table)


@datasets_app.command("fetch")
def datasets_fetch(
    names: Annotated[
        list[str] | None,
        typer.Argument(help="Registered names (see `popbench datasets list`).", show_default=False),
    ] = None,
    fetch_all: Annotated[bool, typer.Option("--all", help="Fetch every registered file.")] = False,
) -> None:
    """Download datasets that are not on disk yet (with their ground truth) and verify them.

    Files go to $POPBENCH_DATA if set, else ~/.cache/popbench; a download is written to a
    temporary file, checked against its pinned sha256 and only then renamed into place.
    """
    from popbench import datasets

    if fetch_all:
        names = [name for name, entry in datasets.DATASETS.items() if entry.alias_of is None]
    if not names:
        raise PopbenchError("name one or more datasets (see `popbench datasets list`) or use --all")
    for name in names:
        typer.echo(f"{name}: ok {datasets.fetch(name)}")


@datasets_app.command("verify")
def datasets_verify(
    names: Annotated[
        list[str] | None,
        typer.Argument(help="Names to check (default: every registered file).", show_default=False),
    ] = None,
) -> None:
    """Check the sha256 of local copies (nothing is downloaded); exit status 1 if any is bad."""
    from rich.console import Console
    from rich.table import Table

    from popbench import datasets

    report = datasets.verify(names or None)
    table = Table()
    table.add_column("name")
    table.add_column("status")
    for name, status in report:
        table.add_row(name, f"[{_status_style(status)}]{status}[/]")
    Console().print(table)
    bad = [name for name, status in report if status != "ok"]
    if bad:
        raise _RuntimeFailure(
            f"{len(bad)} dataset file(s) missing or corrupt: {', '.join(bad)}; "
            f"run `popbench datasets fetch {' '.join(bad)}` (delete corrupt files first)"
        )


# ----- solve --------------------------------------------------------------------------------


def parse_method_options(pairs: list[str]) -> dict[str, Any]:
    """``["kernel=huber", "scale=0.5"]`` → ``{"kernel": "huber", "scale": 0.5}``; values are read
    as JSON when they parse (numbers, true/false, null), else kept as strings."""
    options: dict[str, Any] = {}
    for pair in pairs:
        key, separator, text = pair.partition("=")
        if not separator or not key.isidentifier():
            raise ValueRangeError("--option", pair, "KEY=VALUE with KEY a Python identifier")
        try:
            options[key] = json.loads(text)
        except json.JSONDecodeError:
            options[key] = text
    return options


def build_problem(source: str, robots: int, partition: str, seed: int, init: str = "odometry"):
    """``source`` (a registered name or a file) split among ``robots`` robots, carrying the
    ``init`` start (:func:`popbench.harness.problems.distributed_problem`, as the harness)."""
    from popbench.harness.problems import distributed_problem

    if partition not in PARTITIONS:
        raise ValueRangeError("--partition", partition, " or ".join(PARTITIONS))
    return distributed_problem(source, robots, init, partition, seed)


SET_BY_CLI = {"init": "--init"}  # method options the command sets from its own flags


def check_method_options(method: str, options: dict[str, Any]) -> None:
    """Reject ``-o`` keys the method's solve does not name (every solve ends in ``**_``, so a
    misspelt key would otherwise be ignored silently) and those the command sets itself."""
    from popbench.methods import method_options

    accepted = [name for name in method_options(method) if name not in SET_BY_CLI]
    for key in options:
        if key in SET_BY_CLI:
            raise PopbenchError(
                f"-o {key}=… is set by the command: use {SET_BY_CLI[key]} instead "
                "(the record's init and F_init follow it)"
            )
        if key not in accepted:
            raise PopbenchError(
                f"unknown option -o {key}=… for method {method}; "
                f"accepted: {', '.join(accepted) or 'none'}"
            )


def run_method(problem, method: str, budget, options: dict[str, Any]):
    """Call the registered ``method`` on ``problem`` with ``budget`` and keyword ``options``."""
    from popbench.methods import get_method

    return get_method(method)(problem, budget, **options)


class SolveProgress:
    """A transient status line on stderr while ``popbench solve`` works: the stage, a bar of the
    rounds done (for methods that report them through ``Budget.round_done``) and the elapsed
    time. It is erased when the command ends."""

    def __init__(self, text: str = "") -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            Progress,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
        )

        self._progress = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.fields[rounds]}"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            transient=True,
            redirect_stdout=False,
            redirect_stderr=False,
        )
        self._task = self._progress.add_task(text, total=None, rounds="")
        self._total: int | None = None

    def __enter__(self) -> SolveProgress:
        self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    def stage(self, text: str, rounds: int | None = None) -> None:
        """Show ``text``; ``rounds`` (the budget) sizes the bar once rounds are reported."""
        self._total = rounds
        self._progress.update(self._task, description=text, total=None, completed=0, rounds="")

    def on_round(self, done: int) -> None:
        """``Budget.on_round``: ``done`` rounds have run."""
        total = self._total
        self._progress.update(
            self._task,
            total=total,
            completed=done,
            rounds=f"{done}/{total} rounds" if total else f"{done} rounds",
        )


def solve_record(
    source: str,
    method: str = "lm",
    init: str = "odometry",
    iterations: int | None = None,
    seconds: float | None = None,
    robots: int = 1,
    partition: str = "metis",
    seed: int = 0,
    options: dict[str, Any] | None = None,
    progress: SolveProgress | None = None,
) -> dict[str, Any]:
    """Solve one problem and summarise it as a JSON-ready dict (what ``popbench solve --json``
    prints). ``options`` are checked by :func:`check_method_options`; ``progress`` (optional)
    is shown each stage and told of each round.

    The problem carries the ``init`` start (a name of :data:`popbench.initial.STARTS`) and the
    method starts from it. ``F_init`` is ``F`` (eq. 1) at that estimate, computed here, since
    methods differ in what their ``history`` records.
    """
    from popbench import objective
    from popbench.initial import check_start
    from popbench.methods import Budget

    check_start(init, "--init")
    if iterations is not None and iterations < 0:
        raise ValueRangeError("--iterations", iterations, "an integer ≥ 0")
    if seconds is not None and not seconds > 0:
        raise ValueRangeError("--seconds", seconds, "a number > 0")
    check_method_options(method, options or {})
    budget = Budget(
        iterations=Budget.iterations if iterations is None else iterations,
        seconds=seconds,
        on_round=progress.on_round if progress is not None else None,
    )
    if progress is not None:
        split = f" and splitting it among {robots} robots" if robots > 1 else ""
        progress.stage(f"loading {source}{split}…")
    problem = build_problem(source, robots, partition, seed, init)
    options = dict(options or {})
    if progress is not None:
        team = f", {problem.num_robots} robots" if problem.num_robots > 1 else ""
        from popbench.methods import method_record

        episode = method_record(method).episodic  # one episode; --iterations does not apply
        rounds = "one episode" if episode else f"at most {budget.iterations} rounds"
        progress.stage(
            f"solving {problem.graph.name} with {method}{team}, {rounds}…",
            None if episode else budget.iterations,
        )
    result = run_method(problem, method, budget, options)
    if progress is not None:
        progress.stage(f"F at the {init} estimate…")
    graph = problem.graph
    record: dict[str, Any] = {
        "dataset": graph.name,
        "method": method,
        "init": init,
        "robots": problem.num_robots,
        "partition": partition if problem.num_robots > 1 else None,
        "poses": graph.num_poses,
        "edges": graph.num_edges,
        "F_init": objective.objective(graph, graph.poses),
        "F": float(result.F),
        "F_chordal": float(result.F_chordal),
        "chi2": float(result.chi2),
        "iterations": int(result.iterations),
        "wall_s": float(result.wall_s),
        "parallel_s": float(result.parallel_s),
        "history_length": len(result.history),
        "messages": int(result.messages),
        "options": options,
    }
    record["extras"] = {
        key: value.item() if hasattr(value, "item") else value
        for key, value in result.extras.items()
        if isinstance(value, int | float | bool | str) or getattr(value, "ndim", None) == 0
    }
    return record


def _print_summary(record: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{record['method']} on {record['dataset']}", show_header=False)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    for key, value in record.items():
        if value is None or value == {}:
            continue
        text = f"{value:.6g}" if isinstance(value, float) else str(value)
        table.add_row(key, text)
    Console().print(table)


@app.command(
    epilog=(
        "Examples:\n\n"
        "  popbench solve intel --method lm --init chordal\n\n"
        "  popbench solve m3500 --robots 5 --partition metis --json\n\n"
        "  popbench solve path/to/graph.g2o --iterations 50 -o key=value\n\n"
        "Objectives: F is paper eq. 1 with κ=Λθθ and τ=2/tr(Λtt⁻¹); F_chordal the SE-Sync "
        "chordal cost (no ½); chi2 g2o's EDGE_SE2 Σ eᵀΛe (no ½). See README.md."
    )
)
def solve(
    source: Annotated[
        str,
        typer.Argument(
            metavar="DATASET|PATH",
            help="A registered dataset (popbench datasets list) or a .g2o/.graph file.",
        ),
    ],
    method: Annotated[
        str, typer.Option(help="Registered method: lm, cc-pgo, ml-pgo, mm-pgo, prop-v1, prop-v2.")
    ] = "lm",
    init: Annotated[
        str,
        typer.Option(
            help="Initial estimate: odometry (composition), chordal, or given (the file's poses)."
        ),
    ] = "odometry",
    iterations: Annotated[
        int | None,
        typer.Option(
            help="Rounds the method may run (≥ 0; default 1000). A round is one LM step "
            "(accepted or rejected) for lm; one RBCD block round (one colour class of robots "
            "updates) for cc-pgo and ml-pgo; one MM iteration (every robot one step) for "
            "mm-pgo. prop-v1 and prop-v2 ignore it: they run one episode of one actor step "
            "per local edge, then consensus (prop-v2 then 75 LM steps)."
        ),
    ] = None,
    seconds: Annotated[
        float | None, typer.Option(help="Wall-clock cap in seconds (optional).")
    ] = None,
    robots: Annotated[
        int,
        typer.Option(
            help="Number of robots the graph is split among: 1 to the number of poses. Only "
            "the distributed methods use it; the default method, lm, is centralised and "
            "solves the whole graph whatever --robots says."
        ),
    ] = 1,
    partition: Annotated[
        str, typer.Option(help="How poses are split among robots: metis or contiguous.")
    ] = "metis",
    seed: Annotated[int, typer.Option(help="Seed of the partitioner (METIS).")] = 0,
    option: Annotated[
        list[str] | None,
        typer.Option(
            "--option",
            "-o",
            metavar="KEY=VALUE",
            help="Extra keyword option for the method (repeatable); VALUE is read as JSON "
            "when it parses, else as a string. KEY must be one of the method's options (an "
            "unknown KEY lists them); the start is --init, not -o init.",
        ),
    ] = None,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print exactly one JSON object on stdout.")
    ] = False,
    threads: Annotated[
        int,
        typer.Option(
            min=1,
            help="BLAS / OpenMP / torch threads, pinned whatever OMP_NUM_THREADS says (default "
            "1: an unpinned torch pool competing for a busy core made prop-v1 16-53x slower).",
        ),
    ] = 1,
) -> None:
    """Solve one pose graph with one method and report F, F_chordal, chi2 and timings.

    Progress (stage, rounds, elapsed time) is shown on stderr if a terminal, then erased.
    """
    import contextlib

    arguments = dict(
        method=method,
        init=init,
        iterations=iterations,
        seconds=seconds,
        robots=robots,
        partition=partition,
        seed=seed,
        options=parse_method_options(option or []),
    )
    live = SolveProgress(f"loading {source}…") if sys.stderr.isatty() else None
    from popbench.threads import limited_threads

    with limited_threads(threads), live if live is not None else contextlib.nullcontext():
        record = solve_record(source, **arguments, progress=live)
    if json_output:
        typer.echo(json.dumps(record))
    else:
        _print_summary(record)


# ----- train --------------------------------------------------------------------------------

TRAIN_ENVS = ("V1", "V2", "V3")
TRAIN_DEVICES = ("cpu", "cuda")


def train_config(
    env: str,
    robots: int,
    seed: int,
    frames: int | None,
    device: str,
    out: str | None,
    preset: str,
    progress: bool = True,
):
    """The `TrainConfig` of ``popbench train``: ``preset`` with the command's values applied."""
    import dataclasses

    from agents.config import PRESETS

    if env not in TRAIN_ENVS:
        raise ValueRangeError("--env", env, " or ".join(TRAIN_ENVS))
    if robots < 1:
        raise ValueRangeError("--robots", robots, "an integer ≥ 1")
    if frames is not None and frames < 1:
        raise ValueRangeError("--frames", frames, "an integer ≥ 1")
    if device not in TRAIN_DEVICES:
        raise ValueRangeError("--device", device, " or ".join(TRAIN_DEVICES))
    if preset not in PRESETS:
        raise ValueRangeError("--preset", preset, " or ".join(PRESETS))
    if device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise ValueRangeError("--device", device, "cpu (no CUDA device is available)")
    config = PRESETS[preset]
    experiment = dataclasses.replace(
        config.experiment,
        noise=env,
        robots=robots,
        seed=seed,
        device=device,
        frames=config.experiment.frames if frames is None else frames,
        out_dir=out or f"runs/ga-sac-{env}-n{robots}-s{seed}",
        progress=progress,
    )
    return dataclasses.replace(config, experiment=experiment)


@app.command(
    epilog=(
        "Examples:\n\n"
        "  popbench train --env V2 --robots 7 --seed 0\n\n"
        "  popbench train --env V2 --robots 3 --preset cpu-small --frames 20000 --out runs/n3\n\n"
        "Writes checkpoint.pt, metrics.csv and learning_curve.png into --out; a rerun with the "
        "same --out resumes from checkpoint.pt unless --no-resume."
    )
)
def train(
    env: Annotated[str, typer.Option(help="Training noise setting: V1, V2 or V3.")] = "V2",
    robots: Annotated[int, typer.Option(help="Team size n (the critic is built for n).")] = 7,
    seed: Annotated[int, typer.Option(help="Seed of the environments, torch and replay.")] = 0,
    frames: Annotated[
        int | None, typer.Option(help="Total environment frames (default: the preset's).")
    ] = None,
    device: Annotated[str, typer.Option(help="cpu or cuda.")] = "cpu",
    out: Annotated[
        str | None, typer.Option(help="Run directory (default runs/ga-sac-ENV-nN-sS).")
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume/--no-resume", help="Continue from OUT/checkpoint.pt.")
    ] = True,
    preset: Annotated[
        str,
        typer.Option(help="Model/algorithm sizes: paper (5×128 GNN, §IV-A) or cpu-small."),
    ] = "paper",
    threads: Annotated[
        int,
        typer.Option(
            min=1,
            help="BLAS / OpenMP / torch threads, pinned whatever OMP_NUM_THREADS says (default "
            "1: an unpinned torch pool competing for a busy core made prop-v1 16-53x slower).",
        ),
    ] = 1,
) -> None:
    """Train GA-SAC actors (TorchRL collector + replay) with checkpoints and learning curves."""
    from agents.trainer import train as run_training
    from popbench.threads import limited_threads

    config = train_config(env, robots, seed, frames, device, out, preset)
    with limited_threads(threads):
        summary = run_training(config, resume=resume).summary()
    typer.echo(summary)


# ----- entry point --------------------------------------------------------------------------


class _RuntimeFailure(Exception):
    """A command that ran but failed (exit status 1), with a one-line message."""


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def error_exit(error: BaseException) -> tuple[str, int]:
    """The one-line message and exit status for an exception that reached :func:`main`."""
    from popbench.datasets import DatasetUnavailableError

    if isinstance(error, typer.TyperException):  # usage errors from the parser
        where = getattr(getattr(error, "ctx", None), "command_path", "popbench")
        return f"{error.format_message()} (see `{where} --help`)", error.exit_code
    if isinstance(error, DatasetUnavailableError | _RuntimeFailure):
        return str(error), EXIT_RUNTIME
    if isinstance(error, PopbenchError | ValueError):
        return str(error), EXIT_BAD_INPUT
    if isinstance(error, OSError) and error.filename is not None:
        return f"{error.strerror}: {error.filename}", EXIT_BAD_INPUT
    detail = f"{type(error).__name__}: {error}"
    return f"internal error ({detail}); set POPBENCH_DEBUG=1 for the traceback", EXIT_RUNTIME


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; every error becomes one ``popbench: error: …`` line on stderr."""
    try:
        code = app(args=argv, prog_name="popbench", standalone_mode=False)
    except typer.Abort:
        sys.stderr.write("popbench: aborted\n")
        return EXIT_RUNTIME
    except KeyboardInterrupt as error:
        detail = f" ({error})" if str(error) else ""
        sys.stderr.write(f"popbench: interrupted{detail}\n")
        return 130
    except Exception as error:  # noqa: BLE001 - the one place errors become a message
        if os.environ.get("POPBENCH_DEBUG"):
            raise
        message, code = error_exit(error)
        sys.stderr.write(f"popbench: error: {_one_line(message)}\n")
        return code
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
