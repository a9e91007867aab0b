"""The expert of the PGO environment: each agent's local-graph optimum, walked.

Target: for each agent, the optimum of its own local graph found by the project's LM
(:func:`popbench.solvers.lm.solve_graph`, local vertex 0 — the tree root, the agent's first owned
pose — fixed), started from the episode's initial local copies (with the separators placed when
the core places them) and computed once per problem; edges flagged in
``problem.outlier_mask`` (injected outliers) are left out of that solve.

Policy (:meth:`Expert.act`): each agent processes its spanning-tree edges root-outwards (by the
pre-order position of the vertex a correction moves), then the remaining edges with ``Δ = 0``.

* ``correction="subtree"``: ``Δ = between(x*_p, x*_q) − between(x_p, x_q)`` (angle wrapped), the
  change that gives the edge the optimum's relative pose; every other tree edge keeps its own, so
  after one pass every tree edge whose Δ was not clipped is at the optimum, and with no clipping
  the local copy *is* the optimum.
* ``correction="pose"``: only the head moves, so ``Δ = between(x_p, x*_q) − between(x_p, x_q)``
  on every edge: the head is sent towards its optimum pose (same gauge: the root is fixed in both),
  as far as Δmax allows. This gives the pose mode's one-episode bound.

:meth:`Expert.edge` and :meth:`Expert.delta` label any state (DAgger): the expert's edge among
the unprocessed ones, and its Δ on any edge (0 on a non-tree edge in the subtree mode), both in
the core's action units (whitened when ``action_scale="whitened"``); :meth:`Expert.right_edges`
(every edge the expert counts as right) and :meth:`Expert.actor_delta` (the actor output that
makes the core execute the expert's Δ, the Gauss–Newton base step taken off) are the labels of
behaviour cloning (agents.imitation, agents.loss). The expert reads the optimum (privileged); a
learned actor must never get it as an input.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from envs.core import PGOCore
from envs.geometry import _gather_rows, between, wrap
from envs.tree import place_separators
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.local_lm import local_optima as solve_local_graphs

LM_ITERATIONS = 200


def local_optima(
    problem: DistributedProblem,
    local_poses: Sequence[np.ndarray] | None = None,
    iterations: int = LM_ITERATIONS,
) -> list[np.ndarray]:
    """Each agent's local-graph optimum ``[(n_r, 3)]`` (LM from ``local_poses``, default the
    initial copies; local vertex 0 fixed; injected outliers left out): the expert's target,
    :func:`popbench.solvers.local_lm.local_optima` from the episode's own start."""
    starts = None if local_poses is None else list(local_poses)
    return solve_local_graphs(problem, iterations, problem.outlier_mask, starts)[0]


