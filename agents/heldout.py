"""The rows of ``popbench run heldout`` (popbench.harness.heldout): what each row does to the
robots' local graphs before the shared consensus (popbench.consensus.reconcile).

Every policy row runs one episode of the environment (envs.core.PGOCore, the paper's horizon:
each local edge once) from the same start, with the separator copies placed from their owned
neighbours (envs.tree.place_separators; the no-op row is that placement alone). The non-learned
rows act in :data:`POLICY_TASK`; the learned rows in the environment their checkpoint was
trained with (:func:`learned_episode`).

The learned rows, each adding one learned part to the one before (docs/training.md):
``learned-order`` (the imitation actor's own edge choices, each executed with Δ := 0 on the
Gauss–Newton base step: what the learned *order* adds to gn-sweep's root-outward one),
``imitation`` (the same actor with its correction: what the learned Δ adds) and ``ga-sac`` (the
GA-SAC fine-tuned actor of the same training run: what the fine-tuning adds; any checkpoint
given, shown under the algorithm that trained it, :func:`row_label`). The ``policy`` row runs a
user's policy (agents.user_policy) in the environment it names.

Each cell is one row on one held-out problem (:class:`HeldoutCell`, read once from the harness's
spec). With an outlier rate (``outlier_rate`` > 0) every row gets the same problem with
outliers injected (popbench.outliers.with_outliers, the loop-closure candidates, seeded by the
problem's seed), and the learned rows are also scored as classifiers of them (:func:`gate_scores`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agents.checkpoint import checkpoint_algorithm
from agents.methods import (
    CHECKPOINT_DIR,
    DEFAULT_CHECKPOINT,
    Episode,
    cached_actor,
    flag_gate,
    run_episode,
)
from agents.outlier_gate import candidate_auc
from envs.modes import TRAJECTORY_MODES
from popbench import objective
from popbench.choices import TRAINING_STEP_RULE
from popbench.consensus.reconcile import DEFAULT_CONSENSUS_ITERATIONS, reconcile
from popbench.datasets import file_sha256
from popbench.metrics import ate
from popbench.problems.distributed import DistributedProblem
from popbench.problems.synthetic import make_problem
from popbench.solvers.local_lm import local_optima

# The cpu-residual recipe's two phases, seed 0: its imitation actor and its GA-SAC actor
# (prop-v1's default, DEFAULT_CHECKPOINT).
IMITATION_CHECKPOINT = CHECKPOINT_DIR / "imitation-V2-n7-residual.pt"
GA_SAC_CHECKPOINT = DEFAULT_CHECKPOINT
# The environment of the non-learned policy rows: the trajectory task without the base step
# (each row's Δ is its own).
POLICY_TASK = dataclasses.replace(TRAJECTORY_MODES, base="none")

LEARNED_ROWS = ("learned-order", "imitation", "ga-sac")  # the rows that run a checkpoint

Policy = Callable[[Any], tuple[torch.Tensor, torch.Tensor]]
POLICY_ENTRIES = ("policy", "policy_arg", "policy_env")  # agents.user_policy.describe_policy's


@dataclasses.dataclass(frozen=True)
class HeldoutCell:
    """One cell of ``popbench run heldout``: a row on one held-out problem, read once from the
    harness's spec (popbench.harness.heldout writes it; an entry an earlier cell lacks reads as
    its default, so cached cells stay valid; the spec's other entries are the cache's).

    Attributes:
        row: the row (``initial``, the policy and learned rows, ``local-lm``, ``ground-truth``).
        robots, noise, poses_per_robot, problem_seed: the held-out problem
            (:func:`popbench.problems.synthetic.make_problem`).
        consensus, consensus_iterations: the consensus (popbench.consensus.reconcile) and its
            ADMM iterations at most.
        outlier_rate: the share of loop-closure candidates made outliers (0: none).
        step_rule: the episode rows' step rule (envs.modes.EnvModes.step_rule).
        checkpoint: a learned row's actor checkpoint (None for the other rows).
        policy: the policy row's entries (:data:`POLICY_ENTRIES`; None for the other rows).
    """

    row: str
    robots: int
    noise: str
    poses_per_robot: int
    problem_seed: int
    consensus: str
    consensus_iterations: int = DEFAULT_CONSENSUS_ITERATIONS
    outlier_rate: float = 0.0
    step_rule: str = TRAINING_STEP_RULE
    checkpoint: str | None = None
    policy: Mapping[str, Any] | None = None

    @classmethod
    def of(cls, spec: Mapping[str, Any]) -> HeldoutCell:
        """The cell a harness spec describes."""
        names = {field.name for field in dataclasses.fields(cls)} - {"policy"}
        policy = {key: spec[key] for key in POLICY_ENTRIES if key in spec}
        return cls(**{key: spec[key] for key in names if key in spec}, policy=policy or None)

    def problem(self) -> DistributedProblem:
        """The held-out problem, with its outliers when ``outlier_rate`` > 0 (seeded alike)."""
        problem = make_problem(
            self.robots, self.noise, self.poses_per_robot, seed=self.problem_seed
        )
        if self.outlier_rate > 0:
            from popbench.outliers import with_outliers

            problem = with_outliers(problem, self.outlier_rate, seed=self.problem_seed)
        return problem


def row_checkpoints(
    checkpoint: str | Path | None, imitation: str | Path | None = None
) -> dict[str, tuple[str, str] | None]:
    """``{row: (path, sha256)}`` of the learned rows (None where the file does not exist):
    ``ga-sac`` = ``checkpoint`` (default: the committed GA-SAC fine-tuned actor,
    :data:`GA_SAC_CHECKPOINT`), ``imitation`` = ``imitation`` (default: the committed
    imitation-only actor) and ``learned-order`` = the same actor as ``imitation`` (its edge
    order is the one measured)."""
    imitation_path = Path(imitation or IMITATION_CHECKPOINT)
    paths = {
        "learned-order": imitation_path,
        "imitation": imitation_path,
        "ga-sac": Path(checkpoint or GA_SAC_CHECKPOINT),
    }
    return {
        row: (str(path), file_sha256(path)) if path.is_file() else None
        for row, path in paths.items()
    }


def row_label(row: str, checkpoint: str | Path) -> str:
    """The name a learned ``row`` is shown under: ``ga-sac`` (the row of any fine-tuned
    checkpoint) under the algorithm that trained ``checkpoint`` (its config's
    ``algorithm_name``: ga-sac, mappo, ippo), the other rows under their own."""
    return checkpoint_algorithm(checkpoint) if row == "ga-sac" else row


def episode(
    problem: DistributedProblem,
    policy: Callable[[Any], Policy],
    step_rule: str = TRAINING_STEP_RULE,
) -> list:
    """The robots' local copies after one episode of the non-learned rows' environment
    (:data:`POLICY_TASK` under ``step_rule``, separators placed) driven by ``policy(core)``, a
    function of the core returning the per-step policy ``step(core) -> (edge [n], delta
    [n, 3])``."""
    from envs.core import PGOCore

    n = problem.num_robots
    core = PGOCore.for_problems([problem], dataclasses.replace(POLICY_TASK, step_rule=step_rule))
    step = policy(core)
    for _ in range(core.horizon):
        edge, delta = step(core)
        core.step(torch.as_tensor(edge).view(1, n), torch.as_tensor(delta).view(1, n, 3))
    return core.local_poses(0)


def random_policy(rng: np.random.Generator) -> Callable[[Any], Policy]:
    """A uniformly random unprocessed edge and a uniform Δ within the action bound."""

    def make(core):  # noqa: ANN001, ANN202
        bound = core.action_bound.numpy()

        def policy(core):  # noqa: ANN001, ANN202
            mask = core.action_mask()[0].numpy()
            scores = np.where(mask, rng.random(mask.shape), -1.0)
            return scores.argmax(-1), rng.uniform(-bound, bound, (mask.shape[0], 3))

        return policy

    return make


def greedy_policy(fraction: float = 0.5) -> Callable[[Any], Policy]:
    """The first unprocessed edge, Δ = −fraction · its observed residual (in the action's units;
    the environment clips Δ)."""

    def policy(core):  # noqa: ANN001, ANN202
        residuals = core.observation()["residuals"][0]  # (n, E, 3), in each edge's tail frame
        edge = core.action_mask()[0].to(torch.int8).argmax(-1)  # E (no-op) once all are done
        acting = (edge < residuals.shape[1]).unsqueeze(-1)
        r = residuals[torch.arange(edge.numel()), edge.clamp(max=residuals.shape[1] - 1)]
        return edge, torch.where(acting, -fraction * r, torch.zeros_like(r))

    return lambda core: policy


def class_policy(kind: type) -> Callable[[Any], Policy]:
    """A policy object of the environment (envs.expert.Expert, envs.sweep.GaussNewtonSweep)
    acting on its own core."""

    def make(core):  # noqa: ANN001, ANN202
        agent = kind(core)
        return lambda core: tuple(value[0] for value in agent.act())

    return make


def learned_episode(
    row: str, problem: DistributedProblem, checkpoint: str | Path, step_rule: str | None = None
) -> Episode:
    """One deterministic episode of the actor in ``checkpoint`` (agents.methods.run_episode, in
    the environment it was trained in, under ``step_rule`` where given) for the learned ``row``:
    ``learned-order`` runs it with Δ := 0 in that environment with the Gauss–Newton base step
    (the base step alone on each edge the actor chooses; the committed actors' own base),
    ``imitation`` / ``ga-sac`` as prop-v1 runs it."""
    actor, task = cached_actor(str(checkpoint), "cpu")
    if step_rule is not None:
        task = dataclasses.replace(task, step_rule=step_rule)
    correction = row != "learned-order"
    if not correction:
        task = dataclasses.replace(task, base="gauss-newton")
    with torch.no_grad():
        return run_episode(actor, problem, task=task, correction=correction)


def local_estimates(
    row: str,
    problem: DistributedProblem,
    *,
    step_rule: str = TRAINING_STEP_RULE,
    checkpoint: str | Path | None = None,
    seed: int = 0,
) -> list:
    """The robots' local copies that ``row`` (not ``policy``, :func:`evaluate_row` runs it)
    hands to the consensus: a learned row runs the actor of ``checkpoint``, ``random`` draws
    with ``seed``; the episode rows under ``step_rule`` (envs.core.PGOCore)."""
    from envs.expert import Expert
    from envs.sweep import GaussNewtonSweep
    from envs.tree import place_separators

    if row == "no-op":
        return place_separators(problem)
    if row == "random":
        return episode(problem, random_policy(np.random.default_rng(seed)), step_rule)
    if row == "greedy":
        return episode(problem, greedy_policy(), step_rule)
    if row == "gn-sweep":
        return episode(problem, class_policy(GaussNewtonSweep), step_rule)
    if row == "expert":
        return episode(problem, class_policy(Expert), step_rule)
    if row in LEARNED_ROWS:
        return learned_episode(row, problem, checkpoint, step_rule).local_poses
    if row == "local-lm":
        return local_optima(problem)[0]
    if row == "ground-truth":
        return problem.split(problem.graph.ground_truth)
    raise NotImplementedError(f"held-out row {row!r}")


def gate_scores(
    problem: DistributedProblem, gate: np.ndarray, threshold: float
) -> dict[str, float]:
    """The actor's gate as an outlier classifier over the candidate edges (the loop closures,
    popbench.outliers.candidate_mask): ``gate_auc``, the ROC AUC of the outlier score 1 − gate
    (agents.outlier_gate.candidate_auc; NaN without an outlier), and the counts behind precision
    and recall at the inference ``threshold`` (an edge is flagged when its gate is ≤ it in a
    robot that holds it, as prop-v1 flags it): ``gate_flagged``, ``gate_true`` (injected
    outliers) and ``gate_hits``."""
    from popbench.outliers import candidate_mask

    among = candidate_mask(problem.graph)
    truth = problem.outlier_mask[among]
    flagged = gate[among] <= threshold
    return {
        "gate_auc": candidate_auc(problem, gate),
        "gate_flagged": float(flagged.sum()),
        "gate_true": float(truth.sum()),
        "gate_hits": float((flagged & truth).sum()),
    }


def robots_local_f(problem: DistributedProblem, local_poses: list) -> float:
    """Σ_i F_i: each robot's own local objective (its local graph, edges with an owned endpoint)
    at its own copy ``local_poses[i]`` — what the episode lowers, free of the robots' gauges."""
    return float(
        sum(
            objective.objective(local.graph, np.asarray(poses))
            for local, poses in zip(problem.local_graphs, local_poses, strict=True)
        )
    )


