"""End to end: ``popbench run table1`` writes its tables and resumes after being killed."""

import json
import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

pytestmark = [pytest.mark.dataset, pytest.mark.slow]


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
    assert set(frame["method"]) == {"cc-pgo", "ml-pgo", "mm-pgo", "prop-v1", "prop-v2"}
    assert (frame["gap"] > -1e-6).all()  # the optimum is a floor on every row
    assert frame["paper_F"].notna().all()
    assert "Prop-V2" in (tmp_path / "table1.md").read_text()
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["command"].startswith("popbench run table1")
    assert manifest["wall_s"] > 0 and manifest["hardware"]["cores"] >= 1


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
