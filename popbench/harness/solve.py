"""One method on one pose graph, summarised as a JSON-ready record: what ``popbench solve``
prints (popbench.cli.solve is its parser and display), for scripts and tests.

:func:`solve_record` loads the file (or registered dataset), checks the options, runs the method
from the chosen start, writes the requested outputs and returns the record; the notes it adds
(did not converge, F minimised on an anisotropic file, the never-worse rule returned the start)
are one line each.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

from popbench.choices import OBJECTIVES, PARTITIONS
from popbench.errors import PopbenchError, ValueRangeError
from popbench.harness import defaults


class RoundProgress(Protocol):
    """What :func:`solve_record` tells a progress display (popbench.cli.solve.SolveProgress)."""

    def stage(self, text: str, rounds: int | None = None) -> None: ...

    def on_round(self, done: int) -> None: ...


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
    progress: RoundProgress | None = None,
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

    from popbench.io import ReadWarning

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

    from popbench.io import file_ids

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
    from popbench.io import graph_writer

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
    from popbench.io import file_ids, tum_rounded, write_flags, write_solution, write_tum

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
