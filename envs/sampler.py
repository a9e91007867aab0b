"""Seeded stream of distributed problems per batch element of the PGO environment."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from envs.observation import Dimensions, check_fits, fits
from popbench.problems.distributed import DistributedProblem

ProblemSource = Callable[[int], DistributedProblem]


#: redraws of one episode's problem before a problem that exceeds the padding is an error
MAX_REDRAWS = 100


class ProblemSampler:
    """Seeded problems per batch element: episode ``k`` of element ``b`` uses the seed
    ``SeedSequence([seed, b, k])`` (so every element has its own reproducible stream).

    With ``dims`` (the env's padding maxima), a drawn problem that exceeds them is replaced by
    the draw of ``SeedSequence([seed, b, k, j])``, j = 1, 2, … (at most :data:`MAX_REDRAWS`): the
    stream stays the same wherever its problems fit, and a generator whose sizes have a longer
    tail than the padding's probes (:mod:`envs`) trains on a distribution truncated
    there; ``redrawn`` counts the replaced problems."""

    def __init__(
        self, source: ProblemSource, batch: int, seed: int = 0, dims: Dimensions | None = None
    ) -> None:
        self.source = source
        self.batch = batch
        self.dims = dims
        self.redrawn = 0
        self.seed(seed)

    def seed(self, seed: int) -> None:
        """Restart every element's stream from ``seed``."""
        self.base_seed = int(seed)
        self.episodes = np.zeros(self.batch, np.int64)

    def draw(self, element: int) -> DistributedProblem:
        """The next problem of batch element ``element``."""
        key = [self.base_seed, element, int(self.episodes[element])]
        self.episodes[element] += 1
        problem = self.source(int(np.random.SeedSequence(key).generate_state(1)[0]))
        for attempt in range(1, MAX_REDRAWS + 1):
            if self.dims is None or fits(problem, self.dims):
                return problem
            self.redrawn += 1
            seed = np.random.SeedSequence([*key, attempt]).generate_state(1)[0]
            problem = self.source(int(seed))
        check_fits(problem, self.dims)  # the last redraw does not fit either: the error
        return problem
