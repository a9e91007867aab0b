"""What the actor sees of the batched PGO state (paper §III-C): the per-agent observation of a
:class:`envs.state.CoreState` and, for incremental readers, the entries one step changed in it.
Pure functions of the state and the core's observation modes (:class:`ReadoutModes`).

Node poses are observed in a frame vertex's frame (the agent's first owned pose, or each vertex's
tree parent in the invariant mode); residuals are metric, or ``Λ^½ r`` (in units of the edge's
own standard deviation) when the action scale is whitened. The entries, their widths and what
padding means: :mod:`envs.features` and docs/environment.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import torch

from envs.basestep import BaseModel, observed_model
from envs.geometry import _gather_rows, node_features

if TYPE_CHECKING:
    from envs.state import CoreState


class ReadoutModes(NamedTuple):
    """What the read-out needs of the core's modes: ``invariant`` (node poses relative to their
    tree parent, ``observation="invariant"``) and ``whitened`` (``action_scale="whitened"``)."""

    invariant: bool
    whitened: bool


def observe(
    t: CoreState, modes: ReadoutModes, base: BaseModel | None = None
) -> dict[str, torch.Tensor]:
    """Per-agent padded observation, every entry with leading shape ``(B, n)``.

    * ``node_features (V, 6)`` float32: pose in the frame vertex's frame (x, y [m], sin θ,
      cos θ), ``log(1 + degree)``, owned flag (0 = separator copy);
    * ``node_mask (V,)``; ``edge_index (2, E)`` int64 local (tail, head), 0 on padding;
    * ``edge_attr (E, 11)`` (:func:`envs.observation.edge_attributes`); ``edge_mask (E,)``;
    * ``processed (E,)``; ``residuals (E, 3)`` float32 current ``[r_t, r_θ]`` against the
      measurements (0 on padding), as :func:`observed_residuals` gives them;
    * with the Gauss–Newton base step (``base="gauss-newton"``) also ``base_step (E, 3)``, the
      step Δ_GN of every edge in action units, and ``base_model (E, 9)``, its quadratic model
      relative to the local F (:func:`envs.basestep.observed_model`), float32, from the
      model ``base`` of every edge slot (None: no base step).
    """
    v, e = t.node_mask.shape[-1], t.edge_mask.shape[-1]
    poses = t.poses[:, :, :v]
    if modes.invariant:
        parent = t.tree_parent[:, :, :v]
        frame = _gather_rows(poses.flatten(0, 1), parent.flatten(0, 1)).view(poses.shape)
    else:
        frame = poses[:, :, :1]
    node_mask = t.node_mask
    observation = {
        "node_features": node_features(frame, poses, t.log_degree, t.owned, node_mask),
        "node_mask": node_mask,
        "edge_index": t.edge_index,
        "edge_attr": t.edge_attr,
        "edge_mask": t.edge_mask,
        "processed": t.processed[..., :e].clone(),
        "residuals": observed_residuals(t, modes.whitened).to(torch.float32),
    }
    if base is not None:
        observation.update(base_observation(base, t.edge_mask.shape))
    return observation


def base_observation(model: BaseModel, shape: torch.Size) -> dict[str, torch.Tensor]:
    """``base_step (B, n, E, 3)`` and ``base_model (B, n, E, 9)`` of :func:`observe`, from the
    model of every edge slot; ``shape`` = ``(B, n, E)``."""
    b, n, e = shape
    return {
        "base_step": model.step[:, :e].reshape(b, n, e, 3).to(torch.float32),
        "base_model": observed_model(model)[:, :e].reshape(b, n, e, -1).to(torch.float32),
    }


def chosen_base_observation(model: BaseModel) -> tuple[torch.Tensor, torch.Tensor]:
    """``(base_step (B·n, 3), base_model (B·n, 9))`` float32 of one chosen edge per agent, as
    :func:`base_observation` gives them for every edge, from the chosen edges' model
    (:func:`envs.basestep.chosen_model`, fields ``(B·n, 1, ...)``)."""
    return model.step[:, 0].to(torch.float32), observed_model(model)[:, 0].to(torch.float32)


def observation_changes(
    t: CoreState, modes: ReadoutModes, moved: torch.Tensor, refreshed: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """What the core's last step may have changed in :func:`observe`, for an incremental reader
    (:class:`agents.inference.IncrementalPolicy`): every entry whose value can differ is
    included (some may be unchanged), every other entry is unchanged. ``moved (B·n, V+1)`` and
    ``refreshed (B·n, E+1)``: the vertices the step moved and the edge slots it recomputed.

    Returns:
        vertices ``(S,)`` flat ids ``(b·n + agent)·V + local`` (ascending): the vertices the
        step moved and those whose frame vertex it moved; their ``node_features`` ``(S, 6)``
        float32; edges ``(R,)`` flat ids ``(b·n + agent)·E + slot`` (ascending): the edges
        whose residual it recomputed; their observed ``residuals`` ``(R, 3)`` float32.
    """
    v, e = t.node_mask.shape[-1], t.edge_mask.shape[-1]
    g = moved.shape[0]
    moved = moved[:, :v]
    if modes.invariant:
        frame_index = t.tree_parent.view(g, -1)[:, :v]
    else:
        frame_index = torch.zeros_like(moved, dtype=torch.int64)
    candidate = (moved | torch.gather(moved, 1, frame_index)) & t.node_mask.view(g, v)
    vertices = torch.nonzero(candidate.flatten()).squeeze(-1)
    graph = vertices // v
    poses = t.poses.view(-1, 3)  # (G·(V+1), 3): each graph's rows and its trash vertex
    frames = frame_index.flatten()[vertices] + graph * (v + 1)
    features = node_features(
        poses[frames],
        poses[vertices + graph],
        t.log_degree.flatten()[vertices],
        t.owned.flatten()[vertices],
        t.node_mask.flatten()[vertices],
    )
    edges = torch.nonzero(refreshed[:, :e].flatten()).squeeze(-1)
    r = t.residuals[..., :e, :].reshape(g * e, 3)[edges]
    if modes.whitened:
        root = t.sqrt_information[..., :e, :, :].reshape(g * e, 3, 3)[edges]
        r = (root @ r.unsqueeze(-1)).squeeze(-1)
    return vertices, features, edges, r.to(torch.float32)


def observed_residuals(t: CoreState, whitened: bool) -> torch.Tensor:
    """``(B, n, E, 3)`` residuals as observed: metric, or ``Λ^½ r`` when ``whitened``."""
    e = t.edge_mask.shape[-1]
    r = t.residuals[..., :e, :]
    if whitened:
        r = (t.sqrt_information[..., :e, :, :] @ r.unsqueeze(-1)).squeeze(-1)
    return r
