"""The outlier gate: the actor's gated encoder run once more, on the robots' local graphs at the
reconciled estimate (beyond the paper; docs/outliers.md).

During the episode a robot's separator copies are placed from its own map, so an inter-robot
loop closure that is the only edge to its copy has a zero residual, outlier or not; after the
consensus every copy holds its owner's value and an outlier's residual shows. A checkpoint may
carry an encoder fitted for that state (agents.gate_training) with its flag threshold; prop-v1
then flags an edge when that encoder's layer-averaged gate is ≤ the threshold in a robot that
holds it, and otherwise when the episode's own final gate is ≤ ½.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from agents.encoder import GraphBatch, GraphEncoder
from envs.modes import EnvModes
from popbench.problems.distributed import DistributedProblem

if TYPE_CHECKING:
    from envs.core import PGOCore

GATE_THRESHOLD = 0.5  # the episode gate's flag threshold (the hard-concrete relaxation's median)


@dataclasses.dataclass
class OutlierGate:
    """A fitted outlier gate: the encoder and its flag threshold (an edge is an outlier when its
    gate is ≤ ``threshold``; chosen on the fit's validation problems, agents.gate_training)."""

    encoder: GraphEncoder
    threshold: float


@dataclasses.dataclass
class GateState:
    """The robots' local graphs at one estimate, packed for the encoder.

    Attributes:
        graphs: the G = n local graphs (envs.core's observation; no separator placement).
        edge_ids: (n, E) long, the global id of each local edge slot (−1 on padding).
        edge_mask: (n, E) bool, real edge slots.
        outlier: (n, E) bool, injected outliers (a training label, never an input).
        num_edges: M, the global graph's edge count.
    """

    graphs: GraphBatch
    edge_ids: Tensor
    edge_mask: Tensor
    outlier: Tensor
    num_edges: int


def reconciled_state(
    problem: DistributedProblem, poses: np.ndarray, task: EnvModes, core: PGOCore | None = None
) -> GateState:
    """Every robot's local graph with each vertex, owned or a separator copy, at its global
    ``poses`` ``(N, 3)`` value, observed as in the environment ``task``: in ``core`` (prop-v1's
    episode core over ``problem``, restarted at ``poses``) when given, else in a new one."""
    from envs.core import PGOCore

    if core is None:
        at = dataclasses.replace(problem, graph=problem.graph.replace(poses=np.asarray(poses)))
        core = PGOCore.for_problems([at], task, place_separators=False)
    else:
        if core.problems[0] is not problem:
            raise ValueError("the core does not hold this problem")
        core.restart_at(0, poses)
    t = core.state
    return GateState(
        graphs=GraphBatch(**core.graph_batch(0)),
        edge_ids=t.edge_ids[0],
        edge_mask=t.edge_mask[0],
        outlier=t.outlier[0],
        num_edges=problem.graph.num_edges,
    )


def holder_minimum(
    values: Tensor, edge_ids: Tensor, edge_mask: Tensor, num_edges: int
) -> np.ndarray:
    """``(M,)``: per global edge, the smallest of ``values`` ``(n, E)`` over the robots that hold
    it (``edge_ids`` ``(n, E)`` their global ids, real where ``edge_mask``; 1 for an edge no
    robot holds)."""
    gate = np.ones(num_edges)
    np.minimum.at(gate, edge_ids[edge_mask].numpy(), values[edge_mask].detach().numpy())
    return gate


def state_gate(encoder: GraphEncoder, state: GateState) -> np.ndarray:
    """``(M,)`` the layer-averaged noise-free gate of every global edge, the smallest over its
    holders (1 − gate is the outlier score)."""
    with torch.no_grad():
        gates = encoder(state.graphs, deterministic=True).gates.mean(0)
    return holder_minimum(gates, state.edge_ids, state.edge_mask, state.num_edges)


def reconciled_gate(
    encoder: GraphEncoder,
    task: EnvModes,
    problem: DistributedProblem,
    poses: np.ndarray,
    core: PGOCore | None = None,
) -> np.ndarray:
    """:func:`state_gate` at the reconciled estimate ``poses`` ``(N, 3)`` (in ``core``, as
    :func:`reconciled_state`)."""
    return state_gate(encoder, reconciled_state(problem, poses, task, core))


def candidate_auc(problem: DistributedProblem, gate: np.ndarray) -> float:
    """ROC AUC of the outlier score 1 − ``gate`` ``(M,)`` against ``problem``'s injected
    outliers, over the corruptible edges (the loop closures, popbench.outliers.candidate_mask);
    NaN without an outlier."""
    from popbench.metrics import roc_auc
    from popbench.outliers import candidate_mask

    among = candidate_mask(problem.graph)
    return roc_auc(1.0 - gate[among], problem.outlier_mask[among])


def f1_threshold(gates: list[np.ndarray], outliers: list[np.ndarray]) -> float:
    """The flag threshold t (flag: gate ≤ t) with the largest F1 over the pooled edges of
    ``gates`` and their labels ``outliers`` (lists of equal-shape arrays): the midpoint between
    the gate values on either side of the best cut (0.5 without an outlier)."""
    gate, outlier = np.concatenate(gates), np.concatenate(outliers).astype(bool)
    if not outlier.any():
        return GATE_THRESHOLD
    order = np.argsort(gate, kind="mergesort")
    gate, outlier = gate[order], outlier[order]
    last = np.r_[np.nonzero(np.diff(gate))[0], gate.size - 1]  # the last index of each value
    hits = np.cumsum(outlier)[last]
    f1 = 2.0 * hits / (last + 1 + outlier.sum())  # 2PR / (P + R) = 2·hits / (flagged + true)
    best = int(np.argmax(f1))
    above = gate[last[best] + 1] if last[best] + 1 < gate.size else 1.0
    return float(0.5 * (gate[last[best]] + above))
