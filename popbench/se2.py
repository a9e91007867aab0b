"""Vectorised SE(2) maths over arrays of poses.

A pose is ``(x, y, theta)``: translation in metres, heading in radians. Every function takes
arrays of shape ``(..., 3)`` (poses) or ``(...)`` (angles) and broadcasts over leading axes.
Angles returned are wrapped to ``[-pi, pi)``.
"""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap(angle: np.ndarray) -> np.ndarray:
    """Wrap angles (rad) to ``[-pi, pi)``."""
    return np.mod(np.asarray(angle) + np.pi, TWO_PI) - np.pi


def rotation(theta: np.ndarray) -> np.ndarray:
    """Rotation matrices ``R(theta)``, shape ``(..., 2, 2)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotate(theta: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """``R(theta) @ vector`` for vectors of shape ``(..., 2)``."""
    c, s = np.cos(theta), np.sin(theta)
    x, y = vector[..., 0], vector[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], -1)


def unrotate(theta: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """``R(theta)^T @ vector`` for vectors of shape ``(..., 2)``."""
    return rotate(-np.asarray(theta), vector)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a ∘ b``: pose ``b`` (expressed in frame ``a``) mapped into the world frame."""
    t = a[..., :2] + rotate(a[..., 2], b[..., :2])
    return np.concatenate([t, wrap(a[..., 2] + b[..., 2])[..., None]], -1)


def inverse(a: np.ndarray) -> np.ndarray:
    """``a⁻¹``."""
    t = -unrotate(a[..., 2], a[..., :2])
    return np.concatenate([t, wrap(-a[..., 2])[..., None]], -1)


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative pose ``a⁻¹ ∘ b``: pose ``b`` in the frame of ``a`` (the g2o measurement model)."""
    t = unrotate(a[..., 2], b[..., :2] - a[..., :2])
    return np.concatenate([t, wrap(b[..., 2] - a[..., 2])[..., None]], -1)


def _v_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sin θ / θ, (1 − cos θ) / θ)`` with their Taylor series near zero; ``1 − cos θ`` is
    computed as ``2 sin²(θ/2)``, which does not cancel for small θ."""
    small = np.abs(theta) < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, theta / 2.0 - theta**3 / 24.0, 2.0 * np.sin(safe / 2.0) ** 2 / safe)
    return a, b


def exp(xi: np.ndarray) -> np.ndarray:
    """Exponential map: twist ``(ρx, ρy, θ)`` in the Lie algebra → pose. ``t = V(θ) ρ``."""
    theta = xi[..., 2]
    a, b = _v_coefficients(theta)
    rx, ry = xi[..., 0], xi[..., 1]
    t = np.stack([a * rx - b * ry, b * rx + a * ry], -1)
    return np.concatenate([t, wrap(theta)[..., None]], -1)


def log(pose: np.ndarray) -> np.ndarray:
    """Logarithm map: pose → twist ``(ρx, ρy, θ)`` with ``ρ = V(θ)⁻¹ t`` (θ in ``[-π, π)``)."""
    theta = wrap(pose[..., 2])
    a, b = _v_coefficients(theta)
    det = a * a + b * b
    x, y = pose[..., 0], pose[..., 1]
    rho = np.stack([(a * x + b * y) / det, (-b * x + a * y) / det], -1)
    return np.concatenate([rho, theta[..., None]], -1)
