"""The reward scale c of a run: 1 / std of the first rewards that vary, kept for the run.

Both learners multiply every reward by c before the critic sees it (reward normalisation:
PPO on its first collected batch, GA-SAC on its warm-up). A batch whose rewards are all equal
carries no scale: under the team task's terminal reward (envs.team) the first batches hold only
the 0 of the steps before any episode ends, and 1 / max(std, 1e-6) made c = 10⁶ and the value
targets 10⁶ times the returns (critic losses of 10⁸–10¹¹ in the 2026-12-07 MAPPO team runs).
Such a batch sets nothing; the run uses c = 1 until a batch's rewards vary.

A reward that fixes its own scale skips the rule (:func:`run_scale`): the team task's
terminal reward alone (``team_reward="consensus"``) is a share of F in [−1, 1], already the scale
of a return, and its first varying batch may hold a single small terminal reward (one 2026-12-07
MAPPO team run got c = 102 from one, and critic losses up to 542), so its c is 1.
"""

from __future__ import annotations

import torch

from envs.modes import EnvModes

SCALE_UNSET = 0.0  # the c of a run whose rewards have not varied yet (rewards then pass × 1)
VARYING_STD = 1e-6  # rewards whose std is below this are taken as all equal


def reward_scale(reward: torch.Tensor) -> float:
    """c = 1 / std of ``reward`` (any shape), or SCALE_UNSET when its values are all equal.

    >>> reward_scale(torch.tensor([0.0, 0.0, 0.0]))
    0.0
    >>> round(reward_scale(torch.tensor([0.0, 2.0])), 4)  # std (Bessel) √2
    0.7071
    """
    std = float(reward.float().std()) if reward.numel() > 1 else 0.0
    return 1.0 / std if std > VARYING_STD else SCALE_UNSET


def run_scale(modes: EnvModes, reward: torch.Tensor) -> float:
    """The c a run keeps, from its first rewards ``reward``: 1 where the task's reward fixes its
    own scale (the team task's terminal reward alone, module docstring), else
    :func:`reward_scale` (SCALE_UNSET while they have not varied)."""
    return 1.0 if modes.team_reward == "consensus" else reward_scale(reward)


def applied(scale: float) -> float:
    """The factor the rewards are multiplied by under ``scale`` (1 while it is unset)."""
    return 1.0 if scale == SCALE_UNSET else scale
