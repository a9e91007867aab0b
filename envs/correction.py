"""The correction a step applies (paper eq. C), as functions of the declared state: which
vertices it moves, the move itself, and the refresh of the edges whose residuals it changes.

``G = B·n`` agents; edge slots ``edge (G, 1)`` index an agent's ``E + 1`` slots (``E``: the no-op,
whose tail and head are the trash vertex ``V``). In the ``"pose"`` correction only the edge's
head moves; in the ``"subtree"`` correction the edge's mover (:attr:`envs.tree.SpanningTree.mover`)
moves rigidly with its subtree, a contiguous range of pre-order positions (:mod:`envs.core`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from envs.geometry import _gather_rows, _offset, _scatter_rows, between, compose, inverse, residuals
from popbench.objective import edge_costs

#: the step scales the ``line-search`` and ``nonmonotone`` step rules try, in decreasing order
#: (:func:`candidate_changes`; 0: no move)
LINE_SEARCH_SCALES = (1.0, 0.5, 0.25, 0.125, 0.0625, 0.03125, 0.0)

if TYPE_CHECKING:
    from envs.basestep import Boundary
    from envs.state import CoreState


def subtree_members(t: CoreState, correction: str, edge: torch.Tensor) -> torch.Tensor:
    """``(G, V+1)`` bool: the vertices a ``correction`` (``"pose"`` or ``"subtree"``) of the edge
    slots ``edge (G, 1)`` moves (the mover's subtree, a contiguous range of pre-order positions;
    the head alone in the pose mode; only the trash vertex for the no-op)."""
    g = edge.shape[0]
    if correction == "pose":
        head = torch.gather(t.heads.view(g, -1), 1, edge)
        return torch.arange(t.tree_position.shape[-1], device=edge.device) == head
    mover = torch.gather(t.mover.view(g, -1), 1, edge)
    position = t.tree_position.view(g, -1)
    start = torch.gather(position, 1, mover)
    stop = torch.gather(t.tree_end.view(g, -1), 1, mover)
    return (position >= start) & (position < stop)


def rigid_motion(
    t: CoreState, correction: str, poses: torch.Tensor, edge: torch.Tensor, delta: torch.Tensor
) -> torch.Tensor:
    """``(G, K, 3)``: the world-frame rigid motion of the moved vertices that changes the
    relative pose of each edge slot ``edge (G, 1)`` by each of the ``K`` corrections ``delta
    (G, K, 3)`` (metric), at ``poses (G, V+1, 3)``."""
    g = edge.shape[0]
    tail = torch.gather(t.tails.view(g, -1), 1, edge)
    head = torch.gather(t.heads.view(g, -1), 1, edge)
    mover = head if correction == "pose" else torch.gather(t.mover.view(g, -1), 1, edge)
    x_p, x_q = _gather_rows(poses, tail), _gather_rows(poses, head)
    relative = between(x_p, x_q) + delta
    moves_head = (mover == head).unsqueeze(-1)
    old = torch.where(moves_head, x_q, x_p)
    new = torch.where(moves_head, compose(x_p, relative), compose(x_q, inverse(relative)))
    return compose(new, inverse(old))


def move_subtree(
    t: CoreState,
    correction: str,
    poses: torch.Tensor,
    edge: torch.Tensor,
    delta: torch.Tensor,
    inside: torch.Tensor,
) -> None:
    """Move the vertices ``inside`` (:func:`subtree_members`) of ``poses (G, V+1, 3)`` rigidly,
    in place, so that the relative pose of each edge slot ``edge (G, 1)`` changes by ``delta
    (G, 1, 3)``; only the moved rows are computed and written."""
    transform = rigid_motion(t, correction, poses, edge, delta)
    rows = inside.flatten().nonzero().squeeze(-1)
    flat = poses.view(-1, 3)
    flat[rows] = compose(transform[rows // poses.shape[1], 0], flat[rows])


def candidate_changes(
    t: CoreState,
    correction: str,
    poses: torch.Tensor,
    edge: torch.Tensor,
    candidates: torch.Tensor,
    crossing: Boundary,
) -> torch.Tensor:
    """``(G, K)``: the change of each agent's local F (paper eq. 1, the measurements as targets)
    if it executed each of its ``K`` candidate metric corrections ``candidates (G, K, 3)`` on the
    edge slots ``edge (G, 1)`` (e.g. one correction scaled by :data:`LINE_SEARCH_SCALES`).

    A rigid move changes only the residuals of the edges that cross the moved set's boundary
    (``crossing``), so the change is exact over them."""
    motion = rigid_motion(t, correction, poses, edge, candidates)
    flat = poses.reshape(-1, 3)
    x_tail, x_head = flat[crossing.tail_rows], flat[crossing.head_rows]
    moved = motion[crossing.agent]  # (C, K, 3), one crossing edge per row
    inside_head = crossing.head_inside.view(-1, 1, 1)
    new_tail = torch.where(inside_head, x_tail.unsqueeze(1), compose(moved, x_tail.unsqueeze(1)))
    new_head = torch.where(inside_head, compose(moved, x_head.unsqueeze(1)), x_head.unsqueeze(1))
    measurement = t.measurements.view(-1, 3)[crossing.slots]
    kappa, tau = t.kappa.view(-1)[crossing.slots], t.tau.view(-1)[crossing.slots]
    before = edge_costs(_offset(between(x_tail, x_head), measurement), kappa, tau)
    after = edge_costs(
        _offset(between(new_tail, new_head), measurement.unsqueeze(1)),
        kappa.unsqueeze(1),
        tau.unsqueeze(1),
    )
    change = torch.zeros(candidates.shape[:2], dtype=candidates.dtype, device=candidates.device)
    change.index_add_(0, crossing.agent, after - before.unsqueeze(1))
    return change


def monotone_choice(change: torch.Tensor) -> torch.Tensor:
    """``(G,)`` int64: the index of the scale that lowers each agent's local F the most, of
    the changes ``change (G, K)`` (:func:`candidate_changes`); α = 0 is a candidate, so the chosen
    step never raises F (the ``line-search`` step rule)."""
    return change.argmin(-1)


def nonmonotone_choice(change: torch.Tensor, recent: torch.Tensor) -> torch.Tensor:
    """``(G,)`` int64: the index of the largest scale whose local F stays at or below the
    largest of the agent's last :data:`envs.modes.NONMONOTONE_WINDOW` values ``recent (G, M)``
    (the current one last), of the changes ``change (G, K)`` (the ``nonmonotone`` step rule).

    The reference of Grippo, Lampariello & Lucidi (1986), without their sufficient-decrease term
    (the scales are a fixed grid): a step may raise F for a while, but the window's largest value
    never rises, so no agent ends an episode above its start. α = 0 (the last) is always
    acceptable."""
    reference = recent.max(-1, keepdim=True).values
    acceptable = recent[:, -1:] + change <= reference
    acceptable[:, -1] = True  # α = 0, whatever the round-off of its zero change
    return acceptable.to(torch.int8).argmax(-1)  # the first: scales are in decreasing order


def refresh_boundary(t: CoreState, crossing: Boundary, reward: str) -> torch.Tensor:
    """Recompute, in place, the residuals and target costs of the edges that cross the moved
    subtree's boundary (only those, :func:`envs.basestep.boundary`); return the change of ``L``
    per agent, ``(G,)``. ``reward``: ``"F"`` (the targets are the measurements) or
    ``"localisation"``."""
    slots = crossing.slots
    flat_poses = t.poses.view(-1, 3)
    relative = between(flat_poses[crossing.tail_rows], flat_poses[crossing.head_rows])
    r = _offset(relative, t.measurements.view(-1, 3)[slots])
    if reward == "F":  # the targets are the measurements
        target_r = r
    else:
        target_r = _offset(relative, t.targets.view(-1, 3)[slots])
    cost = edge_costs(target_r, t.kappa.view(-1)[slots], t.tau.view(-1)[slots])
    costs = t.costs.view(-1)
    change = torch.zeros(crossing.crossing.shape[0], dtype=cost.dtype, device=cost.device)
    change.index_add_(0, crossing.agent, cost - costs[slots])
    t.residuals.view(-1, 3)[slots] = r
    costs[slots] = cost
    return change


def refresh_edges(t: CoreState, incident: torch.Tensor) -> torch.Tensor:
    """Recompute, in place, the residuals and target costs of the edge slots ``incident (G, D)``
    (padding: the trash slot ``E``); return the change of ``L`` per agent, ``(G,)``."""
    g = incident.shape[0]
    poses = t.poses.view(g, -1, 3)
    tails = torch.gather(t.tails.view(g, -1), 1, incident)
    heads = torch.gather(t.heads.view(g, -1), 1, incident)
    x_p, x_q = _gather_rows(poses, tails), _gather_rows(poses, heads)
    r = residuals(x_p, x_q, _gather_rows(t.measurements.view(g, -1, 3), incident))
    cost = edge_costs(
        residuals(x_p, x_q, _gather_rows(t.targets.view(g, -1, 3), incident)),
        torch.gather(t.kappa.view(g, -1), 1, incident),
        torch.gather(t.tau.view(g, -1), 1, incident),
    )
    costs = t.costs.view(g, -1)
    real = incident < t.edge_mask.shape[-1]  # padding slots point at the trash slot E
    old = torch.gather(costs, 1, incident)
    change = torch.where(real, cost - old, torch.zeros_like(cost)).sum(-1)
    _scatter_rows(t.residuals.view(g, -1, 3), incident, r)
    costs.scatter_(1, incident, cost)
    return change
