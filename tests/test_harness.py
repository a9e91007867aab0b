"""The harness: cached cells, resumption, reports."""

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from conftest import ring_g2o

from popbench.harness import reports
from popbench.harness.cache import CellCache, cell_key
from popbench.harness.executors import Run
from popbench.harness.paper import PAPER_TABLE1, paper_table1_cell, paper_table2_cell
from popbench.harness.runner import run_cells


def test_cell_key_is_order_independent_and_distinguishes_values():
    assert cell_key({"a": 1, "b": "x"}) == cell_key({"b": "x", "a": 1})
    assert cell_key({"a": 1}) != cell_key({"a": 2})


def test_cache_round_trip_and_torn_file(tmp_path):
    cache = CellCache(tmp_path)
    spec = {"dataset": "mit", "robots": 3}
    assert cache.get(spec) is None
    cache.put(spec, {"F": 1.5})
    assert cache.get(spec) == {"F": 1.5}
    (tmp_path / f"{cell_key(spec)}.json").write_text('{"spec": ')  # a torn write
    assert cache.get(spec) is None


def test_interrupted_run_resumes_without_recomputing_finished_cells(tmp_path):
    specs = [{"dataset": "d", "robots": n, "method": "m"} for n in range(5)]
    computed = []

    def crash_at_third(spec):
        if spec["robots"] == 2:
            raise KeyboardInterrupt  # the user pressed Ctrl-C in the third cell
        computed.append(spec["robots"])
        return {"robots": spec["robots"], "F": float(spec["robots"])}

    cache = CellCache(tmp_path / "cells")
    with pytest.raises(KeyboardInterrupt):
        run_cells(specs, crash_at_third, cache, progress=False)
    assert computed == [0, 1]

    def count(spec):
        computed.append(spec["robots"])
        return {"robots": spec["robots"], "F": float(spec["robots"])}

    rows = run_cells(specs, count, CellCache(tmp_path / "cells"), progress=False)
    assert computed == [0, 1, 2, 3, 4]  # 0 and 1 were not recomputed
    assert [row["robots"] for row in rows] == [0, 1, 2, 3, 4]
    assert len(list((tmp_path / "cells").glob("*.json"))) == 5
    stored = json.loads(next((tmp_path / "cells").glob("*.json")).read_text())
    assert set(stored) == {"spec", "row", "measured"}
    assert stored["measured"]["executor"] == "serial" and stored["measured"]["jobs"] == 1


def test_paper_numbers_transcribed():
    assert set(PAPER_TABLE1) == {
        "m3500",
        "m3500b",
        "m3500c",
        "city10k",
        "grid1000",
        "intel",
        "mit",
        "csail",
    }
    assert paper_table1_cell("m3500", 3, "cc-pgo") == (1123, 575.64)
    assert paper_table1_cell("csail", 35, "prop-v2") == (894, 7.27)
    assert paper_table1_cell("city10k", 7, "mm-pgo") == (5235, 175.04)
    assert paper_table2_cell("csail", 0.1, "prop-v1") == (3.6e3, 0.89, 0.80)
    assert paper_table1_cell("intel", 5, "cc-pgo") is None


def _frame():
    rows = []
    for n in (3, 7):
        for method, f in (("cc-pgo", 50.0), ("mm-pgo", 41.0)):
            rows.append(
                {
                    "dataset": "mit",
                    "poses": 808,
                    "edges": 827,
                    "robots": n,
                    "method": method,
                    "init": "odometry",
                    "F": f + n,
                    "gap": f / 40 - 1,
                    "parallel_s": 0.1 * n,
                    "wall_s": 1.0,
                    "seed": 0,
                }
            )
    return pd.DataFrame(rows)


def test_table1_markdown_and_latex_show_ours_beside_the_paper_and_bold_the_best():
    markdown = reports.table1_markdown(_frame())
    assert "| mit (808, 827) | F | 53 (2048) | **44** (1021) |" in markdown
    latex = reports.table1_latex(_frame())
    assert r"\textbf{44} (1021)" in latex
    assert latex.count(r"\\") == 1 + 4  # header + one row per metric