class Expert:
    """The expert policy over a :class:`PGOCore` (module docstring); optima are cached per
    problem object."""

    def __init__(self, core: PGOCore, iterations: int = LM_ITERATIONS) -> None:
        self.core, self.iterations = core, iterations
        self._optima: dict[int, tuple[DistributedProblem, np.ndarray]] = {}

    def optimum(self) -> torch.Tensor:
        """``(B, n, V+1, 3)`` the current problems' local optima, padded like the core's poses."""
        core = self.core
        v = core.dims.vertices
        current = {id(problem) for problem in core.problems}
        for key in [key for key in self._optima if key not in current]:
            del self._optima[key]  # keep the cache to the loaded problems
        stacked = []
        for problem in core.problems:
            assert problem is not None, "load the core first"
            key = id(problem)
            if key not in self._optima or self._optima[key][0] is not problem:
                start = place_separators(problem) if core.place else problem.split()
                padded = np.zeros((problem.num_robots, v + 1, 3))
                for agent, poses in enumerate(local_optima(problem, start, self.iterations)):
                    padded[agent, : poses.shape[0]] = poses
                self._optima[key] = (problem, padded)
            stacked.append(self._optima[key][1])
        return torch.as_tensor(np.stack(stacked), dtype=core.dtype, device=core.device)

    def edge(self) -> torch.Tensor:
        """``(B, n)`` int64: the unprocessed tree edge whose moved vertex comes first in pre-order,
        else the lowest unprocessed edge, else the no-op ``E``."""
        t = self.core.state
        e, v = self.core.dims.edges, self.core.dims.vertices
        g = self.core.batch * self.core.num_agents
        mover = t.mover.view(g, -1)[:, :e]
        position = torch.gather(t.tree_position.view(g, -1), 1, mover)
        index = torch.arange(e, device=self.core.device).expand(g, e)
        score = torch.where(t.tree_edge.view(g, -1)[:, :e], position, v + 1 + index)
        open_ = self.core.action_mask().view(g, -1)[:, :e]
        score = torch.where(open_, score, torch.full_like(score, 2 * (v + e + 2)))
        best = score.argmin(-1)
        best = torch.where(open_.any(-1), best, torch.full_like(best, e))
        return best.view(self.core.batch, self.core.num_agents)

    def delta(self, edge: torch.Tensor) -> torch.Tensor:
        """``(B, n, 3)`` the expert's Δ on the edges ``edge (B, n)`` from the current state, in
        the core's action units (not clipped: the core clips)."""
        core, t = self.core, self.core.state
        g = core.batch * core.num_agents
        flat_edge = edge.to(core.device, torch.int64).reshape(g, 1)
        poses = t.poses.view(g, -1, 3)
        optimum = self.optimum().view(g, -1, 3)
        tail = torch.gather(t.tails.view(g, -1), 1, flat_edge)
        head = torch.gather(t.heads.view(g, -1), 1, flat_edge)
        x_p, x_q = _gather_rows(poses, tail), _gather_rows(poses, head)
        if core.modes.correction == "subtree":
            target = between(_gather_rows(optimum, tail), _gather_rows(optimum, head))
            on_tree = torch.gather(t.tree_edge.view(g, -1), 1, flat_edge).unsqueeze(-1)
        else:
            target = between(x_p, _gather_rows(optimum, head))
            on_tree = torch.ones_like(flat_edge, dtype=torch.bool).unsqueeze(-1)
        delta = target - between(x_p, x_q)
        delta = torch.cat([delta[..., :2], wrap(delta[..., 2:])], -1)
        delta = torch.where(on_tree, delta, torch.zeros_like(delta))
        if core.modes.action_scale == "whitened":
            root = _gather_rows(t.sqrt_information.view(g, -1, 3, 3), flat_edge)
            delta = (root @ delta.unsqueeze(-1)).squeeze(-1)
        return delta.view(core.batch, core.num_agents, 3)

    def act(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The expert's joint action ``(edge (B, n), delta (B, n, 3))``."""
        edge = self.edge()
        return edge, self.delta(edge)

    def right_edges(self) -> torch.Tensor:
        """``(B, n, E + 1)`` bool: the choices the expert counts as right — the unprocessed
        tree edges where any is left (subtree mode: a correction there changes only that edge's
        relative pose, so the order does not change the end point), else every allowed one."""
        core = self.core
        mask = core.action_mask()
        if core.modes.correction != "subtree":
            return mask
        tree = core.state.tree_edge[..., : mask.shape[-1] - 1] & mask[..., :-1]
        tree = torch.cat([tree, torch.zeros_like(tree[..., :1])], -1)
        return torch.where(tree.any(-1, keepdim=True), tree, mask)

    def actor_delta(self, edge: torch.Tensor) -> torch.Tensor:
        """``(B, n, 3)`` float32: the actor output that makes the core execute the expert's Δ
        on ``edge (B, n)`` — the expert's Δ itself, or its difference from the Gauss–Newton
        base step when the core adds one (``base="gauss-newton"``); not clipped."""
        delta = self.delta(edge)
        if self.core.modes.base == "gauss-newton":
            delta = delta - self.core.base_step(edge)
        return delta.to(torch.float32)
