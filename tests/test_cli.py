"""The command line: one-line errors with the right exit status, never a traceback; the JSON
record of ``popbench solve``; a fast ``--help``."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import urllib.error
from pathlib import Path

import pytest
from conftest import data_missing, require_dataset

from popbench import cli, datasets
from popbench.cli import solve as solve_cli
from popbench.harness import solve as solve_harness

REQUIRED_KEYS = {
    "dataset", "method", "robots", "poses", "edges", "F_init", "F", "F_chordal", "chi2",
    "iterations", "wall_s", "parallel_s", "history_length",
}  # fmt: skip


def popbench(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python -m popbench ARGS`` in a fresh interpreter."""
    return subprocess.run(
        [sys.executable, "-m", "popbench", *args],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        timeout=300,
    )


def assert_one_line_error(run: subprocess.CompletedProcess, code: int, phrase: str) -> None:
    assert run.returncode == code, run.stderr
    assert "Traceback" not in run.stderr
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("popbench: error: "), run.stderr
    assert phrase in lines[0]


def test_malformed_file_is_one_line_with_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 x\n")
    run = popbench("solve", str(path), "--method", "lm")
    assert_one_line_error(run, 2, f"{path}:3: EDGE_SE2")
    assert run.stdout == ""


def test_unknown_dataset_is_one_line_listing_names() -> None:
    assert_one_line_error(popbench("solve", "intell"), 2, "unknown dataset 'intell'; known")


