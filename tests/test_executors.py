"""Executors: ``--jobs 1``, ``--jobs 2`` and a local Ray instance give the same non-time columns
of a quick Table I; a killed parallel run resumes without recomputing a finished cell; a worker
with other code refuses; the thread pin."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from popbench.harness.cache import CellCache
from popbench.harness.executors import (
    CellTask,
    CodeMismatchError,
    Execution,
    ProcessExecutor,
    Run,
    SerialExecutor,
    make_executor,
    run_cell,
)
from popbench.harness.profiles import GAP_COLUMNS
from popbench.threads import limited_threads, thread_environment

TIME_COLUMNS = ("wall_s", "parallel_s", *GAP_COLUMNS)


def _quick(out: Path, execution: Execution) -> pd.DataFrame:
    from popbench.harness.table1 import Table1Config, run_table1

    run_table1(Table1Config.quick(out=out), Run(execution, progress=False))
    return pd.read_csv(out / "table1.csv")


def _non_time(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.drop(columns=list(TIME_COLUMNS))


@pytest.fixture(scope="module")
def serial_table(tmp_path_factory):
    from tests.conftest import require_dataset

    require_dataset("mit")
    return _quick(tmp_path_factory.mktemp("serial"), Execution(jobs=1))


@pytest.mark.dataset
@pytest.mark.slow
def test_jobs_1_and_2_give_identical_non_time_columns(serial_table, tmp_path):
    parallel = _quick(tmp_path, Execution(jobs=2))
    assert list(parallel.columns) == list(serial_table.columns)
    pd.testing.assert_frame_equal(_non_time(parallel), _non_time(serial_table), check_exact=True)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["execution"]["jobs"] == 2 and manifest["execution"]["threads"] == 1
    cells = len(serial_table) + 1  # one per method (Table I's defaults) + the optimum
    assert manifest["execution"]["beside_others"] == manifest["execution"]["cells"] == cells


@pytest.mark.dataset
@pytest.mark.slow
def test_ray_local_instance_gives_the_same_columns(serial_table, tmp_path, monkeypatch):
    ray = pytest.importorskip("ray")
    # Ray's default 10 s for its node to register is too short on a loaded 2-core machine
    # (seen: "GCS cannot find the node ... before the timeout" beside a training run).
    monkeypatch.setenv("RAY_raylet_start_wait_time_s", "120")
    table = _quick(tmp_path, Execution(executor="ray", jobs=2))  # a local instance, 2 CPUs
    assert not ray.is_initialized()  # the instance it started is shut down
    assert list(table.columns) == list(serial_table.columns)
    pd.testing.assert_frame_equal(_non_time(table), _non_time(serial_table), check_exact=True)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["execution"]["executor"] == "ray"


KILLED_RUN = """
import sys
from pathlib import Path
from popbench.harness.executors import Execution, Run
from popbench.harness.table1 import Table1Config, run_table1
if __name__ == "__main__":
    config = Table1Config(datasets=("mit",), robots=(3,), methods=("cc-pgo", "ml-pgo", "lm"),
                          iterations=200, out=Path(sys.argv[1]))
    run_table1(config, Run(Execution(jobs=2), progress=False))
