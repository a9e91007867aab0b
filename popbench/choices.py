"""The named choices that the command line checks before it imports anything heavy, each listed
once: the modules that implement a choice import its list from here (no NumPy, so ``popbench
--help`` stays fast).

* :data:`NOISE_LEVELS` — the synthetic problems' noise levels (:mod:`popbench.problems.synthetic`),
  and :data:`NOISES` — those and :data:`SLAM_LEVEL`, the SLAM-shaped maps
  (:mod:`popbench.problems.slam_maps`);
* :data:`PARTITIONS` — how poses are split among robots (:mod:`popbench.problems.partition`);
* :data:`ROBUST_KERNELS` — the robust kernels of MM-PGO (:mod:`baselines.robust`), besides
  ``"none"``;
* :data:`DEFAULT_GROUP_SIZE` — the false loop closures per group of the vertigo-grouped outlier
  model (:mod:`popbench.outliers`);
* :data:`STEP_RULES` — how the environment executes a correction (:class:`envs.core.PGOCore`),
  :data:`TRAINING_STEP_RULE` — the one every task trains in, and :data:`DEFAULT_STEP_RULE` — the
  one prop-v1 and ``popbench run heldout`` use, chosen on 30 held-out SLAM-shaped maps
  (docs/training.md, "The step rule at inference");
* :data:`OBJECTIVES` — the costs ``lm``, ``gnc`` and ``local-lm`` minimise (docs/solve.md);
* :data:`TEAM_REWARDS` — the environment's team reward modes (:mod:`envs.team`).
"""

from __future__ import annotations

# σ (odometry, intra-robot loop, inter-robot relative and loop), same units on x, y [m], θ [rad].
NOISE_LEVELS: dict[str, tuple[float, float, float]] = {
    "V1": (0.06, 0.10, 0.14),
    "V2": (0.10, 0.14, 0.18),
    "V3": (0.14, 0.18, 0.22),
}
# the level under which popbench.problems.synthetic.make_problem draws SLAM maps
SLAM_LEVEL = "SLAM"
NOISES = (*NOISE_LEVELS, SLAM_LEVEL)
PARTITIONS = ("metis", "contiguous")
ROBUST_KERNELS = ("huber", "gm", "welsch")
DEFAULT_GROUP_SIZE = 5  # vertigo-grouped: edges per group
# "clip": the paper's bounded correction, the training rule; docs/environment.md, "The step rule"
STEP_RULES = ("clip", "line-search", "nonmonotone", "search-with-clip")
TRAINING_STEP_RULE = STEP_RULES[0]  # every task's and committed actor's (envs.modes.EnvModes)
DEFAULT_STEP_RULE = "line-search"
OBJECTIVES = ("F", "chi2")
# "none": each robot's own reward; "consensus": the team's terminal drop in F after the
# consensus; "consensus+shaping": both (envs.team, docs/environment.md "The team task")
TEAM_REWARDS = ("none", "consensus", "consensus+shaping")
