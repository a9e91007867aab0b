"""Where table cells run: in this process, in local worker processes, or as Ray tasks.

The executor is a thin layer. Every cell runs through the same function, :func:`run_cell`: it
checks that the worker runs the driver's code, pins the thread count
(:func:`popbench.threads.limited_threads`), computes the row and, where the worker shares the
driver's disk, writes it through the cell cache at once — so a run killed mid-way keeps every
cell that finished, whichever executor ran it. The executors only decide where
:func:`run_cell` is called:

* :class:`SerialExecutor` — in this process, one cell after another;
* :class:`ProcessExecutor` — ``jobs`` worker processes on this machine (``spawn`` start
  method, so no state is inherited by forking a process that may hold threads), started with
  the thread pin in their environment;
* :class:`RayExecutor` — one Ray task per cell (``num_cpus=1``) on a running Ray cluster
  (``address``) or on a local instance started for the run; the rows come back to the driver,
  which writes them into its cache (the cluster's nodes need not share a disk; a node that sees
  the driver's cell folder reads and writes the refined cells there, see
  :mod:`popbench.harness.refining`).
"""

from __future__ import annotations

import concurrent.futures as futures
import dataclasses
import multiprocessing
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Literal, Protocol

from popbench.errors import ValueRangeError
from popbench.threads import (
    DEFAULT_THREADS,
    check_threads,
    limited_threads,
    pinned_environment,
    thread_environment,
)

Spec = Mapping[str, Any]
Row = dict[str, Any]
Compute = Callable[[Spec], Row]
EXECUTORS = ("serial", "process", "ray")
ExecutorName = Literal["serial", "process", "ray"]


class CodeMismatchError(RuntimeError):
    """A worker runs other code than the driver (another checkout or version on a Ray node):
    its rows would be cached under the driver's code fingerprint, so it refuses the cell."""


@dataclasses.dataclass(frozen=True)
class Execution:
    """How a run executes its cells.

    ``jobs``: cells at once (None: ``os.cpu_count()`` for ``process``; the cluster's CPUs for
    ``ray``); ``executor``: ``serial`` | ``process`` | ``ray`` (``process`` with one job runs
    serially); ``address``: the Ray cluster to connect to (None: start a local instance with
    ``jobs`` CPUs); ``threads``: BLAS / OpenMP / torch threads per cell.
    """

    jobs: int | None = None
    executor: ExecutorName = "process"
    address: str | None = None
    threads: int = DEFAULT_THREADS

    def __post_init__(self) -> None:
        if self.executor not in EXECUTORS:
            raise ValueRangeError("executor", self.executor, " | ".join(EXECUTORS))
        if self.jobs is not None and (isinstance(self.jobs, bool) or self.jobs < 1):
            raise ValueRangeError("jobs", self.jobs, "an integer ≥ 1")
        if self.address is not None and self.executor != "ray":
            raise ValueRangeError("address", self.address, "only with the ray executor")
        check_threads(self.threads)

    @classmethod
    def serial(cls, threads: int = DEFAULT_THREADS) -> Execution:
        """One cell after another in this process."""
        return cls(jobs=1, executor="serial", threads=threads)

    def record(self, jobs: int) -> dict[str, Any]:
        """The manifest's view of this execution with the ``jobs`` actually used."""
        return {
            "executor": self.executor,
            "jobs": jobs,
            "threads": self.threads,
            "cores": os.cpu_count(),
            "address": self.address,
        }


@dataclasses.dataclass(frozen=True)
class Run:
    """How an experiment runs: where its cells run (``execution``, default serially in this
    process), whether every cell is recomputed (``fresh``: the cached ones are ignored and
    overwritten) and whether a progress bar shows (``progress``)."""

    execution: Execution = dataclasses.field(default_factory=Execution.serial)
    fresh: bool = False
    progress: bool = True


@dataclasses.dataclass(frozen=True)
class CellTask:
    """One cell for :func:`run_cell`: ``compute`` must be importable (a module-level function)
    for the process and Ray executors; ``cache_folder`` None leaves the writing to the driver;
    ``code`` the driver's :func:`popbench.harness.cache.code_fingerprint` (None: unchecked);
    ``measured`` how the cell's time is measured (:meth:`Execution.record`), cached beside it;
    ``shared_folder`` the run's cell folder, where ``compute`` reads and writes the cells a
    refining method starts from (:mod:`popbench.harness.refining`) when the worker sees it
    (None, or no such folder on the worker: it computes them itself)."""

    compute: Compute
    spec: Spec
    cache_folder: Path | None
    threads: int = DEFAULT_THREADS
    code: str | None = None
    measured: Mapping[str, Any] | None = None
    shared_folder: Path | None = None


def run_cell(task: CellTask) -> Row:
    """Compute one cell with its thread pin and cache it (the function every executor runs)."""
    from popbench.harness.cache import CellCache, code_fingerprint
    from popbench.harness.refining import using_cache

    if task.code is not None and task.code != code_fingerprint():
        raise CodeMismatchError(
            f"worker on {os.uname().nodename} runs code {code_fingerprint()}, the driver "
            f"{task.code}: install the same popbench on every node"
        )
    shared = task.shared_folder
    cache = CellCache(shared) if shared is not None and Path(shared).is_dir() else None
    with limited_threads(task.threads), using_cache(cache, task.measured):
        row = task.compute(task.spec)
    if task.cache_folder is not None:
        CellCache(task.cache_folder).put(task.spec, row, measured=task.measured)
    return row


class Executor(Protocol):
    """Runs :func:`run_cell` on tasks: ``workers`` at once, results as they finish."""

    workers: int
    writes_cache: bool  # whether run_cell writes the rows (else the driver does)

    def submit(self, task: CellTask) -> Any: ...
    def wait(self, handles: list[Any]) -> list[Any]: ...
    def result(self, handle: Any) -> Row: ...
    def close(self, cancel: bool) -> None: ...


