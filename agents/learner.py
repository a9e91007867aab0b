"""The record of one training algorithm (:class:`Learner`): how ``agents.trainer.train`` builds,
saves, restores and trains its session, and what it can do. The records:
``agents.gasac_trainer.GASAC``, ``agents.ppo_trainer.MAPPO`` / ``IPPO``, registered by algorithm
name in :mod:`agents.algorithms`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

from tensordict import TensorDictBase

from agents.config import TrainConfig


@dataclasses.dataclass(frozen=True)
class Learner:
    """How `train` builds, saves, restores and trains one algorithm's session.

    `batches(session)` returns the per-batch learning step of a (possibly resumed) run: a
    `BatchLearner` (e.g. GA-SAC's replay and updates, agents.ppo_trainer's PPO epochs).
    """

    name: str  # the progress bar's label
    build: Callable[[TrainConfig], Any]
    restore: Callable[[Any, dict[str, Any]], None]
    state: Callable[[Any], dict[str, Any]]
    batches: Callable[[Any], BatchLearner]
    fields: tuple[str, ...]  # metrics.csv's columns
    # the TrainConfig parts it reads besides model, algorithm, experiment, task and imitation
    # (a resumed run must keep them: agents.resume)
    config_parts: tuple[str, ...] = ()


class BatchLearner(Protocol):
    """One algorithm's learning from each collected batch (used by `_run`)."""

    def learn(self, data: TensorDictBase) -> dict[str, Any]:
        """Learn from a collector batch [num_envs, T]; the metrics row's entries it sets."""

    def evaluate(self, eval_env: Any) -> dict[str, Any]:
        """Extra entries of the row at an evaluation point (after the held-out F reduction)."""
