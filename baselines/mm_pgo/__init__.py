"""MM-PGO / AMM-PGO (Fan & Murphey, T-RO 2024): distributed majorisation–minimisation on SE(2),
method ``"mm-pgo"``. One file per part of the method:

* :mod:`~baselines.mm_pgo.edges` — the per-edge residuals, costs, gradients and Gauss–Newton blocks;
* :mod:`~baselines.mm_pgo.team` — every robot's majorised subproblem in one block-diagonal system,
  and the node update;
* :mod:`~baselines.mm_pgo.restart` — AMM-PGO's acceleration and adaptive-restart state;
* :mod:`~baselines.mm_pgo.robust_weights` — the robust modes and IRLS weights;
* :mod:`~baselines.mm_pgo.driver` — the iteration, its accounting and the method's ``solve``.

Design notes, measurements and the variants tried and not kept: docs/mm_pgo.md.
"""

from baselines.mm_pgo.driver import solve
from baselines.mm_pgo.robust_weights import ROBUST_MODES

__all__ = ["ROBUST_MODES", "solve"]
