"""Seeded stream of distributed problems per batch element of the PGO environment."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from popbench.distributed import DistributedProblem

ProblemSource = Callable[[int], DistributedProblem]


class ProblemSampler:
    """Seeded problems per batch element: episode ``k`` of element ``b`` uses the seed
    ``SeedSequence([seed, b, k])`` (so every element has its own reproducible stream)."""

    def __init__(self, source: ProblemSource, batch: int, seed: int = 0) -> None:
        self.source = source
        self.batch = batch
        self.seed(seed)

    def seed(self, seed: int) -> None:
        """Restart every element's stream from ``seed``."""
        self.base_seed = int(seed)
        self.episodes = np.zeros(self.batch, np.int64)

    def draw(self, element: int) -> DistributedProblem:
        """The next problem of batch element ``element``."""
        key = [self.base_seed, element, int(self.episodes[element])]
        self.episodes[element] += 1
        return self.source(int(np.random.SeedSequence(key).generate_state(1)[0]))
