"""The team reward: what the tables score, the global F after the consensus, paid at the end.

Under ``team_reward="consensus"`` every robot of a batch element receives, on the step its
episode ends, the same terminal reward

    r_T = max(−1, 1 − F_c(x_T) / F_c(x_0)),

where F_c(x) is eq. 1 of the global estimate that the default consensus
(:func:`popbench.consensus.reconcile.reconcile`: frame alignment, then 200 ADMM iterations) makes
of the robots' local estimates x, x_0 those at the episode's start and x_T those at its end: the
drop in the tables' metric that the team's corrections caused, as a share of the start's. Every
other step pays 0, so the credit for the team's result must be assigned over the whole episode and
across the robots: the credit-assignment problem of cooperative MARL. ``"consensus+shaping"`` adds
the per-robot local-F reward of every step (the actors' task's) on top; ``"none"`` is that reward
alone. The bound −1 keeps a diverging episode's reward on the scale of a good one's.

Cost: one consensus per episode start and one per end (≈ 0.45 s each at n = 7, 60 poses per
robot, on one core of the 2-core CPU; docs/environment.md).
"""

from __future__ import annotations

import numpy as np
import torch

from popbench import objective
from popbench.consensus.reconcile import reconcile


def consensus_objective(problem, local_poses: list[np.ndarray]) -> float:
    """F (eq. 1) of the default consensus of ``local_poses`` (one ``(n_r, 3)`` array per robot,
    rows in ``problem.local_vertices(r)`` order)."""
    return float(objective.objective(problem.graph, reconcile(problem, local_poses).poses))


class TeamReward:
    """The terminal team reward of one core (module docstring): remembers F_c(x_0) per element.

    Args:
        mode: one of :data:`TEAM_REWARDS` other than ``"none"``.
    """

    def __init__(self, mode: str) -> None:
        self.shaping = mode == "consensus+shaping"
        self.start_objective: dict[int, float] = {}

    def started(self, core, elements: list[int]) -> None:
        """Record F_c(x_0) of the batch elements whose episodes (re)started."""
        for element in elements:
            problem = core.problems[element]
            self.start_objective[element] = consensus_objective(problem, core.local_poses(element))

    def reward(self, core, local_reward: torch.Tensor, finishing: torch.Tensor) -> torch.Tensor:
        """``(B, n)`` rewards of a step: 0 (or ``local_reward`` with shaping) plus r_T on the
        elements of ``finishing (B,)`` bool (the episode ended at this step)."""
        reward = local_reward if self.shaping else torch.zeros_like(local_reward)
        terminal = torch.zeros_like(reward[:, 0])
        for element in finishing.nonzero().flatten().tolist():
            final = consensus_objective(core.problems[element], core.local_poses(element))
            start = self.start_objective[element]
            terminal[element] = max(-1.0, 1.0 - final / max(start, 1e-12))
        return reward + terminal.unsqueeze(-1)