def test_table1_figure_writes_png_and_pdf(tmp_path):
    paths = reports.table1_figure(_frame(), tmp_path / "table1")
    assert all(path.stat().st_size > 1000 for path in paths)


def test_outliers_tables_report_mean_and_interval():
    frame = pd.DataFrame(
        {
            "dataset": "intel",
            "rate": 0.1,
            "method": "mm-pgo",
            "options": "kernel=huber, robust_mode=authors",
            "seed": [0, 1],
            "F": [20.0, 30.0],
            "F_inliers": [10.0, 14.0],
            "gap_gnc": [1.0, 2.0],
            "precision": [0.5, 0.7],
            "recall": [1.0, 1.0],
            "paper_F": 3.4e3,
            "paper_precision": 0.69,
            "paper_recall": 0.55,
        }
    )
    half = 12.706204736174707 * np.std([10.0, 14.0], ddof=1) / np.sqrt(2)  # t(0.975, 1 dof)
    markdown = reports.outliers_markdown(frame)
    assert f"| 12 ± {half:.4g} (3400) |" in markdown
    assert "MM-PGO (huber, authors)" in markdown.splitlines()[0]
    assert f"0.6 ± {12.706204736174707 * 0.1:.4g} (0.69)" in markdown
    assert "| 1 ± 0 (0.55) |" in markdown
    assert r"$\pm$" in reports.outliers_latex(frame)


def test_outliers_table_prints_undefined_scores_as_such():
    """A seed where a method flags nothing has no precision (nor recall without outliers): it
    is left out of the mean and counted, even in cells written with precision_recall's 1."""
    frame = pd.DataFrame(
        {
            "dataset": "csail",
            "rate": 0.1,
            "method": ["mm-pgo"] * 3 + ["gnc"] * 3,
            "seed": [0, 1, 2] * 2,
            "F": 1.0,
            "F_inliers": 1.0,
            "gap_gnc": 0.0,
            "outliers": [4, 4, 0] * 2,
            "flagged": [0, 0, 0, 4, 2, 1],
            "precision": [1.0, 1.0, 1.0, 1.0, 0.5, 0.0],  # the old convention: 1 when none
            "recall": [0.0, 0.0, 1.0, 1.0, 0.25, 1.0],  # and recall 1 without outliers
        }
    )
    summary = reports.outliers_summary(frame).set_index("method")
    assert summary.loc["mm-pgo", "precision_undefined"] == 3
    assert np.isnan(summary.loc["mm-pgo", "precision"])
    assert summary.loc["gnc", "precision"] == pytest.approx(0.5)  # over the three defined
    assert summary.loc["gnc", "recall"] == pytest.approx(0.625)  # seed 2 has no outlier
    assert summary.loc["gnc", "recall_undefined"] == 1
    assert summary.loc["mm-pgo", "recall_undefined"] == 1
    markdown = reports.outliers_markdown(frame)
    row = markdown.splitlines()[2]
    assert "| – [undefined 3/3] |" in row  # mm-pgo's precision, not "1 ± 0"
    assert "| 0 ± 0 [undefined 1/3] |" in row  # mm-pgo's recall over seeds 0 and 1
    assert "| 0.5 ± 1.242 |" in row  # gnc's precision, every seed defined
    assert "undefined" in reports.outliers_latex(frame)


def test_outliers_cells_run_methods_with_their_record_options():
    from popbench.harness.outliers import OutliersConfig, cell_specs
    from popbench.methods import method_record

    config = OutliersConfig(datasets=("mit",), methods=("mm-pgo", "gnc"), seeds=(0,))
    options = {spec["method"]: spec["options"] for spec in cell_specs(config)}
    assert options == {"mm-pgo": dict(method_record("mm-pgo").outlier_options), "gnc": {}}
    assert options["mm-pgo"]["robust_mode"] == "authors"
    config = dataclasses.replace(config, kernel="gm")  # --kernel: only where a kernel exists
    options = {spec["method"]: spec["options"] for spec in cell_specs(config)}
    assert options["mm-pgo"]["kernel"] == "gm" and options["gnc"] == {}


