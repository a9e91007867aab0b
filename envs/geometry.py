"""Batched torch SE(2) operations and node features of the PGO environment.

The torch twins of :mod:`popbench.se2` and :func:`popbench.objective.residuals` on poses
``(..., 3) = [x, y [m], θ [rad]]``, plus the row gather/scatter of the batched state
(:class:`envs.core.PGOCore`).
"""

from __future__ import annotations

import torch


def wrap(angle: torch.Tensor) -> torch.Tensor:
    """Wrap angles (rad) to ``[-π, π)`` (as :func:`popbench.se2.wrap`)."""
    # θ − 2π⌊(θ + π)/2π⌋ equals remainder(θ + π, 2π) − π and is ~2× faster on CPU
    return angle - (2.0 * torch.pi) * torch.floor((angle + torch.pi) / (2.0 * torch.pi))


def between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a⁻¹ ∘ b`` for poses ``(..., 3)``: pose ``b`` in the frame of ``a``."""
    c, s = torch.cos(a[..., 2]), torch.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return torch.stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[..., 2] - a[..., 2])], -1)


def compose(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a ∘ b`` for poses ``(..., 3)``: pose ``b`` (in frame ``a``) in the world frame."""
    c, s = torch.cos(a[..., 2]), torch.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return torch.stack([x, y, wrap(a[..., 2] + b[..., 2])], -1)


def inverse(a: torch.Tensor) -> torch.Tensor:
    """``a⁻¹`` for poses ``(..., 3)``."""
    c, s = torch.cos(a[..., 2]), torch.sin(a[..., 2])
    x = -(c * a[..., 0] + s * a[..., 1])
    y = s * a[..., 0] - c * a[..., 1]
    return torch.stack([x, y, wrap(-a[..., 2])], -1)


def residuals(
    tail_poses: torch.Tensor, head_poses: torch.Tensor, measurements: torch.Tensor
) -> torch.Tensor:
    """``[r_t, r_θ]`` (``(..., 3)``) as :func:`popbench.objective.residuals`:
    ``r_t = R_pᵀ(t_q − t_p) − t̃`` [m], ``r_θ = wrap(θ_q − θ_p − θ̃)`` [rad]."""
    return _offset(between(tail_poses, head_poses), measurements)


def _offset(relative: torch.Tensor, measurements: torch.Tensor) -> torch.Tensor:
    """``[t − t̃, wrap(θ − θ̃)]`` of relative poses ``(..., 3)`` (the tail of :func:`residuals`)."""
    return torch.cat(
        [
            relative[..., :2] - measurements[..., :2],
            wrap(relative[..., 2:] - measurements[..., 2:]),
        ],
        -1,
    )


def node_features(
    frame: torch.Tensor,
    poses: torch.Tensor,
    log_degree: torch.Tensor,
    owned: torch.Tensor,
    node_mask: torch.Tensor,
) -> torch.Tensor:
    """``(..., 6)`` float32 node features ``[x, y [m], sin θ, cos θ, log(1 + degree), owned]``,
    zero on padding: ``poses (..., 3)`` in the frame of ``frame`` (broadcast against ``poses``;
    the agent's first owned pose, or each vertex's tree parent for the invariant observation);
    ``log_degree``, ``owned``, ``node_mask`` of shape ``(...)``."""
    relative = between(frame, poses)
    features = torch.stack(
        [
            relative[..., 0],
            relative[..., 1],
            torch.sin(relative[..., 2]),
            torch.cos(relative[..., 2]),
            log_degree,
            owned.to(poses.dtype),
        ],
        -1,
    )
    return (features * node_mask.unsqueeze(-1)).to(torch.float32)


def _gather_rows(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``out[g, k] = values[g, index[g, k]]``; ``values (G, S, ...)``, ``index (G, K)``."""
    tail = values.shape[2:]
    expanded = index.reshape(index.shape + (1,) * len(tail)).expand(index.shape + tail)
    return torch.gather(values, 1, expanded)


def _scatter_rows(values: torch.Tensor, index: torch.Tensor, rows: torch.Tensor) -> None:
    """In place ``values[g, index[g, k]] = rows[g, k]`` (inverse of :func:`_gather_rows`)."""
    tail = values.shape[2:]
    expanded = index.reshape(index.shape + (1,) * len(tail)).expand(index.shape + tail)
    values.scatter_(1, expanded, rows)


def matrix_parts(matrices: torch.Tensor) -> torch.Tensor:
    """``(3, 3, ...)`` contiguous components of ``(..., 3, 3)`` matrices (fast elementwise use)."""
    return matrices.permute(
        matrices.dim() - 2, matrices.dim() - 1, *range(matrices.dim() - 2)
    ).contiguous()
