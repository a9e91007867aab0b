"""``popbench solve``: one method on one pose graph, summarised (a table or one JSON object).

The command's record is :func:`popbench.harness.solve.solve_record` (what ``--json`` prints,
for scripts and tests); this module is its parser, progress line and display.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from popbench.cli.options import CommandThreads
from popbench.errors import ValueRangeError
from popbench.harness import defaults
from popbench.harness.solve import never_worse_sentence, solve_record


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


def _status_text(status: dict[str, Any]) -> str:
    state = "converged" if status["converged"] else "NOT converged"
    return (
        f"{state} after {status['rounds']} rounds, ‖∇{status['objective']}‖ = "
        f"{status['gradient_norm']:.3g}"
    )


def _print_summary(record: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{record['method']} on {record['dataset']}", show_header=False)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    start_returned = never_worse_sentence(record)
    for key, value in record.items():
        if value is None or value == {} or key == "notes":  # notes: one line each on stderr
            continue
        text = f"{value:.6g}" if isinstance(value, float) else str(value)
        if key == "status":
            text = _status_text(value)
        if key == "outliers":
            text = f"{len(value)} edges flagged"
            if start_returned is not None:
                text += f"; {start_returned}"
        table.add_row(key, text)
    if record["outliers"] is None and start_returned is not None:
        table.add_row("map", start_returned)
    Console().print(table)


EPILOG = (
    "Examples:\n\n"
    "  popbench solve intel --method lm --init chordal\n\n"
    "  popbench solve m3500 --robots 5 --partition metis --json\n\n"
    "  popbench solve path/to/graph.g2o --iterations 50 -o key=value\n\n"
    "  popbench solve intel --method gnc --output out.g2o --trajectory out.tum --flags out.csv\n\n"
    "Objectives: F is paper eq. 1 with κ=Λθθ and τ=2/tr(Λtt⁻¹); F_chordal the SE-Sync "
    "chordal cost (no ½); chi2 g2o's EDGE_SE2 Σ eᵀΛe (no ½), the full information. lm, gnc, "
    "local-lm and prop-v2 minimise chi2 unless --objective F; the others F. See docs/solve.md."
)


def solve_command(
    source: Annotated[
        str,
        typer.Argument(
            metavar="DATASET|PATH",
            help="A registered dataset (popbench datasets list) or a .g2o/.graph file.",
        ),
    ],
    method: Annotated[
        str,
        typer.Option(
            help="Registered method: lm, gnc, cc-pgo, ml-pgo, mm-pgo, prop-v1, prop-v2, local-lm."
        ),
    ] = "lm",
    init: Annotated[
        str,
        typer.Option(
            help="Initial estimate: odometry (composition), chordal, or given (the file's poses)."
        ),
    ] = defaults.INIT,
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
    ] = defaults.PARTITION,
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
    output: Annotated[
        Path | None,
        typer.Option(
            help="Write the graph with the solved poses as its VERTEX lines: g2o for a .g2o "
            "path, TORO for .graph. Edges are written as read, so `popbench solve PATH --init "
            "given` starts at the solution's F.",
            show_default=False,
        ),
    ] = None,
    trajectory: Annotated[
        Path | None,
        typer.Option(
            help="Write the solved poses as a TUM trajectory (evo reads it): one line "
            "'id x y z qx qy qz qw' per pose, the vertex id as timestamp, z = 0, the yaw's "
            "quaternion.",
            show_default=False,
        ),
    ] = None,
    flags: Annotated[
        Path | None,
        typer.Option(
            help="Write a CSV, one row per edge: edge,i,j,kind,weight,flagged (weight: the "
            "final robust weight, empty where the method reports none; flagged: 1 for an "
            "edge the method flags as an outlier, empty where it flags nothing).",
            show_default=False,
        ),
    ] = None,
    objective: Annotated[
        str | None,
        typer.Option(
            help="The cost minimised: chi2 (g2o's, each edge's full 3×3 information, what g2o "
            "and GTSAM minimise; the default for lm, gnc, local-lm and prop-v2) or F (paper "
            "eq. 1, one isotropic weight per edge; what the tables minimise, and all cc-pgo, "
            "ml-pgo, mm-pgo and prop-v1 can). They agree where the information is isotropic "
            "(docs/solve.md).",
            show_default=False,
        ),
    ] = None,
    threads: CommandThreads = 1,
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
        output=output,
        trajectory=trajectory,
        flags=flags,
        objective=objective,
    )
    live = SolveProgress(f"loading {source}…") if sys.stderr.isatty() else None
    from popbench.threads import limited_threads

    with limited_threads(threads), live if live is not None else contextlib.nullcontext():
        record = solve_record(source, **arguments, progress=live)
    for note in record["notes"]:
        sys.stderr.write(f"popbench: note: {note}\n")
    if json_output:
        typer.echo(json.dumps(record))
    else:
        _print_summary(record)
