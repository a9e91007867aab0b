"""Convergence profiles: time to a relative gap (first entry at or below, no interpolation), the
table's columns, the per-round times of every method and the figures."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from popbench.harness.profiles import (
    GAP_COLUMNS,
    gap_column,
    time_to_gap,
    time_to_gap_columns,
)

# gaps 9, 3, 0.5, 0.25, 0.75 (a restart), 0.125: exact in binary floating point
HISTORY = [10.0, 4.0, 1.5, 1.25, 1.75, 1.125]
TIMES = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0]


def test_time_to_gap_is_the_first_entry_at_or_below_the_threshold():
    times = time_to_gap(HISTORY, TIMES, 1.0, thresholds=(3.0, 0.5, 0.3, 0.125, 0.1))
    # 3.0 and 0.5 reached exactly (at or below); 0.3 at the first entry below it, not undone by
    # the later rise; 0.125 only at the last entry; 0.1 never (NaN)
    np.testing.assert_array_equal(times, [1.0, 2.0, 4.0, 16.0, np.nan])


def test_time_to_gap_without_times_or_history_is_nan():
    assert np.isnan(time_to_gap(HISTORY, None, 1.0)).all()
    assert np.isnan(time_to_gap(None, TIMES, 1.0)).all()
    assert time_to_gap(HISTORY, TIMES, 1.0).shape == (len(GAP_COLUMNS),)


def test_columns_use_the_optimum_of_the_history_objective():
    assert [gap_column(t) for t in (1e-1, 1e-2, 1e-3)] == list(GAP_COLUMNS)
    assert GAP_COLUMNS == ("time_gap_1e-1_s", "time_gap_1e-2_s", "time_gap_1e-3_s")
    optima = {"d": {"F_star": 1.0, "F_chordal_star": 2.0}}
    rows = [
        {"dataset": "d", "history": [1.5, 1.0078125, 1.0], "history_s": [0, 1, 3]},
        {
            "dataset": "d",
            "history": [3.0, 2.1, 2.001],
            "history_s": [0, 2, 5],
            "history_objective": "F_chordal",
        },
        {"dataset": "d", "F": 1.0},  # a row cached before histories were kept
    ]
    frame = time_to_gap_columns(rows, optima)
    assert list(frame.columns) == list(GAP_COLUMNS)
    np.testing.assert_array_equal(
        frame.to_numpy(), [[1.0, 1.0, 3.0], [2.0, 5.0, 5.0], [np.nan, np.nan, np.nan]]
    )


@pytest.mark.dataset
@pytest.mark.slow
def test_quick_table_has_the_columns_the_times_and_the_figures(tmp_path):
    from tests.conftest import require_dataset

    require_dataset("mit")
    from popbench.harness.executors import Run
    from popbench.harness.table1 import Table1Config, run_table1

    methods = ("cc-pgo", "ml-pgo", "mm-pgo", "local-lm", "prop-v2")
    config = Table1Config.quick(out=tmp_path, methods=methods, iterations=30, init="chordal")
    run_table1(config, Run(progress=False))
    table = pd.read_csv(tmp_path / "table1.csv")
    assert set(GAP_COLUMNS) <= set(table.columns) and "F_chordal_star" in table
    assert table["time_gap_1e-1_s"].notna().any()
    times = table[list(GAP_COLUMNS)].to_numpy()  # (cells, thresholds), loosest first
    assert not (times > table[["parallel_s"]].to_numpy()).any()
    assert not (times[:, 1:] < times[:, :-1]).any()  # a tighter gap is never reached sooner
    assert not (np.isnan(times[:, :-1]) & ~np.isnan(times[:, 1:])).any()
    assert "t(gap≤0.01) [s]" in (tmp_path / "table1.md").read_text()
    assert r"t(gap$\le$0.01) [s]" in (tmp_path / "table1.tex").read_text()
    for suffix in ("png", "pdf"):
        assert (tmp_path / f"profile-mit-n3.{suffix}").stat().st_size > 0  # the largest n
    rows = [json.loads(path.read_text())["row"] for path in (tmp_path / "cells").glob("*.json")]
    cells = [row for row in rows if "method" in row]
    assert {row["method"] for row in cells} == {*methods, "prop-v1"}  # prop-v2's dependency
    for row in cells:  # through the cache: every cell's history with its times
        assert len(row["history_s"]) == len(row["history"]) > 1
        assert np.all(np.diff(row["history_s"]) >= 0)
        assert row["history_s"][-1] == pytest.approx(row["parallel_s"], rel=1e-12)
