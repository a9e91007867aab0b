"""The environment's modes: one frozen record, its allowed values and its defaults, once.

:class:`PGOCore <envs.core.PGOCore>` runs under an :class:`EnvModes`; a benchmark task
(:class:`envs.tasks.Task`) and an actor's configuration (``agents.config.TrainConfig.task``)
hold one. The defaults are the paper's environment (§III-B), :data:`PAPER_MODES`, which every
checkpoint written before the options existed was trained in; :data:`TRAJECTORY_MODES` is the
environment of the shipped trajectory-parameterised actors (the ``actors`` task).
docs/environment.md ("The modes in detail") says what each mode does and why it exists.

This module imports nothing of the environment, so the state, the step code and the agents
can all read it.
"""

from __future__ import annotations

import dataclasses

from popbench.choices import STEP_RULES, TEAM_REWARDS, TRAINING_STEP_RULE
from popbench.errors import ValueRangeError

CORRECTIONS = ("pose", "subtree")
OBSERVATIONS = ("paper", "invariant")
ACTION_SCALES = ("metric", "whitened")
BASES = ("none", "gauss-newton")
#: the local F values the ``nonmonotone`` step rule's reference is the largest of (the current
#: one and the agent's ``M − 1`` before it): Grippo, Lampariello & Lucidi's (1986) usual M = 10
NONMONOTONE_WINDOW = 10


@dataclasses.dataclass(frozen=True)
class EnvModes:
    """The modes of one environment; a value outside its list raises a one-line error. Each
    default is the first of its list (:data:`ALLOWED`), the step rule's the training one.

    Attributes:
        correction: "pose" (the paper's literal reading: Δ moves the edge's head) or "subtree"
            (Δ moves the head with its spanning-tree subtree).
        observation: "paper" (poses in the frame of the first owned pose) or "invariant"
            (poses relative to their tree parent).
        action_scale: "metric" (Δ in m, rad) or "whitened" (Δ in units of the edge's own
            standard deviation, Δmax applied after the conversion back).
        base: "none" (the actor's Δ is the correction) or "gauss-newton" (a residual policy:
            the environment adds one Gauss–Newton step on the chosen edge, envs.sweep).
        step_rule: one of ``popbench.choices.STEP_RULES``: "clip" (the executed Δ clipped to
            the bounds; every committed actor was trained so), "line-search" (unclipped, scaled
            so that no step raises the robot's local F), "nonmonotone", "search-with-clip".
        team_reward: one of ``popbench.choices.TEAM_REWARDS``: "none" (each robot's own
            reward), "consensus" (the team's terminal drop in F after the consensus, envs.team)
            or "consensus+shaping" (both).
    """

    correction: str = CORRECTIONS[0]
    observation: str = OBSERVATIONS[0]
    action_scale: str = ACTION_SCALES[0]
    base: str = BASES[0]
    step_rule: str = TRAINING_STEP_RULE
    team_reward: str = TEAM_REWARDS[0]

    def __post_init__(self) -> None:
        for name, allowed in ALLOWED.items():
            if getattr(self, name) not in allowed:
                raise ValueRangeError(name, getattr(self, name), ", ".join(allowed))

    @property
    def clips(self) -> bool:
        """Whether the executed Δ is clipped to the bounds (the training rule, the default)."""
        return self.step_rule == TRAINING_STEP_RULE

    def core_options(self) -> dict[str, str]:
        """The modes as keywords (``mode: value``), e.g. for a checkpoint's JSON."""
        return dataclasses.asdict(self)

    def replace(self, **changes: str) -> EnvModes:
        """These modes with ``changes`` (checked)."""
        return dataclasses.replace(self, **changes)


#: each mode's allowed values, the first of each the default
ALLOWED: dict[str, tuple[str, ...]] = {
    "correction": CORRECTIONS,
    "observation": OBSERVATIONS,
    "action_scale": ACTION_SCALES,
    "base": BASES,
    "step_rule": STEP_RULES,
    "team_reward": TEAM_REWARDS,
}
MODE_NAMES = tuple(ALLOWED)
PAPER_MODES = EnvModes()
TRAJECTORY_MODES = EnvModes(
    correction="subtree", observation="invariant", action_scale="whitened", base="gauss-newton"
)
