"""Padding and features of the PGO environment: per-agent local graphs packed into fixed-size
arrays (``V`` vertices, ``E`` edges, ``D`` incident edges per vertex) and the edge attributes of
paper §III-C. Pure numpy; :mod:`envs.core` turns the packs into batched torch state.

Trash slots: the packed arrays have one extra vertex row (index ``V``) and one extra edge slot
(index ``E``); padding edges point at the trash vertex and padding incidence entries at the trash
edge slot, so that the torch step needs no branch for padding or for the no-op action.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from envs.features import EDGE, EDGE_COLUMN, NODE
from popbench import se2
from popbench.errors import ValueRangeError
from popbench.objective import weights
from popbench.problems.distributed import DistributedProblem

REWARDS = ("localisation", "F")
NUM_KINDS = 4
NODE_FEATURES = len(NODE)  # the node feature columns, envs.features.NODE
EDGE_FEATURES = len(EDGE)  # the edge attribute columns, envs.features.EDGE


@dataclasses.dataclass(frozen=True)
class Dimensions:
    """Padding maxima of one agent's local graph: ``vertices`` (V), ``edges`` (E), ``degree`` (D,
    edges incident to one vertex)."""

    vertices: int
    edges: int
    degree: int

    @classmethod
    def of(
        cls, problems: Sequence[DistributedProblem], margin: float = 1.0, multiple: int = 1
    ) -> Dimensions:
        """The maxima over ``problems``' local graphs, times ``margin``, rounded up to a
        ``multiple``."""
        sizes = np.array([_local_sizes(problem) for problem in problems]).max(axis=0)
        rounded = np.ceil(sizes * margin / multiple).astype(int) * multiple
        return cls(*(int(value) for value in rounded))


def _local_sizes(problem: DistributedProblem) -> tuple[int, int, int]:
    """Largest (vertices, edges, degree) over ``problem``'s local graphs."""
    sizes = []
    for local in problem.local_graphs:
        tails, heads = local.graph.tails, local.graph.heads
        ends = np.concatenate([tails, heads[tails != heads]])
        degree = int(np.bincount(ends).max()) if ends.size else 0
        sizes.append((local.num_vertices, local.graph.num_edges, degree))
    return tuple(int(value) for value in np.max(sizes, axis=0))


def fits(problem: DistributedProblem, dims: Dimensions) -> bool:
    """Whether every local graph of ``problem`` fits the padding maxima ``dims``."""
    limits = (dims.vertices, dims.edges, dims.degree)
    return all(size <= limit for size, limit in zip(_local_sizes(problem), limits, strict=True))


def check_fits(problem: DistributedProblem, dims: Dimensions) -> None:
    """Raise :class:`ValueRangeError` naming the option when ``problem`` exceeds ``dims``."""
    names = ("max_vertices", "max_edges", "max_degree")
    limits = (dims.vertices, dims.edges, dims.degree)
    for name, size, limit in zip(names, _local_sizes(problem), limits, strict=True):
        if size > limit:
            raise ValueRangeError(
                name, limit, f"at least {size} for problem {problem.graph.name!r}"
            )


