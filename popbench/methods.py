"""The one method interface and its registry of method records.

Every method is a function ``solve(problem, budget, **options) -> Result`` over a
:class:`~popbench.problems.distributed.DistributedProblem`, starting from the problem's start
(``problem.graph.poses``, see :mod:`popbench.solvers.initial`). Each registered method is one
:class:`MethodRecord`: its solve function as a ``"module:function"`` string, imported lazily (so
the core never imports ``baselines``, ``agents`` or ``envs``, and ``popbench --help`` stays
fast), and the facts the harness, the cache, the reports and the CLI read — its table label, the
checkpoint its results depend on, its capabilities. Adding a method = one solve function + one
record in :data:`METHODS` (+ tests); nothing else names methods.

Never worse than the start: :func:`get_method` hands out every solve function wrapped by
:func:`never_worse`, so no registered method returns an estimate worse than the start it was
given — on F (eq. 1), or on the cost it minimised where that is chi2 or a robust cost (its
:class:`~popbench.status.Status`) — it returns the start instead and says so in
``extras["never_worse"]``. On a problem with injected outliers the rule is not applied;
docs/never_worse.md has the choice. The wrapper also gives every Result its ``status`` and holds
the graph's ``FIX`` poses (:func:`hold_fixed`).

Example:
    >>> from popbench.methods import Budget, get_method
    >>> from popbench.objective import evaluate
    >>> from popbench.problems.synthetic import make_problem
    >>> problem = make_problem(robots=3, poses_per_robot=20, seed=0)
    >>> result = get_method("lm")(problem, Budget(iterations=20))
    >>> bool(result.F < evaluate(problem.graph, problem.graph.poses).F)
    True
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.util
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from popbench import objective, se2
from popbench.errors import PopbenchError, ValueRangeError
from popbench.status import NeverWorse, Status, measure, settled


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
        history: the objective ``history_objective`` after each round (``(K,)``, the first
            entry the start; ``K = iterations + 1`` unless the method documents its rounds).
        history_s: ``(K,)`` simulated parallel time [s] at each ``history`` entry, cumulative
            (the first entry the set-up counted in ``parallel_s``, the last ``parallel_s``), or
            None where the method does not record it (the convergence profiles,
            :mod:`popbench.harness.profiles`).
        history_objective: what ``history`` holds: ``"F"`` (eq. 1) or ``"F_chordal"``.
        inlier_mask: ``(M,)`` bool, False where the method flags an edge as an outlier, or None.
        messages: poses exchanged between robots over the run.
        extras: method-specific figures (certificate, restarts, ...).
        status: where it stopped (:class:`~popbench.status.Status`); a method that sets none
            gets one from :func:`never_worse` (its ``history_objective`` minimised, converged
            by :func:`~popbench.status.settled`).
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
    history_s: np.ndarray | None = None
    history_objective: str = "F"
    status: Status | None = None

    def summary(self) -> dict[str, float | int]:
        """The scalar outcome every table row and ``popbench solve --json`` report, as plain
        Python numbers: F, F_chordal, chi2, wall_s, parallel_s, iterations, messages."""
        costs = {name: float(getattr(self, name)) for name in ("F", "F_chordal", "chi2")}
        times = {"wall_s": float(self.wall_s), "parallel_s": float(self.parallel_s)}
        counts = {"iterations": int(self.iterations), "messages": int(self.messages)}
        return {**costs, **times, **counts}


Method = Callable[..., Result]


@dataclasses.dataclass(frozen=True)
class MethodRecord:
    """One registered method: where its solve function is and what the harness needs to know.

    Attributes:
        name: the registry key (``--method NAME``, the ``method`` column of every table).
        solve: ``"module:function"`` of its ``solve(problem, budget, **options) -> Result``,
            imported on first use (:func:`get_method`).
        label: its name in table headers and figure legends (``"MM-PGO"``).
        checkpoint: a file its results depend on besides the code (the learned methods' actor
            weights), ``"package:relative/path"`` (found without importing the package) or a
            path; its sha256 keys the cached cells (:mod:`popbench.harness.cache`). None: none.
            For a learned method: the actor of training seed 0, the one a plain run uses.
        seed_checkpoints: the actors of training seeds 1, 2, … of the same training recipe
            (same form as ``checkpoint``), so that a table can report a learned method over
            its training seeds (``popbench run table1 --training-seeds``).
        has_inlier_mask: its ``Result.inlier_mask`` flags outliers (Table II's methods).
        outlier_options: the options Table II (``popbench run outliers``) runs it with, as
            ``(name, value)`` pairs; the table names them beside the method (mm-pgo: the kernel
            and robust mode chosen by the rule in docs/outliers.md; prop-v1: the actor of the
            recipe trained with outliers, whose fitted outlier gate flags them, as
            ``("checkpoint", "package:relative/path")``, its sha256 keying Table II's cells).
        learned: it runs a trained policy (``checkpoint`` holds it).
        centralised: it solves the whole graph in one process, whatever the robots (a
            reference, not one of Table I's distributed methods).
        episodic: it runs one episode of fixed length; ``Budget.iterations`` does not bound it.
        refines: the registered method whose output it refines (its ``**options`` are passed
            on to that method's solve), or None. Its solve takes ``refined=``, that method's
            Result on the same problem with the same options (None: it computes it first), and
            reports ``wall_s`` / ``parallel_s`` as that Result's plus its refinement's [s]; the
            harness passes the refined method's cached cell (:mod:`popbench.harness.refining`).
        holds_fixed: it holds any set of poses fixed (the graph's ``FIX`` poses); the others
            hold one (the gauge) by a rigid motion of their answer and refuse more.
        options: ``"module:Class"`` of a dataclass whose fields are options its solve takes
            through ``**options`` besides its named parameters (so that methods sharing options
            declare them once: cc-pgo's and ml-pgo's derive from
            :class:`baselines.rbcd.MethodOptions`), imported on first use
            (:func:`method_options`); None: its solve names them all.
    """

    name: str
    solve: str
    label: str
    checkpoint: str | None = None
    seed_checkpoints: tuple[str, ...] = ()
    has_inlier_mask: bool = False
    outlier_options: tuple[tuple[str, Any], ...] = ()
    learned: bool = False
    centralised: bool = False
    episodic: bool = False
    refines: str | None = None
    options: str | None = None
    holds_fixed: bool = False

    @property
    def training_seeds(self) -> range:
        """The training seeds whose actors the record names (none without a checkpoint)."""
        return range(0 if self.checkpoint is None else 1 + len(self.seed_checkpoints))

    def checkpoint_path(self, training_seed: int = 0) -> Path | None:
        """The checkpoint of ``training_seed`` (:attr:`checkpoint` for 0, else the
        :attr:`seed_checkpoints` entry) as a path (a ``"package:relative/path"`` resolved
        against the package's folder without importing it), or None (no checkpoint, or no such
        package); ValueRangeError for a seed the record names no actor of."""
        if self.checkpoint is None:
            return None
        if training_seed not in self.training_seeds:
            allowed = ", ".join(map(str, self.training_seeds))
            raise ValueRangeError(f"training seed of {self.name}", training_seed, allowed)
        return named_path((self.checkpoint, *self.seed_checkpoints)[training_seed])


def named_path(named: str) -> Path | None:
    """A ``"package:relative/path"`` resolved against the package's folder without importing
    it, or a plain path; None where there is no such package."""
    package, separator, relative = named.partition(":")
    if not separator:
        return Path(named).expanduser()
    folder = package_folder(package)
    return None if folder is None else folder / relative


def package_folder(name: str) -> Path | None:
    """The folder of an importable package, found without importing it (no torch at startup),
    or None where there is no such package."""
    try:
        found = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    if found is None or not found.submodule_search_locations:
        return None
    return Path(next(iter(found.submodule_search_locations)))


# The n = 7 V2 actor (any n): the cpu-residual recipe's (imitation, then GA-SAC with the KL
# anchor), seed 0, chosen on the held-out protocol (docs/training.md, "The default actor"), and
# the same recipe's training seeds 1 and 2. Table II's problems have outliers: there prop-v1
# runs the actor of the recipe trained with them (cpu-imitation-robust), whose fitted outlier
# gate flags them (docs/outliers.md, "The outlier gate after the consensus").
ACTOR_CHECKPOINT = "agents:checkpoints/actor-V2-n7-residual.pt"
OUTLIER_ACTOR_CHECKPOINT = "agents:checkpoints/imitation-V2-n7-robust.pt"
ACTOR_SEED_CHECKPOINTS = tuple(
    f"agents:checkpoints/actor-V2-n7-residual-s{seed}.pt" for seed in (1, 2)
)

METHODS: dict[str, MethodRecord] = {
    record.name: record
    for record in (
        MethodRecord("lm", "popbench.solvers.lm:solve", "LM", centralised=True, holds_fixed=True),
        MethodRecord(
            "gnc",
            "popbench.solvers.gnc:solve",
            "GNC",
            has_inlier_mask=True,
            centralised=True,
            holds_fixed=True,
        ),
        MethodRecord(
            "cc-pgo", "baselines.cc_pgo:solve", "CC-PGO", options="baselines.cc_pgo:Options"
        ),
        MethodRecord(
            "ml-pgo", "baselines.ml_pgo:solve", "ML-PGO", options="baselines.ml_pgo:Options"
        ),
        MethodRecord(
            "mm-pgo",
            "baselines.mm_pgo:solve",
            "MM-PGO",
            has_inlier_mask=True,
            outlier_options=(("kernel", "huber"), ("robust_mode", "authors")),
        ),
        MethodRecord(
            "prop-v1",
            "agents.methods:solve_prop_v1",
            "Prop-V1",
            checkpoint=ACTOR_CHECKPOINT,
            seed_checkpoints=ACTOR_SEED_CHECKPOINTS,
            has_inlier_mask=True,
            outlier_options=(("checkpoint", OUTLIER_ACTOR_CHECKPOINT),),
            learned=True,
            episodic=True,
        ),
        MethodRecord(
            "prop-v2",
            "agents.methods:solve_prop_v2",
            "Prop-V2",
            checkpoint=ACTOR_CHECKPOINT,
            seed_checkpoints=ACTOR_SEED_CHECKPOINTS,
            has_inlier_mask=True,
            learned=True,
            episodic=True,
            refines="prop-v1",
        ),
        MethodRecord("local-lm", "popbench.solvers.local_lm:solve", "local-lm"),
        # mm-pgo started from a one-pass estimate (popbench.solvers.warm_start; Table I at n = 7)
        MethodRecord(
            "prop-v1+mm-pgo",
            "popbench.solvers.warm_start:solve_prop_v1_mm_pgo",
            "Prop-V1+MM-PGO",
            checkpoint=ACTOR_CHECKPOINT,
            seed_checkpoints=ACTOR_SEED_CHECKPOINTS,
            learned=True,
            refines="prop-v1",
        ),
        MethodRecord(
            "local-lm+mm-pgo",
            "popbench.solvers.warm_start:solve_local_lm_mm_pgo",
            "local-lm+MM-PGO",
            refines="local-lm",
        ),
    )
}


# Every other entry point of the layers above the core that the harness and the command line
# load, by name, imported on first use (:func:`entry_point`): named here only, so the core
# never imports ``agents`` and ``agents`` never imports the harness or the command line.
ENTRY_POINTS: dict[str, str] = {
    "train.presets": "agents.config:PRESETS",  # dict[str, agents.config.TrainConfig]
    "train.algorithms": "agents.config:ALGORITHMS",  # the names of --algorithm
    "train.overrides": "agents.config:with_overrides",  # (TrainConfig, ["part.field=value"])
    "train.run": "agents.trainer:train",  # (TrainConfig, resume=bool) -> a run with .summary()
    "train.gate_config": "agents.config:OutlierGateConfig",
    "train.fit_gate": "agents.gate_training:fit_checkpoint",  # (path, out, config) -> str
    "train.tasks": "envs.tasks:TASKS",  # dict[str, envs.tasks.Task], the benchmark tasks
    "train.with_task": "agents.config:with_task",  # (TrainConfig, Task) -> config on the task
    "heldout.row": "agents.heldout:evaluate_row",  # a held-out cell's spec -> its measures
    "heldout.checkpoints": "agents.heldout:row_checkpoints",
    "heldout.label": "agents.heldout:row_label",  # (row, checkpoint) -> the row's label
    "heldout.policy": "agents.user_policy:describe_policy",  # (policy, arg, env) -> spec entries
    "curves.snapshots": "agents.checkpoint:run_snapshots",  # a run's actor snapshots
    "curves.identity": "agents.checkpoint:snapshot_identity",  # what a snapshot's run compares
}


def entry_point(name: str) -> Any:
    """The object registered under ``name`` in :data:`ENTRY_POINTS`, imported on first use."""
    if name not in ENTRY_POINTS:
        raise ValueRangeError("entry point", name, ", ".join(ENTRY_POINTS))
    return load_object(ENTRY_POINTS[name])


def method_record(name: str) -> MethodRecord:
    """The record registered under ``name`` (ValueRangeError listing the names otherwise)."""
    if name not in METHODS:
        raise ValueRangeError("method", name, ", ".join(METHODS))
    return METHODS[name]


def label(name: str) -> str:
    """The table label of ``name``: its record's, or the name itself if it is not registered
    (a row from an older run)."""
    return METHODS[name].label if name in METHODS else name


def distributed_methods() -> tuple[str, ...]:
    """The registered methods that are not centralised, in registry order (Table I's)."""
    return tuple(name for name, record in METHODS.items() if not record.centralised)


def method_options(name: str) -> tuple[str, ...]:
    """The keyword options the method registered under ``name`` accepts: its solve function's
    named parameters after ``problem`` and ``budget``, then the fields of its record's
    :attr:`~MethodRecord.options` dataclass, then the options of the method it refines
    (:attr:`MethodRecord.refines`, which gets its ``**options``). A trailing ``**_`` swallows
    anything else, so callers that take options from users should check them against this
    list. A refiner's ``refined`` (a Result the harness passes) is not a user option."""
    names = [
        parameter.name
        for parameter in list(inspect.signature(get_method(name)).parameters.values())[2:]
        if parameter.kind in (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY)
        and parameter.name != "refined"
    ]
    record = method_record(name)
    if record.options is not None:
        names += [field.name for field in dataclasses.fields(load_object(record.options))]
    if record.refines is not None:
        names += [option for option in method_options(record.refines) if option not in names]
    return tuple(names)


def load_object(path: str) -> Any:
    """The object named by ``"module:attribute"``, importing the module on first use
    (``ModuleNotFoundError`` if it is not installed)."""
    module_name, _, attribute = path.partition(":")
    return getattr(importlib.import_module(module_name), attribute)


def get_method(name: str) -> Method:
    """The ``solve`` function registered under ``name``, wrapped by :func:`never_worse`."""
    record = method_record(name)
    try:
        return never_worse(load_object(record.solve), record)
    except ModuleNotFoundError as error:
        raise ValueRangeError("method", name, f"an implemented method ({error})") from None


def never_worse(solve: Method, record: MethodRecord | None = None) -> Method:
    """``solve`` (same signature) returning the problem's start instead of its estimate where
    the estimate is worse than the start, ``problem.graph.poses`` (:func:`keep_better`), its
    ``status`` filled in where the method set none, and the graph's ``FIX`` poses held
    (:func:`hold_fixed`; ``record`` says whether the method holds them itself)."""

    @functools.wraps(solve)
    def guarded(problem: Any, *args: Any, **kwargs: Any) -> Result:
        holds = record is not None and record.holds_fixed
        fixed = check_fixed(problem.graph, holds, "" if record is None else record.name)
        result = solve(problem, *args, **kwargs)
        if fixed is not None and not holds:
            result = hold_fixed(problem.graph, result, fixed)
        if result.status is None:
            result.status = measure(
                problem.graph,
                result.poses,
                result.history_objective,
                settled(result.history),
                result.iterations,
            )
        return keep_better(problem, result)

    return guarded


def check_fixed(graph: Any, holds: bool, method: str) -> int | None:
    """The one pose a method that cannot hold poses fixed must hold as its gauge (the graph's
    single ``FIX`` pose), or None; PopbenchError for more than one ``FIX`` pose where the method
    does not hold them (``holds``)."""
    fixed = getattr(graph, "fixed", None)
    if fixed is None or holds:
        return None
    if len(fixed) == 1:
        return int(fixed[0])
    raise PopbenchError(
        f"method {method} cannot hold {len(fixed)} FIX poses fixed (it holds one, the gauge): "
        "use lm or gnc, or keep one FIX line"
    )


def hold_fixed(graph: Any, result: Result, vertex: int) -> Result:
    """``result`` moved rigidly so that pose ``vertex`` is at the start's value bit for bit (its
    gauge; every cost is invariant under a rigid motion of all poses)."""
    target = graph.poses[vertex]
    motion = se2.compose(target, se2.inverse(result.poses[vertex]))
    poses = se2.compose(motion[None, :], result.poses)
    poses[vertex] = target
    return dataclasses.replace(result, poses=poses)


def keep_better(problem: Any, result: Result) -> Result:
    """``result``, or the start of ``problem`` (a DistributedProblem) where ``result`` is worse:
    on the cost it minimised (``result.status``) for a robust method or one minimising chi2,
    else on F (eq. 1; the F_chordal family is judged on F, its target).

    ``extras["never_worse"]`` (a :class:`~popbench.status.NeverWorse`) says which was returned:
    ``METHOD``, ``START`` (then ``extras["F_method"]`` is the estimate's F,
    ``extras["never_worse_cost"]`` the cost compared, and the last ``history`` entry the start's
    cost in ``history_objective`` units; times, iterations, the inlier mask and ``status`` stay
    the method's: where it stopped), or ``NOT_APPLIED`` on a problem with injected outliers
    (``problem.outlier_mask`` flags some edge)."""
    mask = getattr(problem, "outlier_mask", None)
    if mask is not None and bool(np.any(mask)):
        result.extras["never_worse"] = NeverWorse.NOT_APPLIED
        return result
    start = problem.graph.poses
    costs = objective.evaluate(problem.graph, start)
    status = result.status
    own = status is not None and (status.robust is not None or status.objective == "chi2")
    if own:
        worse, compared = status.cost > status.start_cost, _cost_name(status)
    else:
        worse, compared = result.F > costs.F, "F"
    if not worse:
        result.extras["never_worse"] = NeverWorse.METHOD
        return result
    history = np.array(result.history, dtype=float, copy=True)
    if history.size:
        history[-1] = getattr(costs, result.history_objective)
    extras = {
        **result.extras,
        "never_worse": NeverWorse.START,
        "F_method": result.F,
        "never_worse_cost": compared,
    }
    return dataclasses.replace(
        result,
        poses=np.array(start, copy=True),
        **costs._asdict(),
        history=history,
        extras=extras,
    )


def _cost_name(status: Status) -> str:
    """``"chi2"``, or ``"tls(F)"`` for a robust kernel over a base cost."""
    return status.objective if status.robust is None else f"{status.robust}({status.objective})"
