"""``popbench solve``: one method on one pose graph, summarised (a table or one JSON object).

:func:`solve_record` is the command without its parser (what ``--json`` prints), for scripts
and tests.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from popbench.choices import OBJECTIVES, PARTITIONS
from popbench.cli.options import CommandThreads
from popbench.errors import PopbenchError, ValueRangeError
from popbench.harness import defaults


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


def build_problem(source: str, robots: int, partition: str, seed: int, init: str = defaults.INIT):
    """``source`` (a registered name or a file) split among ``robots`` robots, carrying the
    ``init`` start (:func:`popbench.harness.problems.distributed_problem`, as the harness)."""
    from popbench.harness.problems import distributed_problem

    if partition not in PARTITIONS:
        raise ValueRangeError("--partition", partition, " or ".join(PARTITIONS))
    return distributed_problem(source, robots, init, partition, seed)


SET_BY_CLI = {"init": "--init", "objective": "--objective"}  # set from the command's own flags
# Largest per-edge anisotropy (popbench.objective.anisotropy: how unevenly F weighs residuals
# against the full information, 1 = not at all) below which F and chi2 are the same problem;
# the registered files are either at 1 (m3500, city10k, w10000) or far above (≥ 3e3 at most).
ANISOTROPY_NOTE = 1.01


def method_objective(method: str, objective: str | None) -> str:
    """The cost ``method`` will minimise: ``objective`` (``"chi2"`` or ``"F"``), or by default
    chi2 where the method can minimise it (it takes an ``objective`` option) and F otherwise;
    a one-line error for chi2 with a method that minimises F only."""
    from popbench.methods import method_options

    if objective is not None and objective not in OBJECTIVES:
        raise ValueRangeError("--objective", objective, " or ".join(OBJECTIVES))
    supports = "objective" in method_options(method)
    if objective == "chi2" and not supports:
        raise PopbenchError(
            f"--objective chi2: {method} minimises F only (paper eq. 1, isotropic weights by "
            "construction); use --objective F, or lm, gnc, local-lm or prop-v2 for chi2"
        )
    return objective or ("chi2" if supports else "F")


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
    init: str = defaults.INIT,
    iterations: int | None = None,
    seconds: float | None = None,
    robots: int = 1,
    partition: str = defaults.PARTITION,
    seed: int = 0,
    options: dict[str, Any] | None = None,
    progress: SolveProgress | None = None,
    output: str | Path | None = None,
    trajectory: str | Path | None = None,
    flags: str | Path | None = None,
    objective: str | None = None,
) -> dict[str, Any]:
    """Solve one problem and summarise it as a JSON-ready dict (what ``popbench solve --json``
    prints). ``objective``: the cost minimised, :func:`method_objective` (default chi2 where
    the method supports it); the record's ``objective`` says which, ``anisotropy`` the file's
    largest per-edge :func:`popbench.objective.anisotropy` and ``status`` where the method
    stopped (:class:`popbench.status.Status`). ``options`` are checked by
    :func:`check_method_options`; ``progress`` (optional) is shown each stage and told of each
    round. ``output``, ``trajectory`` and ``flags``, when given, are written after the solve
    (:func:`write_outputs`); their paths are checked first.

    ``outliers``: for a method that returns an inlier mask, the edges it flags, each
    ``{"edge": index, "i": tail id, "j": head id}`` (the order and ids of the file's edge
    lines); None for a method that flags nothing (no mask).

    The problem carries the ``init`` start (a name of :data:`popbench.solvers.initial.STARTS`) and
    the method starts from it. ``F_init`` is ``F`` (eq. 1) at that estimate, computed here, since
    methods differ in what their ``history`` records.
    """
    from popbench import objective as costs
    from popbench.methods import Budget, method_record
    from popbench.solvers.initial import check_start

    check_start(init, "--init")
    if iterations is not None and iterations < 0:
        raise ValueRangeError("--iterations", iterations, "an integer ≥ 0")
    if seconds is not None and not seconds > 0:
        raise ValueRangeError("--seconds", seconds, "a number > 0")
    check_method_options(method, options or {})
    cost = method_objective(method, objective)
    check_output_paths(output, trajectory, flags)
    budget = Budget(
        iterations=Budget.iterations if iterations is None else iterations,
        seconds=seconds,
        on_round=progress.on_round if progress is not None else None,
    )
    if progress is not None:
        split = f" and splitting it among {robots} robots" if robots > 1 else ""
        progress.stage(f"loading {source}{split}…")
    problem, notes = reading_notes(build_problem, source, robots, partition, seed, init)
    options = dict(options or {})
    method_kwargs = {**options, "objective": cost} if cost == "chi2" else options
    if progress is not None:
        team = f", {problem.num_robots} robots" if problem.num_robots > 1 else ""
        episode = method_record(method).episodic  # one episode; --iterations does not apply
        rounds = "one episode" if episode else f"at most {budget.iterations} rounds"
        progress.stage(
            f"solving {problem.graph.name} with {method}{team}, {rounds}…",
            None if episode else budget.iterations,
        )
    result = run_method(problem, method, budget, method_kwargs)
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
        "F_init": costs.objective(graph, graph.poses),
        **result.summary(),
        "history_length": len(result.history),
        "options": options,
        "objective": cost,
        "anisotropy": float(costs.anisotropy(graph.information).max(initial=1.0)),
        "status": result.status.as_record(),
    }
    record["extras"] = {
        key: value.item() if hasattr(value, "item") else value
        for key, value in result.extras.items()
        if isinstance(value, int | float | bool | str) or getattr(value, "ndim", None) == 0
    }
    record["outliers"] = flagged_edges(graph, result.inlier_mask)
    notes += write_outputs(graph, result, output, trajectory, flags)
    record["notes"] = notes + stderr_notes(record)
    return record


def reading_notes(load, *arguments) -> tuple[Any, list[str]]:
    """``load(*arguments)`` and the one-line messages of the
    :class:`popbench.io.read.ReadWarning` it raised (lines skipped, edges an EQUIV merge dropped);
    other warnings are shown as usual."""
    import warnings

    from popbench.io.read import ReadWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ReadWarning)
        loaded = load(*arguments)
    notes = []
    for warning in caught:
        if issubclass(warning.category, ReadWarning):
            notes.append(str(warning.message))
        else:
            warnings.warn_explicit(
                warning.message, warning.category, warning.filename, warning.lineno
            )
    return loaded, notes


def flagged_edges(graph, inlier_mask) -> list[dict[str, int]] | None:
    """The edges ``inlier_mask`` ``(M,)`` flags (False), as ``{"edge", "i", "j"}`` dicts in
    edge order, ``i``, ``j`` the file's vertex ids; None without a mask."""
    import numpy as np

    from popbench.io.read import file_ids

    if inlier_mask is None:
        return None
    edges = np.flatnonzero(~np.asarray(inlier_mask, dtype=bool))
    ids = file_ids(graph)
    tails, heads = ids[graph.tails[edges]].tolist(), ids[graph.heads[edges]].tolist()
    return [{"edge": int(e), "i": i, "j": j} for e, i, j in zip(edges, tails, heads, strict=True)]


