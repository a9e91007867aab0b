"""The learners by algorithm name (``TrainConfig.algorithm_name``, one of
:data:`agents.config.ALGORITHMS`): one :class:`agents.learner.Learner` record each, which carries
what the algorithm can do, so that no code tests an algorithm's name.
"""

from __future__ import annotations

from agents.config import TrainConfig
from agents.gasac_trainer import GASAC
from agents.learner import Learner
from agents.ppo_trainer import IPPO, MAPPO

LEARNERS: dict[str, Learner] = {"ga-sac": GASAC, "mappo": MAPPO, "ippo": IPPO}


def learner_of(config: TrainConfig) -> Learner:
    """The :class:`~agents.learner.Learner` of ``config.algorithm_name``."""
    return LEARNERS[config.algorithm_name]