"""


@pytest.mark.dataset
@pytest.mark.slow
def test_killed_parallel_run_recomputes_no_finished_cell(tmp_path):
    from tests.conftest import require_dataset

    require_dataset("mit")
    script = tmp_path / "run.py"
    script.write_text(KILLED_RUN)
    out, cells = tmp_path / "out", tmp_path / "out" / "cells"
    root = str(Path(__file__).resolve().parents[1])
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])),
    }
    process = subprocess.Popen(
        [sys.executable, str(script), str(out)],
        env=env,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 300
    while len(list(cells.glob("*.json"))) < 2 and process.poll() is None:
        assert time.monotonic() < deadline, "no cell finished in 300 s"
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGKILL)  # the driver and its workers
    process.wait()
    finished = {path: path.stat().st_mtime_ns for path in cells.glob("*.json")}
    assert 2 <= len(finished) < 4, process.stderr.read()  # the optimum and some cells, not all

    again = subprocess.run(
        [sys.executable, str(script), str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert again.returncode == 0, again.stderr
    assert len(list(cells.glob("*.json"))) == 4  # optimum + 3 cells
    for path, mtime in finished.items():
        assert path.stat().st_mtime_ns == mtime, f"{path.name} was recomputed"
    assert len(pd.read_csv(out / "table1.csv")) == 3


# ----- the layer itself (no dataset) --------------------------------------------------------------


def square(spec):
    return {"x": spec["x"], "y": spec["x"] ** 2, "pid": os.getpid()}


def test_run_cell_refuses_other_code_and_writes_through_the_cache(tmp_path):
    with pytest.raises(CodeMismatchError, match="install the same popbench"):
        run_cell(CellTask(square, {"x": 2}, tmp_path, code="0.0.0+other"))
    assert not list(tmp_path.glob("*.json"))
    row = run_cell(CellTask(square, {"x": 3}, tmp_path, measured={"jobs": 2}))
    assert CellCache(tmp_path).get({"x": 3}) == row
    assert CellCache(tmp_path).measured({"x": 3}) == {"jobs": 2}


def test_process_executor_runs_cells_in_other_processes(tmp_path):
    from popbench.harness.runner import run_cells

    specs = [{"x": x} for x in range(4)]
    rows = run_cells(
        specs, square, CellCache(tmp_path), execution=Execution(jobs=2), progress=False
    )
    assert [row["y"] for row in rows] == [0, 1, 4, 9]
    assert os.getpid() not in {row["pid"] for row in rows}
    again = run_cells(
        specs, square, CellCache(tmp_path), execution=Execution(jobs=2), progress=False
    )
    assert again == rows  # every cell from the cache


def test_one_job_or_one_cell_runs_in_this_process():
    assert isinstance(make_executor(Execution(jobs=1), 5), SerialExecutor)
    assert isinstance(make_executor(Execution(jobs=4), 1), SerialExecutor)
    assert isinstance(make_executor(Execution(executor="serial", jobs=4), 5), SerialExecutor)
    executor = make_executor(Execution(jobs=2), 5)
    try:
        assert isinstance(executor, ProcessExecutor) and executor.workers == 2
    finally:
        executor.close(cancel=False)


@pytest.mark.parametrize(
    "options", [{"jobs": 0}, {"executor": "dask"}, {"threads": 0}, {"address": "auto"}]
)
def test_execution_rejects_bad_options(options):
    from popbench.errors import ValueRangeError

    with pytest.raises(ValueRangeError):
        Execution(**options)


def test_thread_pin_environment_and_torch():
    assert thread_environment(3)["OMP_NUM_THREADS"] == "3"
    assert thread_environment()["OPENBLAS_NUM_THREADS"] == "1"
    torch = pytest.importorskip("torch")
    before = torch.get_num_threads()
    with limited_threads(1):
        assert torch.get_num_threads() == 1
        assert os.environ["MKL_NUM_THREADS"] == "1"
    assert torch.get_num_threads() == before


# ----- the command line ---------------------------------------------------------------------------


def test_run_jobs_flag_reaches_the_manifest_and_bad_flags_fail_first(tmp_path, capsys):
    from conftest import ring_g2o

    from popbench.cli import main

    graph = ring_g2o(tmp_path / "ring.g2o")
    args = ["run", "table1", "--datasets", str(graph), "--robots", "1,2", "--methods", "mm-pgo"]
    args += ["--iterations", "5", "--out", str(tmp_path / "D")]
    assert main([*args, "--jobs", "2", "--threads", "1"]) == 0, capsys.readouterr().err
    execution = json.loads((tmp_path / "D" / "manifest.json").read_text())["execution"]
    assert execution["executor"] == "process" and execution["jobs"] == 2
    assert execution["cells"] == 3 and execution["beside_others"] == 3  # optimum + 2 cells
    capsys.readouterr()
    for bad, message in (
        (["--executor", "dask"], "invalid --executor 'dask'"),
        (["--address", "HEAD:6379"], "invalid --address 'HEAD:6379'"),
        (["--jobs", "0"], "--jobs"),
    ):
        assert main([*args, "--fresh", *bad]) != 0
        assert message in capsys.readouterr().err


def test_solve_threads_flag(tmp_path, capsys, monkeypatch):
    """--threads reaches the thread limit around the solve, and does not change the result."""
    from conftest import ring_g2o

    from popbench import threads
    from popbench.cli import main

    limits = []
    limited = threads.limited_threads

    def spy(count: int):
        limits.append(count)
        return limited(count)

    monkeypatch.setattr(threads, "limited_threads", spy)
    graph = ring_g2o(tmp_path / "ring.g2o")
    values = []
    for count in ("2", "1"):
        assert main(["solve", str(graph), "--threads", count, "--json"]) == 0
        values.append(json.loads(capsys.readouterr().out)["F"])
    assert limits == [2, 1]
    assert values[0] == values[1]
