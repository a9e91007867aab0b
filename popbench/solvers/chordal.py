"""Chordal initialisation: linear rotation synchronisation, then linear translation recovery.

Rotations (the linear / chordal relaxation of Carlone et al. 2015, as in SE-Sync's
``chordal_initialization``). A planar rotation ``R(θ)`` is the unit complex number
``z = cos θ + i sin θ`` and ``R_q = R_p R̃`` reads ``z_q = z_p z̃``. Dropping ``|z| = 1``, the
weighted problem

    min_z  Σ_e κ_e |z_q − z_p z̃_e|²         (= ½ Σ κ_e ‖R_q − R_p R̃_e‖²_F)

with ``z_0 = 1`` (gauge) is a sparse complex linear least-squares problem, solved by its normal
equations (a Hermitian connection Laplacian). Each ``z_i`` is then projected onto SO(2),
``θ_i = arg z_i``.

Translations, rotations fixed: ``min_t Σ_e τ_e ‖t_q − t_p − R_p t̃_e‖²`` with ``t_0 = 0`` is a
weighted graph-Laplacian system with two right-hand sides (x and y).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from popbench import se2
from popbench.graph import PoseGraph
from popbench.objective import weights


def _incidence(
    tails: np.ndarray, heads: np.ndarray, tail_values: np.ndarray, num_poses: int
) -> sp.csr_matrix:
    """``(M, N)`` sparse matrix: ``+1`` at ``(e, q_e)``, ``tail_values[e]`` at ``(e, p_e)``."""
    rows = np.arange(tails.size)
    data = np.concatenate([np.ones(tails.size, dtype=tail_values.dtype), tail_values])
    return sp.csr_matrix(
        (data, (np.concatenate([rows, rows]), np.concatenate([heads, tails]))),
        shape=(tails.size, num_poses),
    )


def _anchored_least_squares(
    incidence: sp.csr_matrix, edge_weights: np.ndarray, rhs: np.ndarray
) -> np.ndarray:
    """Solve ``min_u Σ_e w_e |(A u)_e − b_e|²`` with ``u_0 = 0`` through the normal equations.

    Args:
        incidence: ``A``, ``(M, N)`` (real or complex).
        edge_weights: ``w``, ``(M,)`` positive.
        rhs: ``b``, ``(M,)`` or ``(M, k)``.

    Returns:
        ``u`` with the same trailing shape as ``rhs``, ``(N,)`` or ``(N, k)``, ``u_0 = 0``.
    """
    free = incidence[:, 1:].tocsc()
    weighted_adjoint = free.conj().T @ sp.diags(edge_weights)
    normal = (weighted_adjoint @ free).tocsc()
    solution = splu(normal).solve(np.asarray(weighted_adjoint @ rhs))
    anchor = np.zeros((1,) + solution.shape[1:], dtype=solution.dtype)
    return np.concatenate([anchor, solution])


def chordal_rotations(graph: PoseGraph) -> np.ndarray:
    """Headings ``θ`` [rad], ``(N,)``, from the chordal relaxation projected onto SO(2);
    ``θ_0 = 0``."""
    kappa, _ = weights(graph.information)
    measured = np.exp(1j * graph.measurements[:, 2])
    # Residual z_q − z̃ z_p with z_0 = 1 moved to the right-hand side: unknown u = z − e_0.
    incidence = _incidence(graph.tails, graph.heads, -measured, graph.num_poses)
    rhs = -np.asarray(incidence[:, 0].todense()).ravel()
    z = _anchored_least_squares(incidence, kappa, rhs)
    z[0] += 1.0
    return se2.wrap(np.angle(z))


def recover_translations(graph: PoseGraph, headings: np.ndarray) -> np.ndarray:
    """Translations [m], ``(N, 2)``, minimising ``Σ τ ‖t_q − t_p − R_p t̃‖²`` for fixed
    headings ``(N,)``; ``t_0 = 0``."""
    _, tau = weights(graph.information)
    ones = np.ones(graph.num_edges)
    incidence = _incidence(graph.tails, graph.heads, -ones, graph.num_poses)
    rhs = se2.rotate(headings[graph.tails], graph.measurements[:, :2])
    return _anchored_least_squares(incidence, tau, rhs)


def chordal_initialisation(graph: PoseGraph) -> np.ndarray:
    """The chordal initial estimate, ``(N, 3)`` poses ``(x, y, θ)``, pose 0 at the origin.

    The graph must be connected (otherwise the anchored systems are singular).
    """
    headings = chordal_rotations(graph)
    return np.column_stack([recover_translations(graph, headings), headings])