OUTPUT_OPTIONS = {"output": "--output", "trajectory": "--trajectory", "flags": "--flags"}


def check_output_paths(
    output: str | Path | None, trajectory: str | Path | None, flags: str | Path | None
) -> None:
    """Before solving: ``output`` must end in ``.g2o`` or ``.graph``, and every given path must
    be in an existing folder and not be a folder (ValueRangeError, exit status 2)."""
    from popbench.io.read import graph_writer

    paths = {"output": output, "trajectory": trajectory, "flags": flags}
    for key, path in paths.items():
        if path is None:
            continue
        path = Path(path)
        if path.is_dir() or not path.resolve().parent.is_dir():
            raise ValueRangeError(OUTPUT_OPTIONS[key], str(path), "a file in an existing folder")
    if output is not None:
        graph_writer(output, "--output")


def write_outputs(
    graph,
    result,
    output: str | Path | None = None,
    trajectory: str | Path | None = None,
    flags: str | Path | None = None,
) -> list[str]:
    """Write a method's ``result`` on ``graph`` (the problem's global graph), with the file's
    own vertex ids: the graph with the solved poses to ``output``
    (:func:`popbench.io.read.write_solution`), the TUM trajectory to ``trajectory``
    (:func:`popbench.io.read.write_tum`) and the per-edge CSV to ``flags``
    (:func:`popbench.io.read.write_flags`, weights from ``result.extras["weights"]`` where the
    method reports them: gnc, mm-pgo with a kernel). Returns the one-line notes for the user:
    TUM timestamps that float64 readers (evo) will round (:func:`popbench.io.read.tum_rounded`)."""
    from popbench.io.read import file_ids, tum_rounded, write_flags, write_solution, write_tum

    notes = []
    if output is not None:
        write_solution(graph, result.poses, output)
    if trajectory is not None:
        write_tum(result.poses, trajectory, file_ids(graph))
        rounded = tum_rounded(file_ids(graph))
        if rounded:
            notes.append(
                f"{trajectory}: the timestamps are the vertex ids, exact in the file, but "
                f"{rounded} of the {graph.num_poses} ids are above 2^53 and share their float64 "
                "value with another id, so evo (which reads timestamps as float64) cannot tell "
                "them apart; the .g2o/.graph output keeps every id exactly (docs/solve.md)"
            )
    if flags is not None:
        write_flags(graph, flags, result.inlier_mask, result.extras.get("weights"))
    return notes


def never_worse_sentence(record: dict[str, Any]) -> str | None:
    """In words, when the never-worse rule returned the start instead of the method's answer
    (docs/never_worse.md); None when it kept the answer."""
    from popbench.status import NeverWorse

    extras = record["extras"]
    if extras.get("never_worse") != NeverWorse.START:
        return None
    compared = extras.get("never_worse_cost", "F")
    if compared == "F":
        answer, start = extras["F_method"], record["F_init"]
    else:
        answer, start = record["status"]["cost"], record["status"]["start_cost"]
    return (
        f"the map returned is the START, not {record['method']}'s answer: its {compared} "
        f"({answer:.6g}) was above the start's ({start:.6g}) (never-worse rule)"
    )


def stderr_notes(record: dict[str, Any]) -> list[str]:
    """The solve's own notes (added to the record's ``notes``, one stderr line each): the method
    did not converge; F was minimised on a file whose information F does not represent
    (anisotropy above :data:`ANISOTROPY_NOTE`)."""
    notes = []
    status = record["status"]
    if not status["converged"]:
        notes.append(
            f"{record['method']}: not converged after {status['rounds']} rounds "
            f"(‖∇‖ = {status['gradient_norm']:.3g}, {status['objective']} per m or rad)"
        )
    if record["objective"] == "F" and record["anisotropy"] > ANISOTROPY_NOTE:
        notes.append(
            f"{record['method']} minimised F (paper eq. 1, one isotropic weight per edge), but "
            f"this file's information is anisotropic (F weighs an edge's residual up to "
            f"{record['anisotropy']:.3g}× unevenly against it): the map is F's minimiser, not "
            f"the maximum-likelihood map g2o and GTSAM return (chi2 here {record['chi2']:.6g}; "
            "lm, gnc, local-lm and prop-v2 minimise chi2, docs/solve.md)"
        )
    return notes


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
