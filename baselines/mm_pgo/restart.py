"""AMM-PGO's acceleration state: the running averages and counters of its adaptive restart
(Fan & Murphey 2024, AMM-PGO), applied to team sums; the deviation for odometry starts and its
measurements: docs/mm_pgo.md.
"""

from __future__ import annotations

import dataclasses

import numpy as np

ETA_SLOW, ETA_FAST = 5e-4, 2.5e-2
MAX_SOFT_HITS_AVERAGE, MAX_SOFT_HITS_INCREASE = 10, 25


@dataclasses.dataclass
class RestartState:
    """The team's acceleration / adaptive-restart state (Fan & Murphey 2024, AMM-PGO).

    **Acceleration** (AMM-PGO): ``s_{k+1} = ½ + ½√(4s_k² + 1)``,
    ``γ_k = (s_k − 1)/s_{k+1}``, ``Y = Xᵏ ⊕ γ_k(Xᵏ ⊖ Xᵏ⁻¹)`` (translations linearly, headings by the
    wrapped difference; each robot extrapolates its own and its neighbours' poses, which it holds
    from the last two exchanges), candidate = node update from ``Y`` without the safeguard. With
    ``F_k = F(Xᵏ)`` and ``G = Σ_α G^α(candidate | Xᵏ) ≥ F(candidate)``: ``F̄₀ ← (1−η₀)F̄₀ + η₀F_k``
    (η₀ = 5e-4), ``F̄₁ ← max(F_k, (1−η₁)F̄₁ + η₁F_k)`` (η₁ = 2.5e-2); a **hard restart** when
    ``G > F̄₀``, a **soft restart** when ``G > F̄₁`` and counter₀ ≥ 10, or ``G > F_{k}`` and
    counter₁ > 25 (counter₀ −2 when ``F_k ≤ F̄₁`` else +1; counter₁ reset when ``F`` decreased else
    +1). A restart replaces every robot's candidate by its safeguarded plain step from ``Xᵏ``; a
    hard one also sets ``s ← max(s/2, 1)``; both divide counter₀ by 3 and reset counter₁. The rules
    are applied to team sums (two scalars all-reduced per iteration, as AMM-PGO* with its master
    node), not per robot as in AMM-PGO# (the per-robot rule oscillated: docs/mm_pgo.md).

    *Deviation (odometry starts):* after each update ``F̄₀ ← min(F̄₀, F̄₁)``. AMM-PGO initialises
    ``F̄₀`` at the first ``F``; with η₀ = 5e-4 it then stays near that ``F`` for thousands of
    iterations, so from a start orders of magnitude above the optimum (odometry) the hard restart
    never fired. Capped by the fast average, ``F̄₀`` follows the actual ``F`` down. Measurements and
    the alternatives not kept: docs/mm_pgo.md.
    """

    s: float = 1.0
    average_slow: float = np.inf  # F̄₀
    average_fast: float = np.inf  # F̄₁
    hits_average: int = 0  # counter₀
    hits_increase: int = 0  # counter₁
    previous_objective: float = np.inf  # F(Xᵏ⁻¹)

    def observe(self, value: float) -> None:
        """Update counters and running averages with ``F_k = F(Xᵏ)``."""
        if not np.isfinite(self.average_slow):
            self.average_slow = self.average_fast = value
        if value <= self.average_fast:
            self.hits_average = max(self.hits_average - 2, 0)
        else:
            self.hits_average += 1
        self.hits_increase = 0 if value <= self.previous_objective else self.hits_increase + 1
        self.previous_objective = value
        self.average_slow = (1.0 - ETA_SLOW) * self.average_slow + ETA_SLOW * value
        self.average_fast = max(value, (1.0 - ETA_FAST) * self.average_fast + ETA_FAST * value)
        # F̄₀ capped by F̄₁: from a start far above the optimum (odometry) the slow average
        # would stay near F₀ for thousands of iterations and never trigger a hard restart.
        self.average_slow = min(self.average_slow, self.average_fast)

    def restart(self, surrogate: float) -> str | None:
        """``"hard"``, ``"soft"`` or None for candidates whose summed surrogate value is
        ``surrogate`` (call after :meth:`observe`)."""
        if surrogate > self.average_slow:
            return "hard"
        if (surrogate > self.average_fast and self.hits_average >= MAX_SOFT_HITS_AVERAGE) or (
            surrogate > self.previous_objective and self.hits_increase > MAX_SOFT_HITS_INCREASE
        ):
            return "soft"
        return None
