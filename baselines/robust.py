"""Robust kernels for MM-PGO as iteratively reweighted least squares (IRLS) weights.

An edge's *weighted squared residual* is its chordal cost (SE-Sync convention, no ½)

    s_e = κ_e ‖R_q − R_p R̃_e‖²_F + τ_e ‖t_q − t_p − R_p t̃_e‖²   (dimensionless),

and a kernel replaces ``s`` by ``ρ(s)`` (Fan & Murphey's MM-PGO, REFERENCES.md §3.2, with
scale ``c``; ``ρ(s) = s`` for small ``s``, ``ρ'(0) = 1``):

=========  ==========================================  ==========================
kernel     ρ(s)                                        IRLS weight w = ρ'(s)
=========  ==========================================  ==========================
none       s                                           1
huber      s if s ≤ c, else 2√(cs) − c                 √c / √max(s, c)
gm         c s / (s + c)        (Geman–McClure)        c² / (s + c)²
welsch     c (1 − exp(−s/c))                           exp(−s/c)
=========  ==========================================  ==========================

Every ρ is concave in ``s``, so ``ρ(s) ≤ ρ(s_k) + w(s_k)(s − s_k)``: minimising the
``w``-weighted chordal cost decreases the robust cost (the IRLS majorisation) and ``0 < w ≤ 1``.

**Scale.** MM-PGO's example uses ``c = 0.25`` in its internal units (``f = ½F``); here ``s`` is
in units of the whitened residual. For an inlier whose noise matches its information, the
translation term ``τ‖r_t‖²`` is ≈ χ²₂ (exactly for isotropic ``Λ_tt``) and the rotation term
``4κ(1 − cos r_θ) ≈ 2κ r_θ²`` ≈ 2χ²₁, so ``s`` has mean ≈ 4 and the 3-degree-of-freedom χ²
quantile is the natural yardstick. :data:`DEFAULT_SCALE` = χ²₃ 0.99-quantile = 11.345: edges
below it keep weight ≥ 1/4 (GM) / e⁻¹ (Welsch) / 1 (Huber).

**Flagging outliers.** An edge is an inlier when its final weight is at least the weight at
``s = c`` (:func:`flag_threshold`), i.e. when its final ``s ≤ c`` (every weight is
non-increasing in ``s``; Huber's is 1 up to ``c``); the kernel ``none`` flags nothing.
"""

from __future__ import annotations

import numpy as np

from popbench.errors import ValueRangeError

KERNELS = ("none", "huber", "gm", "welsch")

# χ²₃ quantile at 0.99 (scipy.stats.chi2.ppf(0.99, 3)), see the module docstring.
DEFAULT_SCALE = 11.344866730144373


def check_kernel(kernel: str) -> str:
    """``kernel`` if it is one of :data:`KERNELS`, else a :class:`ValueRangeError`."""
    if kernel not in KERNELS:
        raise ValueRangeError("robust kernel", kernel, ", ".join(KERNELS))
    return kernel


def weights(kernel: str, s: np.ndarray, scale: float) -> np.ndarray:
    """IRLS weights ``w = ρ'(s)`` in ``(0, 1]``, same shape as ``s``.

    Args:
        kernel: one of :data:`KERNELS`.
        s: weighted squared residuals (≥ 0).
        scale: the kernel scale ``c`` > 0, in the units of ``s``.
    """
    s = np.asarray(s, dtype=np.float64)
    if kernel == "none":
        return np.ones_like(s)
    if kernel == "huber":
        return np.sqrt(scale / np.maximum(s, scale))
    if kernel == "gm":
        return scale**2 / (s + scale) ** 2
    if kernel == "welsch":
        return np.exp(-s / scale)
    raise ValueRangeError("robust kernel", kernel, ", ".join(KERNELS))


def loss(kernel: str, s: np.ndarray, scale: float) -> np.ndarray:
    """The robust cost ``ρ(s)`` of each residual, same shape as ``s``."""
    s = np.asarray(s, dtype=np.float64)
    if kernel == "none":
        return s
    if kernel == "huber":
        return np.where(s <= scale, s, 2.0 * np.sqrt(scale * s) - scale)
    if kernel == "gm":
        return scale * s / (s + scale)
    if kernel == "welsch":
        return scale * (1.0 - np.exp(-s / scale))
    raise ValueRangeError("robust kernel", kernel, ", ".join(KERNELS))


def flag_threshold(kernel: str, scale: float) -> float:
    """The weight at ``s = c``: an edge whose final weight is below it is an outlier
    (0 for the kernel ``none``, which flags nothing)."""
    if check_kernel(kernel) == "none":
        return 0.0
    return float(weights(kernel, np.array(scale), scale))
