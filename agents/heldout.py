"""The rows of ``popbench run heldout`` (popbench.harness.heldout): what each row does to the
robots' local graphs before the shared consensus (popbench.reconcile).

Every policy row runs one episode of the environment (envs.core.PGOCore, the paper's horizon:
each local edge once) from the same start; the learned rows use the environment options their
checkpoint was trained with.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agents.methods import CHECKPOINT_DIR, DEFAULT_CHECKPOINT, cached_actor, run_episode
from popbench import objective
from popbench.datasets import file_sha256
from popbench.distributed import DistributedProblem
from popbench.metrics import ate
from popbench.reconcile import reconcile
from popbench.solvers.local_lm import local_optima
from popbench.synthetic import make_problem

IMITATION_CHECKPOINT = CHECKPOINT_DIR / "imitation-V2-n7.pt"
# Δmax of the hand-made policies when no actor says otherwise (the paper's training bound).
DEFAULT_DELTA_MAX = (0.5, 0.5, 0.2)

Policy = Callable[[Any], tuple[torch.Tensor, torch.Tensor]]


def row_checkpoints(checkpoint: str | Path | None) -> dict[str, tuple[str, str] | None]:
    """``{row: (path, sha256)}`` of the learned rows (None where the file does not exist):
    ``prop-v1`` = ``checkpoint`` (default: the committed actor), ``imitation`` = the committed
    imitation-only actor."""
    paths = {"prop-v1": Path(checkpoint or DEFAULT_CHECKPOINT), "imitation": IMITATION_CHECKPOINT}
    return {
        row: (str(path), file_sha256(path)) if path.is_file() else None
        for row, path in paths.items()
    }


def episode(problem: DistributedProblem, delta_max: np.ndarray, policy: Policy) -> list:
    """The robots' local copies after one episode driven by ``policy(core) -> (edge [n],
    delta [n, 3])``."""
    from envs.core import PGOCore
    from envs.observation import Dimensions

    n = problem.num_robots
    core = PGOCore(n, Dimensions.of([problem]), 1, delta_max=list(delta_max), reward="F")
    core.load([problem], [0])
    for _ in range(int(core.tensors["num_edges"].max())):
        edge, delta = policy(core)
        core.step(torch.as_tensor(edge).view(1, n), torch.as_tensor(delta).view(1, n, 3))
    return core.local_poses(0)


def random_policy(rng: np.random.Generator, delta_max: np.ndarray) -> Policy:
    """A uniformly random unprocessed edge and a uniform Δ in [−Δmax, Δmax]."""

    def policy(core):  # noqa: ANN001, ANN202
        mask = core.action_mask()[0].numpy()
        scores = np.where(mask, rng.random(mask.shape), -1.0)
        return scores.argmax(-1), rng.uniform(-delta_max, delta_max, (mask.shape[0], 3))

    return policy


def greedy_policy(fraction: float = 0.5) -> Policy:
    """The first unprocessed edge, Δ = −fraction · its residual (the environment clips Δ)."""

    def policy(core):  # noqa: ANN001, ANN202
        residuals = core.tensors["residuals"][0]  # (n, E, 3), in each edge's tail frame
        edge = core.action_mask()[0].to(torch.int8).argmax(-1)  # E (no-op) once all are done
        acting = (edge < residuals.shape[1]).unsqueeze(-1)
        r = residuals[torch.arange(edge.numel()), edge.clamp(max=residuals.shape[1] - 1)]
        return edge, torch.where(acting, -fraction * r, torch.zeros_like(r))

    return policy


def local_estimates(row: str, problem: DistributedProblem, spec: dict[str, Any]) -> list:
    """The robots' local copies that ``row`` hands to the consensus."""
    delta_max = np.array(DEFAULT_DELTA_MAX)
    if row == "no-op":
        return problem.split()
    if row == "random":
        rng = np.random.default_rng(spec["problem_seed"])
        return episode(problem, delta_max, random_policy(rng, delta_max))
    if row == "greedy":
        return episode(problem, delta_max, greedy_policy())
    if row == "local-lm":
        return local_optima(problem)[0]
    if row == "ground-truth":
        return problem.split(problem.graph.ground_truth)
    if row in ("prop-v1", "imitation"):
        actor, task = cached_actor(spec["checkpoint"], "cpu")
        with torch.no_grad():
            return run_episode(actor, problem, task=task).local_poses
    raise NotImplementedError(f"held-out row {row!r}")


def evaluate_row(spec: dict[str, Any]) -> dict[str, float]:
    """F and ATE of one row on one held-out problem, and ``F_local``: F of the assembled local
    copies handed to the consensus (the start itself for ``initial``)."""
    problem = make_problem(
        spec["robots"], spec["noise"], spec["poses_per_robot"], seed=spec["problem_seed"]
    )
    graph = problem.graph
    if spec["row"] == "initial":
        f = objective.objective(graph, graph.poses)
        return {"F": f, "ATE": ate(graph.poses, graph.ground_truth), "F_local": f}
    reconciled = reconcile(problem, local_estimates(spec["row"], problem, spec), spec["consensus"])
    return {
        "F": objective.objective(graph, reconciled.poses),
        "ATE": ate(reconciled.poses, graph.ground_truth),
        "F_local": reconciled.F_before,
    }
