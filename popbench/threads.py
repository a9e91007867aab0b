"""How many threads BLAS, OpenMP and torch may use: pinned, so that results do not depend on
the caller's environment or on what else runs on the machine.

Unconverged table cells are sensitive to round-off, and the order of a multi-threaded BLAS
reduction depends on the thread count; torch's small-tensor work also slows down many-fold when
its thread pool competes for a busy core. Every table cell, ``popbench solve`` and
``popbench train`` therefore run with one thread by default (``--threads`` overrides).

Two mechanisms, because a library reads its thread count at different times:

* :func:`thread_environment` — the environment variables that a library reads when it is
  loaded (``OMP_NUM_THREADS`` …): for child processes, and for this process before numpy or
  torch is first imported;
* :func:`limited_threads` — a context manager that also changes the libraries already loaded
  (threadpoolctl for BLAS and OpenMP, ``torch.set_num_threads`` when torch is imported).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

DEFAULT_THREADS = 1
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def check_threads(threads: int) -> int:
    """``threads`` if it is a positive integer, else ValueRangeError."""
    from popbench.errors import ValueRangeError

    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueRangeError("threads", threads, "an integer ≥ 1")
    return threads


def thread_environment(threads: int = DEFAULT_THREADS) -> dict[str, str]:
    """The environment variables that pin BLAS / OpenMP / torch to ``threads`` threads in a
    process started with them (``{"OMP_NUM_THREADS": "1", ...}``)."""
    value = str(check_threads(threads))
    return dict.fromkeys(THREAD_VARIABLES, value)


@contextmanager
def pinned_environment(threads: int = DEFAULT_THREADS) -> Iterator[None]:
    """Set :func:`thread_environment` in ``os.environ`` for the block (processes started inside
    it inherit the pin), then restore the previous values."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(thread_environment(threads))
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@contextmanager
def limited_threads(threads: int = DEFAULT_THREADS) -> Iterator[None]:
    """Run the block with ``threads`` threads in BLAS, OpenMP and torch.

    Sets :func:`thread_environment` (read by numpy or torch imported inside the block; it is
    kept afterwards, since a library loaded under it keeps that count anyway), limits the BLAS
    and OpenMP libraries already loaded through threadpoolctl, and calls
    ``torch.set_num_threads`` if torch is already imported (it is not imported for this). The
    previous limits are restored on exit.
    """
    from threadpoolctl import threadpool_limits

    os.environ.update(thread_environment(threads))
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(threads)
    try:
        with threadpool_limits(limits=threads):
            yield
    finally:
        if torch is not None and before is not None:
            torch.set_num_threads(before)
