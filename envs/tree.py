"""Spanning trees of the agents' local graphs and the separator placement.

The ``subtree`` correction mode of :class:`envs.core.PGOCore` (Olson et al. 2006's incremental
parameterisation, TORO) moves a vertex rigidly together with its subtree in a spanning tree of the
agent's local graph. The tree takes odometry edges first (``odometry`` and ``inter_relative``,
a cut odometry edge, weigh 1; loop closures 2; a minimum spanning tree), is rooted at local vertex
0 (the agent's first owned pose, the gauge of its local LM) and is listed in DFS pre-order, so the
subtree of every vertex is one contiguous range ``[position, end)`` of pre-order positions.
A disconnected local graph gives a forest: every further component is rooted at its lowest
local id.

Separator placement: a separator copy starts at the global initial estimate, which for the
odometry start is the global chain's drift, metres away from where the agent's own map puts it.
:func:`place_separators` re-places every copy from an owned neighbour and the measurement between
them (a robot knows both), preferring a cut odometry edge over an inter-robot loop closure.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.sparse.linalg import spsolve_triangular

from popbench import se2
from popbench.graph import EdgeKind, PoseGraph
from popbench.problems.distributed import DistributedProblem, LocalGraph

ODOMETRY_KINDS = (EdgeKind.ODOMETRY, EdgeKind.INTER_RELATIVE)


class SpanningTree(NamedTuple):
    """A rooted spanning tree (forest) of a graph with ``N`` vertices and ``M`` edges.

    Attributes:
        parent: ``(N,)`` parent vertex, −1 at a root.
        parent_edge: ``(N,)`` edge id joining a vertex to its parent, −1 at a root.
        order: ``(N,)`` vertices in DFS pre-order (children after their parent).
        position: ``(N,)`` pre-order position of each vertex (``order[position[v]] == v``).
        end: ``(N,)`` exclusive end of each vertex's subtree range of positions.
        tree_edge: ``(M,)`` bool, the edge is a tree edge.
        mover: ``(M,)`` the endpoint a correction of the edge moves with its subtree: the head,
            unless the head is an ancestor of the tail (then the tail); for a tree edge, the
            endpoint farther from the root.
    """

    parent: np.ndarray
    parent_edge: np.ndarray
    order: np.ndarray
    position: np.ndarray
    end: np.ndarray
    tree_edge: np.ndarray
    mover: np.ndarray


def edge_priority(kinds: np.ndarray) -> np.ndarray:
    """``(M,)`` tree weight of each edge: 1 for odometry-like kinds, 2 for loop closures."""
    return np.where(np.isin(kinds, ODOMETRY_KINDS), 1, 2)


def spanning_tree(graph: PoseGraph) -> SpanningTree:
    """The odometry-first spanning tree of ``graph`` rooted at vertex 0 (see the module
    docstring); parallel edges between one pair keep the best-weighted, lowest id."""
    n, tails, heads = graph.num_poses, graph.tails, graph.heads
    ids = np.flatnonzero(tails != heads)
    low, high = np.minimum(tails[ids], heads[ids]), np.maximum(tails[ids], heads[ids])
    weight = edge_priority(graph.kinds[ids])
    order = np.lexsort((ids, weight, high, low))  # per pair: best weight, then lowest id first
    low, high, weight, ids = low[order], high[order], weight[order], ids[order]
    first = np.ones(ids.size, bool)
    first[1:] = (low[1:] != low[:-1]) | (high[1:] != high[:-1])
    low, high, weight, ids = low[first], high[first], weight[first], ids[first]
    matrix = sparse.coo_matrix((weight.astype(float), (low, high)), shape=(n, n)).tocsr()
    tree = csgraph.minimum_spanning_tree(matrix).tocoo()
    # a virtual root n joins vertex 0 and the lowest vertex of every other component
    _, labels = csgraph.connected_components(tree, directed=False)
    roots = np.unique(labels, return_index=True)[1]
    rows = np.concatenate([tree.row, np.full(roots.size, n)])
    cols = np.concatenate([tree.col, roots])
    adjacency = sparse.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n + 1, n + 1))
    visit, predecessor = csgraph.depth_first_order(adjacency.tocsr(), n, directed=False)
    order = visit[1:]
    parent = predecessor[:n].astype(np.int64)
    parent[parent == n] = -1
    position = np.empty(n, np.int64)
    position[order] = np.arange(n)
    # subtree sizes: (I − C) size = 1 with C[parent, child] = 1, upper triangular in pre-order
    child = np.flatnonzero(parent >= 0)
    children = sparse.csr_matrix(
        (-np.ones(child.size), (position[parent[child]], position[child])), shape=(n, n)
    ) + sparse.identity(n, format="csr")
    size = np.rint(spsolve_triangular(children, np.ones(n), lower=False)).astype(np.int64)
    end = np.empty(n, np.int64)
    end[order] = np.arange(n) + size
    # tree edge of each (parent, child) pair: the pair's best edge
    key_of_pair = low * n + high
    pair = np.minimum(parent[child], child) * n + np.maximum(parent[child], child)
    parent_edge = np.full(n, -1, np.int64)
    parent_edge[child] = ids[np.searchsorted(key_of_pair, pair)]
    tree_edge = np.zeros(graph.num_edges, bool)
    tree_edge[parent_edge[child]] = True
    ancestor = (position[heads] <= position[tails]) & (position[tails] < end[heads])
    mover = np.where(ancestor & (tails != heads), tails, heads)
    return SpanningTree(parent, parent_edge, order, position, end, tree_edge, mover)


def lowest_common_ancestors(tree: SpanningTree, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(M,)`` the lowest common ancestor of each pair ``(a, b)`` in ``tree``, −1 where the two
    lie in different components (binary lifting, vectorised over the pairs)."""
    n = tree.parent.size
    up = np.where(tree.parent >= 0, tree.parent, np.arange(n))

    def is_ancestor(u: np.ndarray, w: np.ndarray) -> np.ndarray:
        return (tree.position[u] <= tree.position[w]) & (tree.position[w] < tree.end[u])

    table = [up]
    for _ in range(max(int(n).bit_length(), 1)):
        table.append(table[-1][table[-1]])
    x = a.copy()
    climbing = ~is_ancestor(a, b)
    for jump in reversed(table):
        step = climbing & ~is_ancestor(jump[x], b)
        x = np.where(step, jump[x], x)
    lca = np.where(climbing, up[x], a)
    return np.where(is_ancestor(lca, b), lca, -1)