def test_wrong_checksum_is_one_line(tmp_path: Path) -> None:
    source = datasets.find("mit")
    if source is None:
        data_missing("mit.g2o not available locally (set POPBENCH_DATA)")
    shutil.copy(source, tmp_path / "mit.g2o")
    with (tmp_path / "mit.g2o").open("a") as handle:
        handle.write("\n")
    env = {"POPBENCH_DATA": str(tmp_path), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    run = popbench("solve", "mit", env=env)
    assert_one_line_error(run, 2, f"checksum mismatch for {tmp_path / 'mit.g2o'}")


def test_help_is_fast_to_import_and_teaches() -> None:
    heavy = "{'torch', 'scipy', 'matplotlib', 'numpy', 'agents'}"  # agents: loaded by name
    probe = f"import sys, popbench.cli; print(sorted({heavy} & set(sys.modules)))"
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "[]"
    run = popbench("solve", "--help")
    assert run.returncode == 0 and "popbench solve intel --method lm --init chordal" in run.stdout


@pytest.mark.parametrize(
    ("args", "code", "phrase"),
    [
        (["solve", "intel", "--init", "random"], 2, "invalid --init 'random': allowed odometry"),
        (
            ["solve", "intel", "--iterations", "-5"],
            2,
            "invalid --iterations -5: allowed an integer",
        ),
        (["solve", "intel", "--seconds", "0"], 2, "invalid --seconds 0"),
        (["solve", "intel", "--partition", "kahip"], 2, "invalid --partition 'kahip'"),
        (["solve", "intel", "-o", "kernel"], 2, "invalid --option 'kernel'"),
        (["solve", "no/such/file.g2o"], 2, "no such file: no/such/file.g2o"),
        (["solve"], 2, "Missing argument"),
        (["frobnicate"], 2, "No such command 'frobnicate'"),
        (["solve", "intel", "--iterations", "many"], 2, "'--iterations'"),
        (["datasets", "fetch"], 2, "name one or more datasets"),
        (["datasets", "verify", "nope"], 2, "unknown dataset 'nope'"),
    ],
)
def test_bad_input_is_one_line(capsys: pytest.CaptureFixture, args, code, phrase) -> None:
    assert cli.main(args) == code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("popbench: error: ") and phrase in err, err


@pytest.mark.dataset
def test_bad_robot_count_and_method_are_one_line(capsys: pytest.CaptureFixture) -> None:
    require_dataset("mit")
    assert cli.main(["solve", "mit", "--robots", "0"]) == 2
    assert "invalid robots 0" in capsys.readouterr().err
    assert cli.main(["solve", "mit", "--method", "gauss"]) == 2
    assert "invalid method 'gauss'" in capsys.readouterr().err


def test_offline_fetch_and_verify_exit_1(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    def refuse(url: str):
        raise urllib.error.URLError("no network")

    monkeypatch.setattr(datasets, "_open_url", refuse)
    monkeypatch.setenv("POPBENCH_DATA", str(tmp_path))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert cli.main(["datasets", "fetch", "intel"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no network" in err and "popbench datasets fetch intel" in err
    assert cli.main(["datasets", "verify", "intel"]) == 1
    captured = capsys.readouterr()
    assert "missing" in captured.out and captured.err.startswith("popbench: error: 1 dataset")


def test_unexpected_exception_is_one_line(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    def explode(*args, **kwargs):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(solve_cli, "solve_record", explode)
    monkeypatch.delenv("POPBENCH_DEBUG", raising=False)
    assert cli.main(["solve", "intel"]) == 1
    err = capsys.readouterr().err
    assert err == (
        "popbench: error: internal error (ZeroDivisionError: boom); "
        "set POPBENCH_DEBUG=1 for the traceback\n"
    )


def test_method_options_are_parsed_as_json_or_strings() -> None:
    parsed = solve_cli.parse_method_options(["kernel=huber", "scale=0.5", "steps=3", "robust=true"])
    assert parsed == {"kernel": "huber", "scale": 0.5, "steps": 3, "robust": True}


def test_version(capsys: pytest.CaptureFixture) -> None:
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("popbench ")


@pytest.mark.dataset
def test_solve_intel_json_reaches_the_reference_optimum() -> None:
    require_dataset("intel")
    args = ("solve", "intel", "--method", "lm", "--init", "chordal", "--objective", "F", "--json")
    run = popbench(*args)
    assert run.returncode == 0, run.stderr
    record = json.loads(run.stdout)  # exactly one JSON object: json.loads rejects trailing data
    assert REQUIRED_KEYS <= set(record)
    assert (record["dataset"], record["method"], record["robots"]) == ("intel", "lm", 1)
    assert (record["poses"], record["edges"]) == (1228, 1483)
    # Independent reference (docs/conventions.md): intel F* = 205.0502 (eq. 1, κ/τ weights).
    assert record["F"] == pytest.approx(205.0502, rel=1e-5)
    assert record["F"] <= record["F_init"]
    assert record["history_length"] == record["iterations"] + 1
    assert record["objective"] == "F" and record["status"]["converged"]


@pytest.mark.dataset
def test_solve_prints_a_human_summary(capsys: pytest.CaptureFixture) -> None:
    require_dataset("mit")
    assert cli.main(["solve", "mit", "--iterations", "3", "--robots", "2"]) == 0
    out = capsys.readouterr().out
    assert "lm on mit" in out and "F_chordal" in out


def test_datasets_list_shows_every_name(capsys: pytest.CaptureFixture) -> None:
    assert cli.main(["datasets", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in datasets.DATASETS)


@pytest.mark.dataset
def test_solve_json_record_with_a_distributed_method(capsys: pytest.CaptureFixture) -> None:
    require_dataset("mit")
    args = ["solve", "mit", "--method", "mm-pgo", "--robots", "3", "--iterations", "5", "--json"]
    assert cli.main([*args, "--init", "chordal"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert REQUIRED_KEYS <= set(record)
    assert (record["robots"], record["partition"], record["iterations"]) == (3, "metis", 5)
    assert record["history_length"] == 6 and record["parallel_s"] <= record["wall_s"]
    # F_init is F (eq. 1) at the chordal estimate, whatever the method's history records.
    from popbench.objective import objective
    from popbench.solvers.chordal import chordal_initialisation

    graph = datasets.load("mit")
    assert record["F_init"] == pytest.approx(objective(graph, chordal_initialisation(graph)))


@pytest.mark.parametrize(
    ("args", "phrase"),
    [
        (["-o", "bogus=1"], "unknown option -o bogus=… for method lm; accepted: chordal_stage, "),
        (
            ["--method", "mm-pgo", "-o", "kernal=gm"],
            "unknown option -o kernal=… for method mm-pgo; accepted: kernel, kernel_scale,",
        ),
        (["--method", "ml-pgo", "-o", "rank=3", "-o", "rnak=3"], "-o rnak=… for method ml-pgo"),
        (["--method", "cc-pgo", "-o", "init=chordal"], "-o init=… is set by the command: use"),
    ],
)
def test_unknown_method_options_are_rejected(capsys: pytest.CaptureFixture, args, phrase) -> None:
    # Every solve ends in **_, so without the check a misspelt option ran silently (exit 0).
    # The check runs before the problem is built: no dataset is read.
    assert cli.main(["solve", "no-such-dataset", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("popbench: error: ") and phrase in err, err
    assert "init" not in err.partition("accepted:")[2]  # init is --init's, not an -o option


def test_method_options_follow_forwarding() -> None:
    from popbench.methods import method_options

    # prop-v2 passes its **options to prop-v1, so prop-v1's options are prop-v2's too.
    assert {"lm_iterations", "consensus_iterations", "checkpoint"} <= set(method_options("prop-v2"))
    assert "consensus_iterations" in method_options("prop-v1")
    assert "lm_iterations" not in method_options("prop-v1")
    solve_harness.check_method_options("prop-v2", {"consensus_iterations": 3, "lm_iterations": 5})


def test_solve_help_explains_rounds_and_robots() -> None:
    import typer.main

    params = {p.name: p.help for p in typer.main.get_command(cli.app).commands["solve"].params}
    assert "prop-v1 and prop-v2 ignore it" in params["iterations"]
    assert "one LM step" in params["iterations"] and "one MM iteration" in params["iterations"]
    assert "1 to the number of poses" in params["robots"]
    assert "lm, is centralised" in params["robots"]


def _counting_solve(problem, budget, **_):
    """A registered method for the progress test: reports each round, then runs LM."""
    from popbench.solvers.lm import solve as lm_solve

    for done in range(1, budget.iterations + 1):
        budget.round_done(done)
    return lm_solve(problem, budget)


class _Recorder:
    def __init__(self) -> None:
        self.stages: list[tuple[str, int | None]] = []
        self.rounds: list[int] = []

    def stage(self, text: str, rounds: int | None = None) -> None:
        self.stages.append((text, rounds))

    def on_round(self, done: int) -> None:
        self.rounds.append(done)


def test_solve_record_reports_stages_and_rounds(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from popbench import methods

    record = methods.MethodRecord("counting", "test_cli:_counting_solve", "Counting")
    monkeypatch.setitem(methods.METHODS, "counting", record)
    path = tmp_path / "tri.g2o"
    path.write_text(
        "EDGE_SE2 0 1 1 0 1.5 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 1.5 1 0 0 1 0 1\n"
        "EDGE_SE2 2 0 1 0 1.6 1 0 0 1 0 1\n"
    )
    recorder = _Recorder()
    record = solve_cli.solve_record(str(path), method="counting", iterations=4, progress=recorder)
    assert recorder.rounds == [1, 2, 3, 4]
    texts = [text for text, _ in recorder.stages]
    assert texts[0].startswith(f"loading {path}")
    assert ("solving tri with counting, at most 4 rounds…", 4) in recorder.stages
    assert record["iterations"] <= 4
    # Without a progress object the Budget carries no callback and round_done is a no-op.
    again = solve_cli.solve_record(str(path), method="counting", iterations=2)
    assert again["method"] == "counting"
    assert methods.Budget(iterations=3) == methods.Budget(iterations=3, on_round=print)


def _run_with_tty_stderr(*args: str) -> tuple[subprocess.CompletedProcess, str]:
    """``python -m popbench ARGS`` with stderr on a pseudo-terminal; returns the run (stdout
    captured) and what the terminal received."""
    import pty
    import threading

    master, slave = pty.openpty()
    received: list[bytes] = []

    def drain() -> None:
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:
                return
            if not data:
                return
            received.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        run = subprocess.run(
            [sys.executable, "-m", "popbench", *args],
            stdout=subprocess.PIPE,
            stderr=slave,
            text=True,
            env={**os.environ, "COLUMNS": "200"},
            timeout=300,
        )
    finally:
        os.close(slave)
    reader.join(timeout=5)
    os.close(master)
    return run, b"".join(received).decode(errors="replace")


@pytest.mark.dataset
def test_solve_shows_progress_on_a_terminal_only() -> None:
    require_dataset("mit")
    args = ("solve", "mit", "--method", "mm-pgo", "--robots", "3", "--iterations", "300")
    run, terminal = _run_with_tty_stderr(*args, "--json")
    assert run.returncode == 0, terminal
    assert json.loads(run.stdout)["iterations"] == 300  # stdout: exactly the JSON object
    assert "solving mit with mm-pgo, 3 robots, at most 300 rounds…" in terminal
    assert "popbench: error" not in terminal
    # stderr not a terminal: no progress on it, only the notes (not converged, F on anisotropic
    # information: docs/solve.md).
    piped = popbench(*args, "--json")
    notes = piped.stderr.splitlines()
    assert piped.returncode == 0 and all(line.startswith("popbench: note: ") for line in notes)


@pytest.mark.parametrize("method", ["cc-pgo", "ml-pgo", "mm-pgo", "prop-v1"])
def test_every_iterative_method_reports_each_round(small_graph, method: str) -> None:
    """The progress bar counts real rounds: each method calls Budget.round_done once per round
    (prop-v1: per actor step), with the running count."""
    from popbench.methods import Budget, get_method
    from popbench.problems.distributed import DistributedProblem

    problem = DistributedProblem.from_graph(small_graph, 3)
    seen: list[int] = []
    result = get_method(method)(problem, Budget(iterations=12, on_round=seen.append))
    assert seen == list(range(1, result.iterations + 1))
    assert result.iterations > 0
