"""End to end: ``popbench run table1`` writes its tables and resumes after being killed; the
cache follows the graph file; bad inputs fail before any work; ``--quick`` and ``--help``."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import grid_g2o, ring_g2o

from popbench.cli import main


def _popbench(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "popbench", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


@pytest.fixture
def mit():
    from tests.conftest import require_dataset

    return require_dataset("mit")


@pytest.mark.dataset
@pytest.mark.slow
def test_table1_quick_writes_csv_markdown_latex_and_figure(tmp_path, mit):
    process = _popbench("run", "table1", "--quick", "--out", str(tmp_path))
    _, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr
    for name in (
        "table1.csv",
        "table1.md",
        "table1.tex",
        "table1.png",
        "table1.pdf",
        "manifest.json",
    ):
        assert (tmp_path / name).stat().st_size > 0, name
    frame = pd.read_csv(tmp_path / "table1.csv")
    paper = {"cc-pgo", "ml-pgo", "mm-pgo", "prop-v1", "prop-v2"}
    assert set(frame["method"]) == paper | {"local-lm"}  # every non-centralised method
    assert (frame["gap"] > -1e-6).all()  # the optimum is a floor on every row
    in_paper = frame["method"].isin(paper)
    assert frame.loc[in_paper, "paper_F"].notna().all()
    assert frame.loc[~in_paper, "paper_F"].isna().all()  # local-lm is not in the paper
    assert "Prop-V2" in (tmp_path / "table1.md").read_text()
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["command"].startswith("popbench run table1")
    assert manifest["wall_s"] > 0 and manifest["hardware"]["cores"] >= 1


@pytest.mark.dataset
@pytest.mark.slow
def test_killed_run_recomputes_no_finished_cell(tmp_path, mit):
    args = (
        "run",
        "table1",
        "--datasets",
        "mit",
        "--robots",
        "3",
        "--methods",
        "cc-pgo,ml-pgo,lm",
        "--iterations",
        "200",  # ≥ 0.5 s per baseline cell on mit: far longer than the 50 ms poll and the kill
        "--out",
        str(tmp_path),
    )
    cells = tmp_path / "cells"
    process = _popbench(*args, start_new_session=True)
    deadline = time.monotonic() + 300
    while len(list(cells.glob("*.json"))) < 2 and process.poll() is None:
        assert time.monotonic() < deadline, "no cell finished in 300 s"
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    finished = {path: path.stat().st_mtime_ns for path in cells.glob("*.json")}
    assert 2 <= len(finished) < 4  # the optimum and at least one cell, not all of them

    again = _popbench(*args)
    _, stderr = again.communicate(timeout=600)
    assert again.returncode == 0, stderr
    assert len(list(cells.glob("*.json"))) == 4  # optimum + 3 cells
    for path, mtime in finished.items():
        assert path.stat().st_mtime_ns == mtime, f"{path.name} was recomputed"
    assert len(pd.read_csv(tmp_path / "table1.csv")) == 3


# ----- in-process CLI on a tiny graph (no dataset needed) ----------------------------------------


def _run(capsys, *args):
    code = main([str(arg) for arg in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_outliers_table_reports_f_gap_precision_recall_with_intervals(tmp_path, capsys):
    """Table II on a tiny grid: every cell's inlier F and gap to gnc, the summary's mean and
    95 % half-width per metric, mm-pgo named with its kernel, the reference without a gap."""
    graph = grid_g2o(tmp_path / "grid.g2o")
    out = tmp_path / "o"
    args = ("run", "outliers", "--datasets", graph, "--robots", "2", "--rate", "0.3")
    args += ("--methods", "mm-pgo,gnc", "--seeds", "0,1,2", "--iterations", "30")
    code, _, err = _run(capsys, *args, "--executor", "serial", "--out", out)
    assert code == 0, err
    cells = pd.read_csv(out / "outliers.csv")
    assert len(cells) == 6 and (cells["outliers"] == 4).all()  # round(0.3 × 12) loop closures
    gnc = cells[cells["method"] == "gnc"]
    assert (gnc["gap_gnc"].abs() < 1e-12).all() and (gnc["F_inliers"] <= gnc["F"]).all()
    summary = pd.read_csv(out / "outliers_summary.csv")
    for metric in ("F_inliers", "gap_gnc", "precision", "recall", "F"):
        assert {metric, f"{metric}_ci95"} <= set(summary.columns)
    mm = cells[cells["method"] == "mm-pgo"]
    row = summary[summary["method"] == "mm-pgo"].iloc[0]
    assert row["options"] == "kernel=huber, robust_mode=authors" and row["seeds"] == 3
    assert row["recall"] == pytest.approx(mm["recall"].mean())
    t = 4.302652729911275  # Student t, 0.975 quantile, 2 degrees of freedom
    assert row["recall_ci95"] == pytest.approx(t * mm["recall"].std(ddof=1) / 3**0.5)
    header = (out / "outliers.md").read_text().splitlines()[0]
    assert "gap to GNC MM-PGO (huber, authors)" in header and "gap to GNC GNC" not in header
    assert "F (inliers) GNC" in header and "recall MM-PGO (huber, authors)" in header
    assert r"$\pm$" in (out / "outliers.tex").read_text()


def test_an_edited_graph_file_is_recomputed_and_fresh_recomputes(tmp_path, capsys):
    graph = ring_g2o(tmp_path / "u.g2o")
    out = tmp_path / "D"
    args = ("run", "table1", "--datasets", graph, "--robots", "1", "--methods", "mm-pgo")
    args += ("--iterations", "5", "--out", out)

    def f():
        return pd.read_csv(out / "table1.csv")["F"].item()

    code, _, err = _run(capsys, *args)
    assert code == 0, err
    first = f()
    code, _, err = _run(capsys, *args)
    assert code == 0 and "2 of 2 cells already finished" in err  # the optimum and the cell
    ring_g2o(graph, dx="0.951")  # one measurement edited (and the size changed)
    code, _, err = _run(capsys, *args)
    assert code == 0, err
    assert "already finished" not in err  # neither the optimum nor the cell is reused
    assert f() != pytest.approx(first)
    code, _, err = _run(capsys, *args, "--fresh")
    assert code == 0 and "already finished" not in err


def _one_error_line(err: str, start: str) -> None:
    assert err.count("\n") == 1 and err.startswith(f"popbench: error: {start}"), err


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (("--datasets", "{graph},nosuch"), "unknown dataset 'nosuch'"),
        (("--datasets", "{graph},{tmp}/missing.g2o"), "no such file"),
        (("--datasets", "{graph}", "--robots", "1,5000"), "invalid --robots 5000: allowed "),
        (("--datasets", "{graph}", "--robots", "9", "--quick"), "invalid --robots 9: "),
    ],
)
def test_table1_rejects_bad_inputs_before_any_work(tmp_path, capsys, options, message):
    graph = ring_g2o(tmp_path / "u.g2o")
    options = [o.format(graph=graph, tmp=tmp_path) for o in options]
    out = tmp_path / "D"
    code, stdout, err = _run(
        capsys, "run", "table1", "--robots", "1", *options, "--methods", "mm-pgo", "--out", out
    )
    assert code == 2
    _one_error_line(err, message)
    assert stdout == ""
    assert not out.exists()  # no optimum, no cell, no progress


@pytest.mark.parametrize(
    "args",
    [
        ("run", "outliers", "--datasets", "{graph},nosuch", "--robots", "1"),
        ("run", "outliers", "--datasets", "{graph}", "--robots", "9"),
        ("run", "scalability", "--dataset", "nosuch"),
        ("run", "scalability", "--dataset", "{graph}", "--robots", "1,9"),
    ],
)
def test_outliers_and_scalability_reject_bad_inputs_before_any_work(tmp_path, capsys, args):
    graph = ring_g2o(tmp_path / "u.g2o")
    out = tmp_path / "D"
    args = [a.format(graph=graph) for a in args]
    code, _, err = _run(capsys, *args, "--methods", "mm-pgo", "--out", out)
    assert code == 2
    _one_error_line(err, "unknown dataset" if "nosuch" in " ".join(args) else "invalid --robots 9")
    assert not out.exists()


def test_outliers_rejects_unknown_candidates_before_any_work(tmp_path, capsys):
    graph = ring_g2o(tmp_path / "u.g2o")
    out = tmp_path / "D"
    args = ("run", "outliers", "--datasets", graph, "--robots", "1", "--candidates", "odometry")
    code, _, err = _run(capsys, *args, "--methods", "mm-pgo", "--out", out)
    assert code == 2
    _one_error_line(err, "invalid candidates 'odometry'")
    assert not out.exists()


@pytest.fixture
def captured_table1(monkeypatch):
    """The Table1Config that `popbench run table1` would run (nothing is computed)."""
    from popbench.harness import table1

    configs = []
    monkeypatch.setattr(table1, "run_table1", lambda config, run=None: configs.append(config) or [])
    return configs


def test_quick_writes_its_own_folder_and_keeps_the_options_given(capsys, captured_table1):
    from popbench.harness.table1 import QUICK, Table1Config

    assert _run(capsys, "run", "table1", "--quick")[0] == 0
    assert _run(capsys, "run", "table1", "--quick", "--robots", "2,4", "--iterations", "7")[0] == 0
    assert _run(capsys, "run", "table1", "--quick", "--out", "elsewhere")[0] == 0
    assert _run(capsys, "run", "table1")[0] == 0
    plain, given, moved, full = captured_table1
    assert plain.out == Path("results/table1-quick") != Table1Config().out
    assert (plain.datasets, plain.robots, plain.iterations) == (
        QUICK["datasets"],
        QUICK["robots"],
        QUICK["iterations"],
    )
    assert (given.robots, given.iterations, given.out) == ((2, 4), 7, plain.out)
    assert moved.out == Path("elsewhere")
    assert full == Table1Config()  # the full table: results/table1, all defaults


RAY = "(pip install 'popbench[ray]')"  # rich markup must not eat the "[ray]"


@pytest.mark.parametrize(
    ("command", "expected"),
    [
        (("run", "table1"), ("popbench run table1 --quick", "--fresh", "OUT/cells", RAY)),
        (("run", "outliers"), ("popbench run outliers --rate", "--fresh", "OUT/cells", RAY)),
        (("run", "scalability"), ("popbench run scalability", "--fresh", "OUT/cells", RAY)),
        (("run", "heldout"), ("popbench run heldout --rows no-op,ga-sac", "--json", RAY)),
        (
            ("plot", "trajectories"),
            ("popbench plot trajectories intel", "results/figures/trajectories_DATASET"),
        ),
        (("plot", "curves"), ("popbench plot curves ",)),
    ],
)
def test_help_has_examples(capsys, monkeypatch, command, expected):
    monkeypatch.setenv("COLUMNS", "250")
    code, out, _ = _run(capsys, *command, "--help")
    assert code == 0
    text = " ".join(out.replace("│", " ").split())
    assert "Examples:" in text
    for piece in expected:
        assert piece in text, piece


def test_trajectories_default_stem_is_the_one_the_help_names(tmp_path, capsys, monkeypatch):
    from popbench.harness import figures

    stems = []

    def plot(dataset, robots, methods, stem, *rest):
        stems.append(stem)
        return []

    monkeypatch.setattr(figures, "plot_trajectories", plot)
    code, _, err = _run(capsys, "plot", "trajectories", tmp_path / "u.g2o", "--methods", "lm")
    assert code == 0, err
    assert stems == [Path("results/figures/trajectories_u")]


def test_heldout_json_is_the_last_line_with_its_rows(tmp_path, capsys):
    rows = ("initial", "no-op", "local-lm")
    args = ("run", "heldout", "--robots", "3", "--problems", "2", "--rows", ",".join(rows))
    small = ("--poses-per-robot", "12", "--jobs", "1", "--out", tmp_path)
    code, out, err = _run(capsys, *args, *small, "--json")
    assert code == 0, err
    summary = json.loads(out.strip().splitlines()[-1])  # one JSON object, the last line
    assert [row["row"] for row in summary["rows"]] == list(rows)
    for row in summary["rows"]:
        assert (row["noise"], row["robots"], row["problems"]) == ("V2", 3, 2)
        assert row["F_median"] > 0 and len(row["F_median_ci"]) == 2
    local = summary["rows"][-1]
    assert local["closed_F"] == pytest.approx(1.0)  # local-lm closes its own gap
    assert (tmp_path / "summary.csv").is_file() and (tmp_path / "manifest.json").is_file()


def test_heldout_bad_values_are_one_line(tmp_path, capsys):
    for option, value, phrase in (
        ("--noise", "V4", "invalid --noise 'V4'"),
        ("--rows", "oracle", "invalid --rows 'oracle'"),
        ("--rows", "prop-v1,oracle", "invalid --rows 'oracle'"),
        ("--consensus", "gossip", "invalid --consensus 'gossip'"),
        ("--checkpoint", str(tmp_path / "none.pt"), "invalid --checkpoint"),
    ):
        code, _, err = _run(capsys, "run", "heldout", option, value, "--out", tmp_path / "o")
        assert code == 2, (option, err)
        _one_error_line(err, phrase)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["table1", "outliers", "scalability", "heldout"])
def test_every_experiment_passes_its_run_options_as_one_run(capsys, monkeypatch, command):
    import importlib

    from popbench.harness.executors import Execution, Run

    runs = []
    module = importlib.import_module(f"popbench.harness.{command}")
    monkeypatch.setattr(module, f"run_{command}", lambda config, run: runs.append(run) or [])
    options = ("--fresh", "--jobs", "3", "--threads", "2", "--executor", "serial")
    assert _run(capsys, "run", command, *options)[0] == 0
    assert runs == [Run(Execution(jobs=3, executor="serial", threads=2), fresh=True)]


def test_outliers_vertigo_models_and_a_mask_file(tmp_path, capsys):
    """--model vertigo-*: false loop closures added and scored; --outlier-mask: a file that
    already holds them (written here from the injector) gives the same problem and scores."""
    from popbench.datasets import load
    from popbench.io import write_g2o
    from popbench.outliers import add_false_loop_closures

    graph = grid_g2o(tmp_path / "grid.g2o")
    base = ("run", "outliers", "--datasets", graph, "--robots", "2", "--methods", "gnc")
    base += ("--seeds", "0", "--iterations", "30", "--executor", "serial")
    code, _, err = _run(
        capsys,
        *base,
        "--model",
        "vertigo-grouped",
        "--group-size",
        "2",
        "--rate",
        "0.5",
        "--out",
        tmp_path / "g",
    )
    assert code == 0, err
    cells = pd.read_csv(tmp_path / "g" / "outliers.csv")
    assert cells["outliers"].tolist() == [6]  # round(0.5 · 12 / 2) groups of 2
    assert (cells["model"] == "vertigo-grouped").all() and (cells["group_size"] == 2).all()
    assert cells["paper_precision"].isna().all()  # the paper's numbers are for corrupt only
    assert "vertigo-grouped (groups of 2" in (tmp_path / "g" / "outliers.md").read_text()
    # the same false closures written into a file, named by a mask file
    added, mask = add_false_loop_closures(load(graph), 0.5, "vertigo-random", seed=0)
    write_g2o(added, tmp_path / "bad.g2o")
    (tmp_path / "bad.mask").write_text("".join(f"{int(m)}\n" for m in mask))
    code, _, err = _run(
        capsys, *base, "--model", "vertigo-random", "--rate", "0.5", "--out", tmp_path / "r"
    )
    assert code == 0, err
    base = (*base[:3], tmp_path / "bad.g2o", *base[4:])
    code, _, err = _run(
        capsys, *base, "--outlier-mask", tmp_path / "bad.mask", "--out", tmp_path / "m"
    )
    assert code == 0, err
    injected = pd.read_csv(tmp_path / "r" / "outliers.csv").iloc[0]
    named = pd.read_csv(tmp_path / "m" / "outliers.csv").iloc[0]
    assert named["model"] == "mask" and named["outliers"] == injected["outliers"] == 6
    assert named["rate"] == pytest.approx(0.5)  # 6 false of the 12 true closures
    for column in ("precision", "recall", "flagged", "F_inliers"):
        assert named[column] == pytest.approx(injected[column]), column


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (("--model", "vertigo"), "invalid --model 'vertigo'"),
        (("--group-size", "3"), "--group-size is for --model vertigo-grouped"),
        (("--outlier-mask", "{tmp}/none.mask"), "invalid --outlier-mask"),
        (("--outlier-mask", "{tmp}/m.mask", "--rate", "0.1"), "--outlier-mask names"),
        (("--outlier-mask", "{tmp}/m.mask"), "{tmp}/m.mask:2: 1 mask value(s), the graph has 31"),
        (("--model", "vertigo-local", "--candidates", "paper"), "invalid --candidates with"),
    ],
)
def test_outliers_rejects_bad_model_options_before_any_work(tmp_path, capsys, options, message):
    graph = grid_g2o(tmp_path / "grid.g2o")
    (tmp_path / "m.mask").write_text("# too short\n1\n")
    out = tmp_path / "D"
    options = [str(o).format(tmp=tmp_path) for o in options]
    args = ("run", "outliers", "--datasets", graph, "--robots", "1", *options)
    code, _, err = _run(capsys, *args, "--methods", "gnc", "--out", out)
    assert code == 2, err
    _one_error_line(err, message.format(tmp=tmp_path))
    assert not out.exists()