def evaluate_row(spec: dict[str, Any]) -> dict[str, float]:
    """F and ATE of one row on one held-out problem (the cell ``spec`` describes,
    :class:`HeldoutCell`), ``F_local``: F of the assembled local copies handed to the consensus
    (the start itself for ``initial``), and ``F_robots``: the robots' own local F before the
    consensus (:func:`robots_local_f`); with an outlier rate, the learned rows add
    :func:`gate_scores`."""
    cell = HeldoutCell.of(spec)
    problem = cell.problem()
    graph = problem.graph
    if cell.row == "initial":
        f = objective.objective(graph, graph.poses)
        robots = robots_local_f(problem, problem.split())
        return {
            "F": f,
            "ATE": ate(graph.poses, graph.ground_truth),
            "F_local": f,
            "F_robots": robots,
        }
    learned = cell.row in LEARNED_ROWS
    if learned:
        run = learned_episode(cell.row, problem, cell.checkpoint, cell.step_rule)
        local = run.local_poses
    elif cell.row == "policy":
        from agents.user_policy import policy_episode

        protocol = (cell.robots, cell.noise, cell.poses_per_robot)
        local = policy_episode(problem, cell.policy or {}, protocol)
    else:
        local = local_estimates(cell.row, problem, step_rule=cell.step_rule, seed=cell.problem_seed)
    reconciled = reconcile(problem, local, cell.consensus, cell.consensus_iterations)
    scores: dict[str, float] = {}
    if learned and cell.outlier_rate > 0:  # the gate prop-v1 flags from (agents.methods.flag_gate)
        task = cached_actor(cell.checkpoint, "cpu")[1]
        scores = gate_scores(
            problem, *flag_gate(problem, run, reconciled.poses, cell.checkpoint, task)
        )
    return {
        "F": objective.objective(graph, reconciled.poses),
        "ATE": ate(reconciled.poses, graph.ground_truth),
        "F_local": reconciled.F_before,
        "F_robots": robots_local_f(problem, local),
        **scores,
    }