class _Finished:
    """The handle of a cell that :class:`SerialExecutor` already computed."""

    __slots__ = ("row",)

    def __init__(self, row: Row) -> None:
        self.row = row


class SerialExecutor:
    """In this process; ``submit`` computes the cell at once."""

    workers = 1
    writes_cache = True

    def submit(self, task: CellTask) -> _Finished:
        return _Finished(run_cell(task))

    def wait(self, handles: list[Any]) -> list[Any]:
        return handles

    def result(self, handle: Any) -> Row:
        return handle.row

    def close(self, cancel: bool) -> None:
        pass


def _pin_worker(threads: int) -> None:
    """Initializer of a worker process: pin the libraries it has already loaded."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=threads)


class ProcessExecutor:
    """``workers`` local processes (spawned, thread pin in their environment), reused across
    cells; each computes one cell at a time."""

    writes_cache = True

    def __init__(self, workers: int, threads: int) -> None:
        self.workers = workers
        self._environment = pinned_environment(threads)
        self._environment.__enter__()  # the workers are spawned during the run, inheriting it
        self._pool = futures.ProcessPoolExecutor(
            max_workers=workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_pin_worker,
            initargs=(threads,),
        )

    def submit(self, task: CellTask) -> futures.Future:
        return self._pool.submit(run_cell, task)

    def wait(self, handles: list[Any]) -> list[Any]:
        done, _ = futures.wait(handles, return_when=futures.FIRST_COMPLETED)
        return list(done)

    def result(self, handle: Any) -> Row:
        return handle.result()

    def close(self, cancel: bool) -> None:
        try:
            if cancel:  # an error or Ctrl-C: do not wait for the cells in flight
                for process in list(getattr(self._pool, "_processes", {}).values()):
                    process.terminate()
            self._pool.shutdown(wait=not cancel, cancel_futures=cancel)
        finally:
            self._environment.__exit__(None, None, None)


def _package_root() -> str:
    """The folder that holds the ``popbench`` package (for a local Ray instance's workers)."""
    return str(Path(__file__).resolve().parents[2])


class RayExecutor:
    """One Ray task per cell (``num_cpus=1``) on the cluster at ``address``, or on a local Ray
    instance with ``jobs`` CPUs started for the run (and shut down after it)."""

    writes_cache = False

    def __init__(self, jobs: int | None, address: str | None, threads: int) -> None:
        try:
            import ray
        except ImportError:
            raise ValueRangeError(
                "executor", "ray", "installed Ray: pip install 'popbench[ray]'"
            ) from None
        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            pin = thread_environment(threads)
            environment = {
                **pin,
                "PYTHONPATH": os.pathsep.join(
                    [_package_root(), *filter(None, [os.environ.get("PYTHONPATH")])]
                ),
            }
            options: dict[str, Any] = {"log_to_driver": False, "include_dashboard": False}
            if address is None:
                options["num_cpus"] = jobs or os.cpu_count()
                options["runtime_env"] = {"env_vars": environment}
            else:
                options["runtime_env"] = {"env_vars": pin}
            ray.init(address=address, **options)
        cluster_cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = max(1, jobs or cluster_cpus)
        self._remote = ray.remote(num_cpus=1, max_retries=0)(run_cell)

    def submit(self, task: CellTask) -> Any:
        return self._remote.remote(task)

    def wait(self, handles: list[Any]) -> list[Any]:
        done, _ = self._ray.wait(handles, num_returns=1)
        return done

    def result(self, handle: Any) -> Row:
        try:
            return self._ray.get(handle)
        except self._ray.exceptions.RayTaskError as error:
            raise error.as_instanceof_cause() from None

    def close(self, cancel: bool) -> None:
        if self._started:
            self._ray.shutdown()


def make_executor(execution: Execution, cells: int) -> Executor:
    """The executor of ``execution`` for ``cells`` cells to compute: serial when only one
    process would run (``serial``, ``jobs`` 1 or a single cell) — no worker start-up cost."""
    if execution.executor == "ray":
        return RayExecutor(execution.jobs, execution.address, execution.threads)
    jobs = execution.jobs or os.cpu_count() or 1
    workers = min(jobs, cells)
    if execution.executor == "serial" or workers <= 1:
        return SerialExecutor()
    return ProcessExecutor(workers, execution.threads)


# The help of the command-line options that build an Execution (popbench run ...).
JOBS_HELP = (
    "Cells computed at once (default: this machine's cores; with --executor ray: the cluster's "
    "CPUs). Each cell runs in its own worker process with --threads threads; --jobs 1 computes "
    "them one after another in this process. F, gap, iterations and every other non-time "
    "column do not depend on it; the times of cells run side by side include their contention "
    "(manifest.json, execution.beside_others)."
)
EXECUTOR_HELP = (
    "process: local worker processes; serial: this process; ray: one Ray task per cell, on the "
    "cluster at --address or on a local Ray instance (pip install 'popbench[ray]'). All three "
    "run the same cell function and write the same cache (OUT/cells/)."
)
ADDRESS_HELP = (
    "Ray cluster to submit the cells to (--executor ray): HEAD:6379 after `ray start --head` on "
    "the head node, or 'auto' for the cluster this machine joined. Default: a local Ray "
    "instance with --jobs CPUs, shut down after the run."
)
THREADS_HELP = (
    "BLAS / OpenMP / torch threads per cell (pinned whatever OMP_NUM_THREADS says: results of "
    "unconverged cells depend on the thread count; the committed tables use 1)."
)
