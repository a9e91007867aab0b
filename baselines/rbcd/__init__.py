"""Riemannian block-coordinate descent (RBCD / RBCD++) on the rank-r Burer–Monteiro relaxation:
the shared core of ``cc-pgo`` (Tian et al., dpgo) and ``ml-pgo`` (Li et al. 2024).

One file per part of the method, as SE-Sync lays it out:

* :mod:`~baselines.rbcd.relaxation` — the connection Laplacian ``Q``, the relaxed cost, lifting;
* :mod:`~baselines.rbcd.stiefel` — the manifold ``(St(2, r) × R^r)^n``: projections, retraction,
  Riemannian gradient and Hessian;
* :mod:`~baselines.rbcd.rounding` — rounding to poses and the optimality certificate;
* :mod:`~baselines.rbcd.blocks` — the robots' colouring into blocks and each block's rows of ``Q``;
* :mod:`~baselines.rbcd.local_solver` — the robots' trust-region update;
* :mod:`~baselines.rbcd.driver` — the RBCD / RBCD++ iteration and the method's options.

The names below are re-exported for callers that want the method, not its parts. Measurements
(speed, rounding) and the variants tried and not kept: docs/rbcd.md.
"""

from baselines.rbcd.driver import MethodOptions, RBCDOptions, RBCDRun, run_rbcd, solve_rbcd
from baselines.rbcd.local_solver import LocalOptions

__all__ = ["LocalOptions", "MethodOptions", "RBCDOptions", "RBCDRun", "run_rbcd", "solve_rbcd"]