def pack_problem(
    problem: DistributedProblem,
    dims: Dimensions,
    reward: str = "localisation",
    local_poses: Sequence[np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Padded per-agent arrays of one problem (leading axis = agent ``n``).

    ``local_poses`` (one ``(n_r, 3)`` array per agent) replaces the initial local copies
    (default: the problem's initial estimate), e.g. with placed separators
    (:func:`envs.tree.place_separators`).

    Returns a dict of numpy arrays: ``vertex_ids (n,V)`` global ids (−1 pad), ``node_mask``,
    ``owned``, ``log_degree (n,V)``, ``poses (n,V+1,3)``, ``tails``/``heads (n,E+1)`` local ids
    (pad and no-op slot → trash vertex ``V``), ``edge_ids (n,E)`` global ids (−1 pad),
    ``edge_mask (n,E)``, ``measurements``/``targets (n,E+1,3)``, ``kappa``/``tau (n,E+1)``
    (0 on pads), ``edge_attr (n,E,11)``, ``incident (n,V+1,D)`` edge slots (pad → ``E``),
    ``num_edges (n,)``, ``sqrt_information``/``inverse_sqrt_information (n,E+1,3,3)``
    (:func:`whitening`; identity on pads), ``outlier (n,E)`` bool: the edge is an injected
    outlier (``problem.outlier_mask``; a training label, never an observation).
    """
    graph = problem.graph
    if reward not in REWARDS:
        raise ValueRangeError("reward", reward, ", ".join(REWARDS))
    if reward == "localisation" and graph.ground_truth is None:
        raise ValueRangeError(
            "reward", reward, f"'F' for {graph.name!r}, which has no ground truth"
        )
    check_fits(problem, dims)
    n, v, e, d = problem.num_robots, dims.vertices, dims.edges, dims.degree
    pack = {
        "vertex_ids": np.full((n, v), -1, np.int64),
        "node_mask": np.zeros((n, v), bool),
        "owned": np.zeros((n, v), bool),
        "log_degree": np.zeros((n, v)),
        "poses": np.zeros((n, v + 1, 3)),
        "tails": np.full((n, e + 1), v, np.int64),
        "heads": np.full((n, e + 1), v, np.int64),
        "edge_ids": np.full((n, e), -1, np.int64),
        "edge_mask": np.zeros((n, e), bool),
        "measurements": np.zeros((n, e + 1, 3)),
        "targets": np.zeros((n, e + 1, 3)),
        "kappa": np.zeros((n, e + 1)),
        "tau": np.zeros((n, e + 1)),
        "edge_attr": np.zeros((n, e, EDGE_FEATURES), np.float32),
        "incident": np.full((n, v + 1, d), e, np.int64),
        "num_edges": np.zeros(n, np.int64),
        "sqrt_information": np.tile(np.eye(3), (n, e + 1, 1, 1)),
        "inverse_sqrt_information": np.tile(np.eye(3), (n, e + 1, 1, 1)),
        "outlier": np.zeros((n, e), bool),
    }
    outlier_mask = problem.outlier_mask
    kappa_all, tau_all = weights(graph.information)
    gap_scale = np.log1p(max(graph.num_poses - 1, 1))
    for robot, local in enumerate(problem.local_graphs):  # one iteration per agent
        nv, ne = local.num_vertices, local.graph.num_edges
        tails, heads, edges = local.graph.tails, local.graph.heads, local.edge_ids
        pack["vertex_ids"][robot, :nv] = local.global_ids
        pack["node_mask"][robot, :nv] = True
        pack["owned"][robot, : local.owned_count] = True
        degree = np.bincount(np.concatenate([tails, heads[tails != heads]]), minlength=nv)
        pack["log_degree"][robot, :nv] = np.log1p(degree)
        pack["poses"][robot, :nv] = local.graph.poses if local_poses is None else local_poses[robot]
        pack["tails"][robot, :ne], pack["heads"][robot, :ne] = tails, heads
        pack["edge_ids"][robot, :ne] = edges
        pack["edge_mask"][robot, :ne] = True
        pack["measurements"][robot, :ne] = local.graph.measurements
        if reward == "F":
            pack["targets"][robot, :ne] = local.graph.measurements
        else:
            truth = local.graph.ground_truth
            pack["targets"][robot, :ne] = se2.between(truth[tails], truth[heads])
        pack["kappa"][robot, :ne], pack["tau"][robot, :ne] = kappa_all[edges], tau_all[edges]
        gap = np.abs(graph.heads[edges] - graph.tails[edges])
        pack["edge_attr"][robot, :ne] = edge_attributes(
            local.graph.kinds, local.graph.information, local.graph.measurements, gap, gap_scale
        )
        pack["incident"][robot] = _incidence(tails, heads, v, d, e)
        pack["num_edges"][robot] = ne
        root, inverse_root = whitening(local.graph.information)
        pack["sqrt_information"][robot, :ne] = root
        pack["inverse_sqrt_information"][robot, :ne] = inverse_root
        if outlier_mask is not None:
            pack["outlier"][robot, :ne] = outlier_mask[edges]
    return pack


def whitening(information: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Λ^½, Λ^−½)``, each ``(M, 3, 3)``: the symmetric square root of each edge's information
    and its inverse (``Λ^½ r`` is a residual in units of the edge's own standard deviation;
    ``‖Λ^½ r‖² = rᵀΛr``)."""
    values, vectors = np.linalg.eigh(information)
    root = np.sqrt(np.maximum(values, np.finfo(float).tiny))
    transposed = np.swapaxes(vectors, 1, 2)
    return (vectors * root[:, None, :]) @ transposed, (vectors / root[:, None, :]) @ transposed


def whiten_attributes(pack: dict[str, np.ndarray]) -> None:
    """Scale-free edge attributes in place (``action_scale="whitened"``): ``‖t̃‖ → √τ ‖t̃‖`` and
    ``log diag Λ`` centred on the agent's mean over its edges."""
    attr, mask = pack["edge_attr"], pack["edge_mask"]
    e = attr.shape[1]
    attr[..., EDGE_COLUMN["length"]] *= np.sqrt(pack["tau"][:, :e]).astype(np.float32)
    info = slice(EDGE_COLUMN["log_info_x"], EDGE_COLUMN["log_info_theta"] + 1)
    count = np.maximum(mask.sum(1, keepdims=True), 1)[..., None]
    mean = (attr[..., info] * mask[..., None]).sum(1, keepdims=True) / count
    attr[..., info] = np.where(mask[..., None], attr[..., info] - mean, 0.0)


def edge_attributes(
    kinds: np.ndarray,
    information: np.ndarray,
    measurements: np.ndarray,
    gap: np.ndarray,
    gap_scale: float,
) -> np.ndarray:
    """``(M, 11)`` float32 edge attributes (paper §III-C): kind one-hot (4), ``log diag Λ`` (3),
    timestep gap ``log(1 + |q − p|) / log(N)`` (global ids, ∈ (0, 1]), ``‖t̃‖`` [m],
    ``sin θ̃``, ``cos θ̃``."""
    one_hot = np.eye(NUM_KINDS)[kinds.astype(np.int64)]
    log_information = np.log(np.diagonal(information, axis1=1, axis2=2))
    gap_feature = np.log1p(gap) / gap_scale
    length = np.linalg.norm(measurements[:, :2], axis=1)
    angle = measurements[:, 2]
    columns = [gap_feature, length, np.sin(angle), np.cos(angle)]
    return np.column_stack([one_hot, log_information, *columns]).astype(np.float32)


def _incidence(
    tails: np.ndarray, heads: np.ndarray, num_vertices: int, degree: int, pad: int
) -> np.ndarray:
    """``(num_vertices + 1, degree)`` edge ids incident to each vertex, padded with ``pad``."""
    ids = np.arange(tails.size)
    distinct = tails != heads  # a self-loop is listed once
    ends = np.concatenate([tails, heads[distinct]])
    edges = np.concatenate([ids, ids[distinct]])
    order = np.argsort(ends, kind="stable")
    ends, edges = ends[order], edges[order]
    starts = np.searchsorted(ends, ends, side="left")
    slot = np.arange(ends.size) - starts
    table = np.full((num_vertices + 1, degree), pad, np.int64)
    table[ends, slot] = edges
    return table
