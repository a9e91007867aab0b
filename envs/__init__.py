"""Multi-agent PGO environments (paper §III-B): TorchRL (:class:`envs.torchrl_env.PGOEnv`) and
PettingZoo (:class:`envs.pettingzoo_env.PGOParallelEnv`) over one batched torch core
(:mod:`envs.core`).

Problems come from the synthetic generator (:func:`popbench.problems.synthetic.make_problem`, a new
seeded problem every episode) or from a dataset (``dataset="intel"`` or a path: the same problem
every episode, split among ``robots`` by :meth:`DistributedProblem.from_graph`).

Training outliers (``outlier_rate_max`` > 0, synthetic problems only): every drawn problem gets
outliers injected with the project's model (:func:`popbench.outliers.with_outliers`, the default
loop-closure candidates), at a rate drawn per problem from ``U(0, outlier_rate_max)``; the
problem's ``outlier_mask`` carries the labels (the expert leaves them out of its optimum, the
supervised gate loss reads them). The default 0 draws clean problems.

Padding maxima (``max_vertices``, ``max_edges``, ``max_degree``) default to: for a dataset, its
exact local-graph maxima; for the synthetic generator, the maxima over :data:`PROBE_PROBLEMS`
(:data:`SLAM_PROBE_PROBLEMS` for the ``"SLAM"`` maps) problems drawn with fixed seeds
(independent of ``seed``, so envs with different seeds share their specs), times
:data:`PADDING_MARGIN`, rounded up to a multiple of 8. A later problem of the stream that does
not fit is replaced by a redraw (:class:`envs.sampler.ProblemSampler`, which counts them); one
loaded into the core directly (``PGOCore.for_problems``, ``load``) that does not fit raises a
one-line :class:`popbench.errors.ValueRangeError` naming the option to raise.

torchrl and pettingzoo are imported only when an env is made. On a small shared CPU, prefer
``torch.set_num_threads(1)``: the env's tensors are small (measured: docs/environment.md).

Example:
    >>> from envs import make_torchrl_env
    >>> env = make_torchrl_env(robots=3, batch_size=2, poses_per_robot=10, seed=0)
    >>> env.rollout(3).batch_size  # 2 problems, 3 steps of random actions
    torch.Size([2, 3])
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np

from envs.observation import Dimensions
from popbench.problems.distributed import DistributedProblem

if TYPE_CHECKING:
    from envs.pettingzoo_env import PGOParallelEnv
    from envs.tasks import Task
    from envs.torchrl_env import PGOEnv

PROBE_PROBLEMS = 32
PROBE_SEED = 2**31 - 1  # probe seeds PROBE_SEED + k: apart from the training streams
PADDING_MARGIN = 1.25
# The "SLAM" maps (popbench.problems.slam_maps) draw their loop density and size per map, so their
# local graphs vary more: at 40 poses per robot the largest local edge count over 600 maps was 180,
# over the 32 probes 128 (2026-12-04); 512 probes cover that tail.
SLAM_PROBE_PROBLEMS = 512

__all__ = [
    "edge_mask_transform",
    "make_problem_source",
    "make_pettingzoo_env",
    "make_torchrl_env",
    "task_options",
]


def make_problem_source(
    robots: int = 7,
    noise: str = "V2",
    dataset: str | None = None,
    poses_per_robot: int = 60,
    loop_ratio: float = 0.15,
    partition: str = "metis",
    start: str = "odometry",
    max_vertices: int | None = None,
    max_edges: int | None = None,
    max_degree: int | None = None,
    outlier_rate_max: float = 0.0,
    start_noise: float = 0.0,
) -> tuple[Any, Dimensions, bool]:
    """``(source, dims, has_ground_truth)``: a ``seed -> DistributedProblem`` callable and the
    padding maxima (see the module docstring).

    Args:
        robots: robots (agents) per problem.
        noise: synthetic noise level ``"V1"``/``"V2"``/``"V3"``.
        dataset: a registered dataset name or a g2o/TORO path; ``None`` for synthetic problems.
        poses_per_robot, loop_ratio: synthetic generator options.
        partition: ``"metis"`` or ``"contiguous"`` (datasets only).
        start: dataset initial estimate, a name of :data:`popbench.solvers.initial.STARTS`
            (``"odometry"``, the composition, default; ``"chordal"``; ``"given"``, the file's).
        max_vertices, max_edges, max_degree: padding maxima overriding the defaults.
        outlier_rate_max: the largest training outlier rate (module docstring; synthetic only).
        start_noise: > 0: synthetic problems start off their odometry, every measurement of the
            composition perturbed by that many standard deviations
            (:func:`popbench.problems.synthetic.perturbed_start`; the sanity task).
    """
    if dataset is None:
        source = _Synthetic(
            robots, noise, poses_per_robot, loop_ratio, outlier_rate_max, start_noise
        )
        count = SLAM_PROBE_PROBLEMS if noise == "SLAM" else PROBE_PROBLEMS
        probes = [source(PROBE_SEED + k) for k in range(count)]
        dims = Dimensions.of(probes, PADDING_MARGIN, multiple=8)
        has_truth = True
    else:
        from popbench.errors import ValueRangeError

        if outlier_rate_max > 0:
            raise ValueRangeError("outlier_rate_max", outlier_rate_max, "0 for a dataset")
        if start_noise > 0:
            raise ValueRangeError("start_noise", start_noise, "0 for a dataset")
        problem = dataset_problem(dataset, robots, partition, start)
        source = _Constant(problem)
        dims = Dimensions.of([problem])
        has_truth = problem.graph.ground_truth is not None
    dims = Dimensions(
        max_vertices or dims.vertices, max_edges or dims.edges, max_degree or dims.degree
    )
    return source, dims, has_truth


def dataset_problem(
    dataset: str, robots: int, partition: str = "metis", start: str = "odometry"
) -> DistributedProblem:
    """A dataset split among ``robots`` (:meth:`DistributedProblem.from_graph`, seed 0),
    carrying the ``start`` estimate (:func:`popbench.solvers.initial.with_start`; default the
    odometry composition, ``"given"`` the file's poses)."""
    from popbench.datasets import load
    from popbench.solvers.initial import with_start

    graph = with_start(load(dataset), start)
    return DistributedProblem.from_graph(graph, robots, partition, start=start)


@dataclasses.dataclass(frozen=True)
class _Synthetic:
    """A problem source drawing :func:`popbench.problems.synthetic.make_problem` problems by seed,
    started off their odometry when ``start_noise`` > 0, with outliers at a rate ``U(0,
    outlier_rate_max)`` per problem when ``outlier_rate_max`` > 0 (the start, the rate and the
    corruption seeded by the problem's seed)."""

    robots: int
    noise: str
    poses_per_robot: int
    loop_ratio: float
    outlier_rate_max: float = 0.0
    start_noise: float = 0.0

    def __call__(self, seed: int) -> DistributedProblem:
        from popbench.problems.synthetic import make_problem, perturbed_start

        problem = make_problem(
            self.robots, self.noise, self.poses_per_robot, self.loop_ratio, seed=seed
        )
        if self.start_noise > 0:
            start_seed = int(np.random.SeedSequence([seed, 2]).generate_state(1)[0])
            problem = perturbed_start(problem, self.start_noise, start_seed)
        if self.outlier_rate_max <= 0:
            return problem
        from popbench.outliers import with_outliers

        rate_seed, outlier_seed = np.random.SeedSequence([seed, 1]).generate_state(2)
        rate = np.random.default_rng(int(rate_seed)).uniform(0.0, self.outlier_rate_max)
        return with_outliers(problem, rate, seed=int(outlier_seed))


class _Constant:
    """A problem source that ignores the seed (a fixed dataset problem)."""

    def __init__(self, problem: DistributedProblem) -> None:
        self.problem = problem

    def __call__(self, seed: int) -> DistributedProblem:
        return self.problem


def _split_options(options: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Separate problem-source options from env options."""
    source_keys = {
        "dataset",
        "poses_per_robot",
        "loop_ratio",
        "partition",
        "start",
        "max_vertices",
        "max_edges",
        "max_degree",
        "outlier_rate_max",
        "start_noise",
    }
    source = {key: value for key, value in options.items() if key in source_keys}
    env = {key: value for key, value in options.items() if key not in source_keys}
    return source, env


def task_options(
    task: str | Task | None, robots: int | None, noise: str | None, options: dict[str, Any]
) -> tuple[int, str, dict[str, Any]]:
    """``(robots, noise, options)`` of a benchmark ``task`` (a name of
    :data:`envs.tasks.TASKS` or a :class:`~envs.tasks.Task`; None: the paper's game) with the
    keywords given (not None) overriding the task's."""
    from envs.tasks import PAPER, get_task

    record = get_task(task) if isinstance(task, str) else task or PAPER
    given = {"robots": robots, "noise": noise}
    merged = {**record.env_options(), **{k: v for k, v in given.items() if v is not None}}
    merged.update(options)
    return merged.pop("robots"), merged.pop("noise"), merged


def make_torchrl_env(
    robots: int | None = None,
    batch_size: int | tuple[()] = 32,
    noise: str | None = None,
    seed: int = 0,
    device: str = "cpu",
    task: str | Task | None = None,
    **options: Any,
) -> PGOEnv:
    """A batched TorchRL :class:`~envs.torchrl_env.PGOEnv` (``B = batch_size`` problems;
    ``batch_size=()``: one problem, unbatched).

    ``task``: a benchmark task (a name of :data:`envs.tasks.TASKS`, e.g. ``"actors"``, or a
    :class:`~envs.tasks.Task`; default the paper's game, ``"paper"``): its robots, noise,
    generator and modes are the defaults that the keywords given here override. Options: those
    of :func:`make_problem_source` (``dataset``, ``poses_per_robot``, ``loop_ratio``,
    ``partition``, ``start``, ``max_*``) and of ``PGOEnv`` (``delta_max``, ``reward``,
    ``invalid_edge``, ``dtype``, the modes). ``reward`` defaults to the task's, else to
    ``"localisation"`` when the problems have ground truth, else ``"F"``.
    """
    from envs.torchrl_env import PGOEnv

    robots, noise, options = task_options(task, robots, noise, options)
    source_options, env_options = _split_options(options)
    source, dims, has_truth = make_problem_source(robots, noise, **source_options)
    env_options.setdefault("reward", "localisation" if has_truth else "F")
    return PGOEnv(source, robots, dims, batch_size, seed, device, **env_options)


def make_pettingzoo_env(
    robots: int | None = None,
    noise: str | None = None,
    seed: int = 0,
    task: str | Task | None = None,
    **options: Any,
) -> PGOParallelEnv:
    """A PettingZoo :class:`~envs.pettingzoo_env.PGOParallelEnv` (same options and ``task`` as
    :func:`make_torchrl_env`, without ``batch_size``/``device``/``dtype``; also ``action_mask``
    and ``render_mode``)."""
    from envs.pettingzoo_env import PGOParallelEnv

    robots, noise, options = task_options(task, robots, noise, options)
    source_options, env_options = _split_options(options)
    source, dims, has_truth = make_problem_source(robots, noise, **source_options)
    env_options.setdefault("reward", "localisation" if has_truth else "F")
    return PGOParallelEnv(source, robots, dims, seed, **env_options)


def edge_mask_transform() -> Any:
    """The transform a ``SerialEnv`` / ``ParallelEnv`` of these envs takes over it, so that its
    action spec carries the workers' live edge masks (TorchRL's ``ActionMask`` pattern;
    :func:`envs.torchrl_env.edge_mask_transform`, docs/environment.md)."""
    from envs.torchrl_env import edge_mask_transform as make

    return make()