@pytest.mark.dataset
def test_scalability_and_trajectory_figures(tmp_path):
    from popbench.harness.figures import plot_trajectories
    from popbench.harness.scalability import ScalabilityConfig, run_scalability
    from popbench.plotting import plot_learning_curves
    from tests.conftest import require_dataset

    require_dataset("mit")
    config = ScalabilityConfig(
        dataset="mit", robots=(1, 3), methods=("lm", "mm-pgo"), iterations=20, out=tmp_path / "scal"
    )
    frame = run_scalability(config, Run(progress=False))
    assert sorted(frame["robots"].unique()) == [1, 3]
    assert (frame["gap"] > -1e-6).all()
    assert (tmp_path / "scal" / "scalability.png").stat().st_size > 1000
    paths = plot_trajectories("mit", 3, ("lm",), tmp_path / "traj", iterations=5)
    assert all(path.stat().st_size > 1000 for path in paths)
    csv = tmp_path / "metrics.csv"
    pd.DataFrame({"frames": [0, 10], "episode_return": [-1.0, -0.5]}).to_csv(csv, index=False)
    assert all(p.stat().st_size > 1000 for p in plot_learning_curves([csv], tmp_path / "lc"))


# ----- cache keys: what a cell is computed from -------------------------------------------------


def _specs(experiment, dataset, method="mm-pgo"):
    """The cell specifications of one cell of ``experiment`` on ``dataset``."""
    from popbench.harness import outliers, scalability, table1

    if experiment == "table1":
        return table1.cell_specs(
            table1.Table1Config(datasets=(dataset,), robots=(1,), methods=(method,))
        ) + [table1.optimum_spec(dataset)]
    if experiment == "outliers":
        return outliers.cell_specs(
            outliers.OutliersConfig(datasets=(dataset,), robots=1, methods=(method,), seeds=(0,))
        )
    return scalability.cell_specs(
        scalability.ScalabilityConfig(dataset=dataset, robots=(1,), methods=(method,))
    ) + [table1.optimum_spec(dataset)]


@pytest.mark.parametrize("experiment", ["table1", "outliers", "scalability"])
def test_cell_keys_change_when_the_graph_file_changes(tmp_path, experiment):
    graph = ring_g2o(tmp_path / "u.g2o")
    before = [cell_key(spec) for spec in _specs(experiment, str(graph))]
    assert before == [cell_key(spec) for spec in _specs(experiment, str(graph))]  # stable
    ring_g2o(graph, dx="0.951")  # one measurement edited (and the size changed)
    after = [cell_key(spec) for spec in _specs(experiment, str(graph))]
    assert not set(before) & set(after)


def test_registered_datasets_are_keyed_by_their_pinned_sha256():
    from popbench import datasets

    for spec in _specs("table1", "mit"):
        assert spec["dataset_sha256"] == datasets.DATASETS["mit"].sha256


def test_source_fingerprint_follows_the_code_not_git(tmp_path):
    from popbench import __version__
    from popbench.harness.cache import code_fingerprint, source_fingerprint

    package = tmp_path / "pkg"  # no git repository anywhere under tmp_path
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    (package / "sub" / "b.py").write_text("y = 2\n")
    first = source_fingerprint([package])
    (package / "notes.md").write_text("docs do not count\n")
    assert source_fingerprint([package]) == first
    (package / "sub" / "b.py").write_text("y = 3\n")
    assert source_fingerprint([package]) != first
    assert code_fingerprint().startswith(f"{__version__}+")
    assert {spec["code"] for spec in _specs("table1", "mit")} == {code_fingerprint()}


