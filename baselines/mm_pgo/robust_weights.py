"""MM-PGO's robust reweighting: which edges a kernel acts on (the robust modes) and the IRLS
weights ``ρ'(F_e)`` of those edges at an iterate (kernels: :mod:`baselines.robust`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baselines import robust
from baselines.mm_pgo.edges import edge_costs, edge_data, edge_terms
from popbench import objective
from popbench.graph import EdgeKind, PoseGraph


@dataclasses.dataclass(frozen=True)
class RobustMode:
    """Where a robust kernel acts and its default scale (:mod:`baselines.robust`).

    Attributes:
        kinds: the edge kinds under the kernel (the others keep weight 1, are never flagged).
        scale: the kernel scale ``c`` used when ``kernel_scale`` is not given.
    """

    kinds: tuple[EdgeKind, ...]
    scale: float


ROBUST_MODES: dict[str, RobustMode] = {
    # MM-PGO's own code: the kernel on the inter-node edges only (DPGOProblem::evaluate_E over
    # the inter-node incidence mB_[1]: cut odometry and inter-robot loop closures), c = 0.25.
    "authors": RobustMode((EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP), robust.AUTHORS_SCALE),
    # The project's earlier reading: intra-robot loop closures too, c = χ²₃(0.99).
    "project": RobustMode(
        (EdgeKind.LOOP, EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP), robust.DEFAULT_SCALE
    ),
}


def robust_costs(graph: PoseGraph, poses: np.ndarray, kinds: tuple[EdgeKind, ...]) -> np.ndarray:
    """``s_e = F_e`` ``(M,)`` at ``poses`` on the edges of ``kinds``, 0 elsewhere."""
    kappa, tau = objective.weights(graph.information)
    terms = edge_terms(poses, edge_data(graph.tails, graph.heads, graph.measurements))
    under = np.isin(graph.kinds, np.array(kinds, dtype=np.int8))
    return np.where(under, edge_costs(terms, kappa, tau), 0.0)


def edge_weights(
    graph: PoseGraph, poses: np.ndarray, kernel: str, scale: float, kinds: tuple[EdgeKind, ...]
) -> np.ndarray:
    """IRLS weights ``(M,)`` at ``poses``: ``ρ'(F_e)`` on the edges of ``kinds``, 1 elsewhere.

    **Robust kernels** (:mod:`baselines.robust`) on the edge kinds of the robust mode
    (:data:`ROBUST_MODES`: ``"authors"``, as MM-PGO's own code, the inter-robot edges
    INTER_RELATIVE and INTER_LOOP; ``"project"`` also the intra-robot loop closures LOOP; the
    others keep weight 1): IRLS weights ``w_e = ρ'(s_e)`` of the unweighted chordal cost
    ``s_e = F_e`` multiply ``κ_e, τ_e``. They are recomputed from the current iterate before the
    first iteration and every ``weight_interval`` (20) iterations (static between updates: the
    weighted quadratic is minimised by MM; at an update each robot refactorises ``H_α`` (at the
    current iterate) and ``L_α`` and the acceleration state is reset, since the surrogated
    objective changed; MM-PGO's code instead re-evaluates the weights in every gradient, under a
    majoriser built with weight 1). ``inlier_mask``: an edge under the kernel is an outlier when
    its final weight is below the weight at ``s = flag_bound``, i.e. its final
    ``s > flag_bound`` (:func:`robust.flagged`; MM-PGO's code flags nothing, the rule is the
    project's); every other edge is an inlier (in the ``"authors"`` mode an intra-robot loop
    closure is never flagged); None for the kernel ``none``. When ``problem.outlier_mask`` is
    given, ``extras`` has ``precision``/``recall`` of the flagged edges.
    """
    # s = 0 off the kernel's kinds, where every kernel's weight is exactly 1
    return robust.weights(kernel, robust_costs(graph, poses, kinds), scale)
