"""GaussNewtonSweep: the simple non-learned policy of the subtree mode.

One root-outward pass over each agent's spanning-tree edges (the order of
:class:`envs.expert.Expert`, then the remaining edges with ``Δ = 0``). The Δ of a tree edge is
one Gauss–Newton step on the 3-vector Δ itself (:mod:`envs.basestep`): the moved subtree is
rigid, so only the edges that cross its boundary change. In the pose mode the same sweep moves
the head alone (the "subtree" is one vertex) and takes a Gauss–Newton Δ on every edge: one
block-coordinate pass, the pose mode's non-learned reference. The core then clips Δ to Δmax.
Needs the problem's measurements only (no ground truth, no optimum).
"""

from __future__ import annotations

import torch

from envs.core import PGOCore
from envs.expert import Expert


class GaussNewtonSweep:
    """The one-pass Gauss–Newton policy over a :class:`PGOCore` (subtree or pose mode)."""

    def __init__(self, core: PGOCore) -> None:
        self.core = core
        self.order = Expert(core)  # only its edge order is used (no optimum is computed)

    def act(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's joint action ``(edge (B, n), delta (B, n, 3))``."""
        edge = self.order.edge()
        return edge, self.core.base_step(edge)