def place_separators(
    problem: DistributedProblem, local_poses: Sequence[np.ndarray] | None = None
) -> list[np.ndarray]:
    """Local copies ``[(n_r, 3)]`` with every separator copy re-placed from an owned neighbour.

    Each copy ``s`` takes ``x_s = x_o ∘ z̃`` over an edge ``o → s`` (``x_o ∘ z̃⁻¹`` over
    ``s → o``) from its owned neighbour ``o``, choosing a cut odometry edge over an inter-robot
    loop closure, then the lowest edge id. Owned poses are unchanged.

    Args:
        problem: the problem.
        local_poses: the agents' local copies (default: ``problem.split()``, the initial estimate).
    """
    local_poses = problem.split() if local_poses is None else local_poses
    return [
        _place(local, np.array(poses, dtype=np.float64))
        for local, poses in zip(problem.local_graphs, local_poses, strict=True)
    ]


def _place(local: LocalGraph, poses: np.ndarray) -> np.ndarray:
    graph, owned = local.graph, local.owned_count
    tails, heads = graph.tails, graph.heads
    tail_copy, head_copy = tails >= owned, heads >= owned
    crossing = np.flatnonzero(tail_copy != head_copy)  # one owned endpoint, one copy
    if crossing.size == 0:
        return poses
    copy = np.where(tail_copy[crossing], tails[crossing], heads[crossing])
    order = np.lexsort((crossing, edge_priority(graph.kinds[crossing]), copy))
    copy, crossing = copy[order], crossing[order]
    _, first = np.unique(copy, return_index=True)
    copy, edge = copy[first], crossing[first]
    forward = head_copy[edge]  # owned tail → copy head
    z = graph.measurements[edge]
    z = np.where(forward[:, None], z, se2.inverse(z))
    anchor = np.where(forward, tails[edge], heads[edge])
    poses[copy] = se2.compose(poses[anchor], z)
    return poses


def pack_trees(problem: DistributedProblem, vertices: int, edges: int) -> dict[str, np.ndarray]:
    """Padded per-agent tree arrays for :class:`envs.core.PGOCore` (leading axis = agent).

    ``tree_position``/``tree_end (n, V+1)``: pre-order position and subtree end of each vertex
    (a padding vertex or the trash vertex ``v`` gets ``[v, v + 1)``, outside every real range);
    ``tree_parent (n, V+1)`` (a root and the padding point at themselves); ``tree_edge (n, E+1)``
    bool; ``mover (n, E+1)`` local id moved by a correction of each edge and ``lca (n, E+1)``
    the lowest common ancestor of its endpoints (:mod:`envs.basestep`) (trash ``V`` on padding,
    on the no-op slot and for an edge between two components).
    """
    n, v, e = problem.num_robots, vertices, edges
    slots = np.arange(v + 1)
    pack = {
        "tree_position": np.tile(slots, (n, 1)),
        "tree_end": np.tile(slots + 1, (n, 1)),
        "tree_parent": np.tile(slots, (n, 1)),
        "tree_edge": np.zeros((n, e + 1), bool),
        "mover": np.full((n, e + 1), v, np.int64),
        "lca": np.full((n, e + 1), v, np.int64),
    }
    for robot, local in enumerate(problem.local_graphs):  # one iteration per agent
        tree = spanning_tree(local.graph)
        nv, ne = local.num_vertices, local.graph.num_edges
        pack["tree_position"][robot, :nv] = tree.position
        pack["tree_end"][robot, :nv] = tree.end
        pack["tree_parent"][robot, :nv] = np.where(tree.parent >= 0, tree.parent, np.arange(nv))
        pack["tree_edge"][robot, :ne] = tree.tree_edge
        pack["mover"][robot, :ne] = tree.mover
        lca = lowest_common_ancestors(tree, local.graph.tails, local.graph.heads)
        pack["lca"][robot, :ne] = np.where(lca >= 0, lca, v)
    return pack
