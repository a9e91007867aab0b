"""Fitting the outlier gate of a trained actor (agents.outlier_gate; beyond the paper,
docs/outliers.md).

States: for each training problem (synthetic, outliers at a rate drawn from U(0, r_max)) the
actor's deterministic episode, the consensus, and the robots' local graphs at the reconciled
estimate (agents.outlier_gate.reconciled_state). Model: a copy of the actor's encoder, every
parameter trainable (the actor itself is not changed). Loss per state, one Adam step each:

    L = L_gate + λ_1 · mean z

with L_gate the class-balanced supervised gate loss of agents.loss_terms against the injected
labels and mean z the gates' L1 penalty. The kept encoder is the one of the epoch with the best
mean ROC AUC on the validation problems (a stream apart from the training one and from the
held-out seeds 2^32 + k of popbench.harness.heldout), and its flag threshold the one with the
best F1 over those problems' loop closures (agents.outlier_gate.f1_threshold).
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from agents.actor import HybridActor
from agents.config import ExperimentConfig, OutlierGateConfig
from agents.encoder import GraphEncoder
from agents.loss_terms import gate_supervision_loss
from agents.outlier_gate import (
    GateState,
    OutlierGate,
    candidate_auc,
    f1_threshold,
    reconciled_state,
    state_gate,
)
from envs.modes import EnvModes
from popbench.problems.distributed import DistributedProblem

TRAINING_STREAM, VALIDATION_STREAM = 0x6A7E, 0x6A7F  # SeedSequence keys [seed, k, stream]


@dataclasses.dataclass
class GateFit:
    """The fitted encoder and its record.

    Attributes:
        gate: the fitted encoder (eval mode) and its flag threshold.
        epochs: one dict per epoch: ``epoch``, ``loss`` (mean L), ``validation_auc``.
        best_epoch: the kept epoch (0 = the actor's own encoder).
        seconds: wall time of the fit, states included [s].
    """

    gate: OutlierGate
    epochs: list[dict[str, float]]
    best_epoch: int
    seconds: float


def problem_seed(seed: int, k: int, stream: int) -> int:
    """The seed of problem ``k`` of a gate-fitting stream."""
    return int(np.random.SeedSequence([seed, k, stream]).generate_state(1)[0])


def reconciled_states(
    actor: HybridActor,
    task: EnvModes,
    problems: list[DistributedProblem],
    consensus: str,
    on_problem: Callable[[], None] | None = None,
) -> list[tuple[DistributedProblem, GateState]]:
    """Each problem with its robots' local graphs after the actor's episode and the consensus."""
    from agents.methods import run_episode
    from popbench.consensus.reconcile import reconcile

    states = []
    for problem in problems:
        with torch.no_grad():
            episode = run_episode(actor, problem, task=task)
        poses = reconcile(problem, episode.local_poses, consensus).poses
        states.append((problem, reconciled_state(problem, poses, task)))
        if on_problem is not None:
            on_problem()
    return states


def mean_auc(encoder: GraphEncoder, states: list[tuple[DistributedProblem, GateState]]) -> float:
    """Mean :func:`agents.outlier_gate.candidate_auc` over the states with an outlier."""
    values = [candidate_auc(problem, state_gate(encoder, state)) for problem, state in states]
    return float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")


def fit_outlier_gate(
    actor: HybridActor,
    task: EnvModes,
    config: OutlierGateConfig,
    experiment: ExperimentConfig,
    on_problem: Callable[[], None] | None = None,
) -> GateFit:
    """Fit the outlier gate of ``actor`` (module docstring) on synthetic problems like its
    training ones (``experiment``'s team size, noise level and poses per robot);
    ``on_problem`` is told after each state is made."""
    from envs import make_problem_source
    from popbench.consensus.reconcile import DEFAULT_CONSENSUS

    started = time.perf_counter()
    source = make_problem_source(
        experiment.robots,
        experiment.noise,
        poses_per_robot=experiment.poses_per_robot,
        start_noise=experiment.start_noise,
        outlier_rate_max=config.outlier_rate_max,
    )[0]
    consensus = config.consensus or DEFAULT_CONSENSUS

    def stream(key: int, count: int) -> list[tuple[DistributedProblem, GateState]]:
        problems = [source(problem_seed(config.seed, k, key)) for k in range(count)]
        return reconciled_states(actor, task, problems, consensus, on_problem)

    training = stream(TRAINING_STREAM, config.problems)
    validation = stream(VALIDATION_STREAM, config.validation)
    torch.manual_seed(config.seed)
    encoder = copy.deepcopy(actor.encoder).requires_grad_(True)
    optimiser = torch.optim.Adam(encoder.parameters(), lr=config.lr)
    order = np.random.default_rng(config.seed)
    auc = mean_auc(encoder, validation)
    best = (np.nan_to_num(auc, nan=-np.inf), 0, copy.deepcopy(encoder.state_dict()))
    epochs = [{"epoch": 0, "loss": float("nan"), "validation_auc": auc}]
    for epoch in range(1, config.epochs + 1):
        losses = []
        for index in order.permutation(len(training)):
            state = training[index][1]
            encoding = encoder(state.graphs, deterministic=True)
            loss = gate_supervision_loss(encoding.gate_logits, state.outlier, state.edge_mask)
            loss = loss + config.gate_l1 * encoding.gate_l1
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(loss.item())
        auc = mean_auc(encoder, validation)
        epochs.append({"epoch": epoch, "loss": float(np.mean(losses)), "validation_auc": auc})
        if auc > best[0]:
            best = (auc, epoch, copy.deepcopy(encoder.state_dict()))
    encoder.load_state_dict(best[2])
    encoder.requires_grad_(False).eval()
    threshold = validation_threshold(encoder, validation)
    return GateFit(OutlierGate(encoder, threshold), epochs, best[1], time.perf_counter() - started)


def validation_threshold(
    encoder: GraphEncoder, states: list[tuple[DistributedProblem, GateState]]
) -> float:
    """:func:`agents.outlier_gate.f1_threshold` over the loop closures of ``states``."""
    from popbench.outliers import candidate_mask

    gates, outliers = [], []
    for problem, state in states:
        among = candidate_mask(problem.graph)
        gates.append(state_gate(encoder, state)[among])
        outliers.append(problem.outlier_mask[among])
    return f1_threshold(gates, outliers)


def fit_checkpoint(
    checkpoint: str | Path,
    out: str | Path,
    config: OutlierGateConfig,
    progress: bool = True,
) -> str:
    """``popbench train-gate``: fit the outlier gate of ``checkpoint``'s actor on problems
    like its training ones, write the checkpoint with it to ``out``, and
    return a summary (validation ROC AUC per epoch, the kept epoch, wall time)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    from agents.checkpoint import add_outlier_gate, load_actor

    actor, trained = load_actor(checkpoint)
    experiment = trained.experiment
    with Progress(
        "states", BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), disable=not progress
    ) as bar:
        task = bar.add_task("states", total=config.problems + config.validation)
        fit = fit_outlier_gate(
            actor, trained.task, config, experiment, on_problem=lambda: bar.advance(task)
        )
    add_outlier_gate(checkpoint, out, config, fit.gate, fit.epochs, fit.best_epoch, fit.seconds)
    aucs = ", ".join(f"{epoch['validation_auc']:.3f}" for epoch in fit.epochs)
    return (
        f"{out}: outlier gate of {checkpoint} (n = {experiment.robots}, {experiment.noise}); "
        f"validation ROC AUC by epoch {aucs}; kept epoch {fit.best_epoch}; flag threshold "
        f"{fit.gate.threshold:.4f}; wall time {fit.seconds:.0f} s"
    )