def test_code_fingerprint_changes_the_cell_keys(monkeypatch):
    from popbench.harness import cache

    before = [cell_key(spec) for spec in _specs("outliers", "mit")]
    monkeypatch.setattr(cache, "code_fingerprint", lambda: "0.1.0+edited")
    after = [cell_key(spec) for spec in _specs("outliers", "mit")]
    assert not set(before) & set(after)


@pytest.mark.parametrize("method", ["prop-v1", "prop-v2"])
def test_learned_cells_are_keyed_by_the_actor_checkpoint(tmp_path, monkeypatch, method):
    from popbench.harness import cache

    checkpoint = tmp_path / "actor.pt"
    checkpoint.write_bytes(b"weights one")
    monkeypatch.setattr(cache, "checkpoint_path", lambda method, training_seed=0: checkpoint)
    before = cell_key(_specs("table1", "mit", method)[0])
    checkpoint.write_bytes(b"weights two, retrained")
    assert cell_key(_specs("table1", "mit", method)[0]) != before
    assert "checkpoint_sha256" not in _specs("table1", "mit", "mm-pgo")[0]


def test_a_refiners_training_seed_cell_starts_from_the_same_seeds_refined_cell():
    from popbench.harness import table1
    from popbench.harness.cache import checkpoint_sha256
    from popbench.harness.refining import refined_spec

    config = table1.Table1Config(
        datasets=("mit",), robots=(7,), methods=("prop-v1", "prop-v2"), training_seeds=(0, 1, 2)
    )
    specs = table1.cell_specs(config)
    assert [(s["method"], s["training_seed"]) for s in specs] == [
        (method, seed) for method in ("prop-v1", "prop-v2") for seed in (0, 1, 2)
    ]
    assert len({s["checkpoint_sha256"] for s in specs}) == 3  # one actor per training seed
    for prop_v1, prop_v2 in zip(specs[:3], specs[3:], strict=True):
        assert refined_spec(prop_v2) == prop_v1
        assert prop_v1["checkpoint_sha256"] == checkpoint_sha256(
            "prop-v1", prop_v1["training_seed"]
        )


@pytest.mark.slow  # imports torch
def test_checkpoint_path_is_the_one_the_learned_methods_load():
    from agents.methods import DEFAULT_CHECKPOINT
    from popbench.harness.cache import checkpoint_path

    assert checkpoint_path("prop-v1") == checkpoint_path("prop-v2") == DEFAULT_CHECKPOINT
    assert DEFAULT_CHECKPOINT.is_file() and checkpoint_path("mm-pgo") is None


def test_fresh_recomputes_cached_cells(tmp_path):
    specs = [{"dataset": "d", "robots": n} for n in range(3)]
    computed = []

    def compute(spec):
        computed.append(spec["robots"])
        return {"F": float(len(computed))}

    cache = CellCache(tmp_path / "cells")
    run_cells(specs, compute, cache, progress=False)
    run_cells(specs, compute, cache, progress=False)
    assert computed == [0, 1, 2]
    rows = run_cells(specs, compute, cache, progress=False, fresh=True)
    assert computed == [0, 1, 2, 0, 1, 2]
    assert [row["F"] for row in rows] == [4.0, 5.0, 6.0]
    assert [cache.get(spec)["F"] for spec in specs] == [4.0, 5.0, 6.0]  # overwritten


@pytest.mark.parametrize("text", ["VERTEX_SE2 0 0 0 0\n", "a,b\n1,2\n", "frames,label\n1,x\n"])
def test_plot_curves_rejects_a_file_that_is_not_a_metrics_csv(tmp_path, text: str) -> None:
    from popbench.errors import ValueRangeError
    from popbench.plotting import plot_learning_curves

    path = tmp_path / "metrics.csv"
    path.write_text(text)
    with pytest.raises(ValueRangeError, match="metrics.csv.*'frames' column"):
        plot_learning_curves([path], tmp_path / "curves")
