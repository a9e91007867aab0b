"""The one method interface and its registry.

Every method is a function ``solve(problem, budget, **options) -> Result`` over a
:class:`~popbench.distributed.DistributedProblem`. The registry maps names to
``"module:function"`` strings and imports lazily, so the core never imports ``baselines``,
``agents`` or ``envs`` (and ``popbench --help`` stays fast).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np

from popbench.errors import ValueRangeError


@dataclasses.dataclass(frozen=True)
class Budget:
    """How long a method may run: ``iterations`` rounds (each method documents what one round
    is) and, optionally, a wall-clock cap in seconds.

    ``on_round``, if given, is told the number of rounds done after each round (the CLI's
    progress bar); methods report through :meth:`round_done`, which costs nothing without it.
    """

    iterations: int = 1000
    seconds: float | None = None
    on_round: Callable[[int], None] | None = dataclasses.field(
        default=None, compare=False, repr=False
    )

    def round_done(self, rounds: int) -> None:
        """Tell ``on_round`` (if any) that ``rounds`` rounds have run so far."""
        if self.on_round is not None:
            self.on_round(rounds)


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
    "gnc": "popbench.solvers.gnc:solve",
    "cc-pgo": "baselines.cc_pgo:solve",
    "ml-pgo": "baselines.ml_pgo:solve",
    "mm-pgo": "baselines.mm_pgo:solve",
    "prop-v1": "agents.methods:solve_prop_v1",
    "prop-v2": "agents.methods:solve_prop_v2",
}


# Methods whose ``**options`` are passed on to another registered method's solve.
FORWARDS: dict[str, str] = {"prop-v2": "prop-v1"}


def method_options(name: str) -> tuple[str, ...]:
    """The keyword options the method registered under ``name`` accepts: its solve function's
    named parameters after ``problem`` and ``budget`` (and those of the method it forwards
    ``**options`` to, see :data:`FORWARDS`). A trailing ``**_`` swallows anything else, so
    callers that take options from users should check them against this list."""
    names = [
        parameter.name
        for parameter in list(inspect.signature(get_method(name)).parameters.values())[2:]
        if parameter.kind in (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY)
    ]
    if name in FORWARDS:
        names += [option for option in method_options(FORWARDS[name]) if option not in names]
    return tuple(names)


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
