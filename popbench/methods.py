"""The one method interface and its registry.

Every method is a function ``solve(problem, budget, **options) -> Result`` over a
:class:`~popbench.distributed.DistributedProblem`. The registry maps names to
``"module:function"`` strings and imports lazily, so the core never imports ``baselines``,
``agents`` or ``envs`` (and ``popbench --help`` stays fast).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from typing import Any

import numpy as np

from popbench.errors import ValueRangeError


@dataclasses.dataclass(frozen=True)
class Budget:
    """How long a method may run: ``iterations`` rounds (each method documents what one round
    is) and, optionally, a wall-clock cap in seconds."""

    iterations: int = 1000
    seconds: float | None = None


@dataclasses.dataclass
class Result:
    """What a method returns.

    Attributes:
        poses: ``(N, 3)`` global estimate.
        F, F_chordal, chi2: the costs of ``poses`` (see :mod:`popbench.objective`).
        wall_s: the whole run in one process [s].
        parallel_s: simulated makespan [s]: per round, the slowest robot's compute, plus
            consensus/communication rounds.
        iterations: rounds run.
        history: ``F`` after each round (``(iterations + 1,)``, the first entry the start).
        inlier_mask: ``(M,)`` bool, False where the method flags an edge as an outlier, or None.
        messages: poses exchanged between robots over the run.
        extras: method-specific figures (certificate, restarts, ...).
    """

    poses: np.ndarray
    F: float
    F_chordal: float
    chi2: float
    wall_s: float
    parallel_s: float
    iterations: int
    history: np.ndarray
    inlier_mask: np.ndarray | None = None
    messages: int = 0
    extras: dict[str, Any] = dataclasses.field(default_factory=dict)


Method = Callable[..., Result]

METHODS: dict[str, str] = {
    "lm": "popbench.solvers.lm:solve",
    "cc-pgo": "baselines.cc_pgo:solve",
    "ml-pgo": "baselines.ml_pgo:solve",
    "mm-pgo": "baselines.mm_pgo:solve",
    "prop-v1": "agents.methods:solve_prop_v1",
    "prop-v2": "agents.methods:solve_prop_v2",
}


def get_method(name: str) -> Method:
    """The ``solve`` function registered under ``name``."""
    if name not in METHODS:
        raise ValueRangeError("method", name, ", ".join(METHODS))
    module_name, function_name = METHODS[name].split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        raise ValueRangeError("method", name, f"an implemented method ({error})") from None
    return getattr(module, function_name)
