"""Robust kernels for MM-PGO as iteratively reweighted least squares (IRLS) weights.

An edge's *weighted squared residual* is its chordal cost (SE-Sync convention, no ½)

    s_e = κ_e ‖R_q − R_p R̃_e‖²_F + τ_e ‖t_q − t_p − R_p t̃_e‖²   (dimensionless),

and a kernel replaces ``s`` by ``ρ(s)`` (Fan & Murphey's MM-PGO, with
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

**Scale.** For an inlier whose noise matches its information, the translation term ``τ‖r_t‖²``
is ≈ χ²₂ (exactly for isotropic ``Λ_tt``) and the rotation term ``4κ(1 − cos r_θ) ≈ 2κ r_θ²`` ≈
2χ²₁, so ``s`` has mean ≈ 4. :data:`DEFAULT_SCALE` (the project's scale) = χ²₃ 0.99-quantile =
11.345: edges below it keep weight ≥ 1/4 (GM) / e⁻¹ (Welsch) / 1 (Huber). MM-PGO's own code
(MurpheyLab/DPGO ``examples/dist_pgo.cpp``, ``loss_reg``) uses :data:`AUTHORS_SCALE` = 0.25 on the
same ``s`` (its ``evaluate_E`` squares the √κ/√τ-scaled residual rows; only its cost carries a
½), far below a consistent edge's ``s``: nearly every edge under the kernel is down-weighted.

**Flagging outliers** (:func:`flagged`). A kernel's weights are non-increasing in ``s`` (strictly
beyond ``c``), so any weight threshold is a threshold on ``s``. The kernel's own scale cannot be
it: at MM-PGO's ``c = 0.25`` every consistent edge (``s`` ≈ 4) is beyond ``c``. The threshold is
instead where an inlier's ``s`` has a 1 % chance to lie beyond: for the small-error ``s ≈ τ‖r_t‖²
+ 2κ r_θ²`` that is the 0.99 quantile of ``χ²₂ + 2χ²₁``, :data:`INLIER_BOUND` = 16.304 (the
χ²₃(0.99) = 11.345 of eq. 1's ``κ r_θ² + τ‖r_t‖²``, which counts the rotation once; 4.2 % of
inliers have ``s`` above 11.345). An edge under the kernel is flagged when its final weight is
below ``w(INLIER_BOUND)``, i.e. when its final ``s > INLIER_BOUND``, whatever the kernel and its
scale; the kernel ``none`` flags nothing.
"""

from __future__ import annotations

import numpy as np

from popbench.choices import ROBUST_KERNELS
from popbench.errors import ValueRangeError
from popbench.objective import CHI2_3_99

KERNELS = ("none", *ROBUST_KERNELS)

DEFAULT_SCALE = CHI2_3_99  # χ²₃(0.99), see the module docstring
AUTHORS_SCALE = 0.25  # MM-PGO's loss_reg in examples/dist_pgo.cpp (its default is 1.0)
# 0.99 quantile of χ²₂ + 2χ²₁ (P(X₂ + 2X₁ > t) = 0.01 by quadrature), see the module docstring.
INLIER_BOUND = 16.30391385410364


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


def flagged(kernel: str, s: np.ndarray, bound: float = INLIER_BOUND) -> np.ndarray:
    """Outlier flags ``(M,)`` bool of edges under ``kernel`` with final weighted squared
    residuals ``s`` ``(M,)``: ``s > bound`` (the weight below ``w(bound)``; module docstring);
    none for the kernel ``none``."""
    s = np.asarray(s, dtype=np.float64)
    if check_kernel(kernel) == "none":
        return np.zeros(s.shape, dtype=bool)
    return s > bound
