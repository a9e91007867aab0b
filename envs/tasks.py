"""Named benchmark tasks of the PGO game: one record per task (in the spirit of BenchMARL's task
configs) with its environment options, its problem generator and its evaluation protocol.

``make_torchrl_env(task="actors")``, ``make_pettingzoo_env(task=...)`` and ``popbench train
--task ...`` read them; ``popbench tasks`` lists them. docs/environment.md ("Benchmark tasks")
says why each exists and what separates them.

Every task draws synthetic problems (:func:`popbench.problems.synthetic.make_problem`, a new seeded
problem every episode, :mod:`envs.sampler`); its evaluation protocol is that of ``popbench run
heldout``: ``problems`` held-out problems of the task's generator (seeds disjoint from every
training stream), each robot's local estimate brought through the consensus, scored by the global F
and the ATE (docs/harness.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from envs.modes import PAPER_MODES, TRAJECTORY_MODES, EnvModes
from popbench.errors import ValueRangeError


@dataclasses.dataclass(frozen=True)
class Task:
    """One benchmark task.

    Attributes:
        name: the registry key.
        summary: one line: what the task asks of an algorithm.
        modes: the environment's modes (:class:`envs.modes.EnvModes`; every task trains
            under the clipped step rule, the one the committed actors were trained in).
        reward: ``"localisation"`` (ground truth), ``"F"`` (the local objective), or None:
            ``"localisation"`` where the problems have ground truth, else ``"F"``.
        terminal_bonus: the terminal log-ratio bonus on the episode's last step.
        robots: agents ``n`` per problem; noise: ``"V1"``/``"V2"``/``"V3"``, or ``"SLAM"``
            (SLAM-shaped maps, :mod:`popbench.problems.slam_maps`).
        poses_per_robot: the synthetic generator's map size.
        outlier_rate_max: training problems get outliers at a rate ``U(0, outlier_rate_max)``.
        eval_problems: held-out problems of the evaluation protocol.
        eval_outlier_rate: outliers injected into every held-out problem.
    """

    name: str
    summary: str
    modes: EnvModes = PAPER_MODES
    reward: str | None = None
    terminal_bonus: bool = True
    robots: int = 7
    noise: str = "V2"
    poses_per_robot: int = 60
    outlier_rate_max: float = 0.0
    eval_problems: int = 100
    eval_outlier_rate: float = 0.0

    def core_options(self) -> dict[str, str]:
        """The mode keywords of :class:`envs.core.PGOCore` (:meth:`PGOCore.for_problems`)."""
        return self.modes.core_options()

    def env_options(self) -> dict[str, Any]:
        """The keywords of ``envs.make_torchrl_env`` / ``make_pettingzoo_env`` that build it."""
        options: dict[str, Any] = {
            **self.core_options(),
            "terminal_bonus": self.terminal_bonus,
            "robots": self.robots,
            "noise": self.noise,
            "poses_per_robot": self.poses_per_robot,
            "outlier_rate_max": self.outlier_rate_max,
        }
        if self.reward is not None:
            options["reward"] = self.reward
        return options

    def heldout_options(self) -> dict[str, Any]:
        """The evaluation protocol as ``popbench.harness.heldout.HeldoutConfig`` keywords."""
        return {
            "noise": (self.noise,),
            "robots": (self.robots,),
            "problems": self.eval_problems,
            "poses_per_robot": self.poses_per_robot,
            "outlier_rate": self.eval_outlier_rate,
        }


PAPER = Task(
    "paper",
    "the paper's game (§III-B): Δ moves the edge's head, poses in the first owned pose's "
    "frame, metric Δ, localisation reward with the terminal bonus",
)
ACTORS = dataclasses.replace(
    PAPER,
    name="actors",
    summary="what the shipped GA-SAC, MAPPO and IPPO actors train on: subtree correction, "
    "invariant observation, whitened Δ on a Gauss–Newton base step, local-F reward, no bonus",
    modes=TRAJECTORY_MODES,
    reward="F",
    terminal_bonus=False,
)
TASKS: dict[str, Task] = {
    task.name: task
    for task in (
        PAPER,
        ACTORS,
        dataclasses.replace(
            ACTORS,
            name="big-maps",
            summary="the actors' task on maps 2.5x longer (150 poses per robot): longer "
            "episodes, larger local graphs",
            poses_per_robot=150,
        ),
        dataclasses.replace(
            ACTORS,
            name="noisy",
            summary="the actors' task at the V3 noise level, the highest of "
            "popbench.problems.synthetic.NOISE_LEVELS",
            noise="V3",
        ),
        dataclasses.replace(
            ACTORS,
            name="outliers",
            summary="the actors' task with outliers: training rates U(0, 0.2), 10 % of the "
            "loop closures corrupted in every held-out problem",
            outlier_rate_max=0.2,
            eval_outlier_rate=0.1,
        ),
        dataclasses.replace(
            ACTORS,
            name="team",
            summary="the actors' task rewarded as a team: every robot gets 1 - F_c(end) / "
            "F_c(start) at the episode's end, F_c the F after the consensus (what the tables "
            "score), 0 before (envs.team)",
            modes=TRAJECTORY_MODES.replace(team_reward="consensus"),
        ),
        dataclasses.replace(
            ACTORS,
            name="slam-maps",
            summary="the actors' task on single-trajectory SLAM-shaped maps cut by METIS "
            "(popbench.problems.slam_maps; 40-80 poses per robot)",
            noise="SLAM",
            poses_per_robot=40,
        ),
    )
}


def get_task(name: str) -> Task:
    """The task ``name`` of :data:`TASKS`; a one-line :class:`ValueRangeError` otherwise."""
    if name not in TASKS:
        raise ValueRangeError("task", name, ", ".join(TASKS))
    return TASKS[name]
