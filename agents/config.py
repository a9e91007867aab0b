"""Configuration dataclasses for GA-SAC, MAPPO and IPPO, split BenchMARL-style into model /
algorithm / experiment / task.

Values are the paper's (§IV-A) where it gives them; every other value is a choice written down
here with its reason (docs/training.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any

from envs.modes import PAPER_MODES, TRAJECTORY_MODES, EnvModes

if TYPE_CHECKING:
    from envs.tasks import Task


@dataclass(frozen=True)
class ModelConfig:
    """Network sizes of the actor (recurrent gated GNN + two heads) and the central critic.

    Attributes:
        hidden: node-embedding width d of every GNN layer (paper: 128).
        layers: number of edge-conditioned layers, each followed by an edge gate (paper: 5).
        edge_hidden: width K of φ_edge's hidden layer; W_pq = B_0 + Σ_k φ_k(a_pq) B_k is then the
            exact output of the MLP φ_edge (see encoder.EdgeConditionedConv), not an approximation.
        activation: node-update non-linearity σ of eq. node_update; "sigmoid" as the paper writes.
        gate_hidden: hidden width of P_gate (paper: "lightweight"; our choice).
        gate_temperature: hard-concrete temperature τ of eq. bernoulli (Louizos et al.: 2/3).
        gate_inter_loop_bias: β > 0 added to the logit of inter-robot loop closures (eq. logit).
        gate_init_logit: initial bias of P_gate's output so that gates start open (z ≈ 1).
        memory_layers: K stacked GRU cells (paper: unspecified; 2).
        memory_hidden: GRU state width (= hidden by default).
        edge_head_hidden: hidden width of the edge-selection head (paper: 200).
        gumbel_temperature: Gumbel-softmax temperature of the edge selector (paper: unspecified; 1).
        correction_hidden: widths of the correction MLP (paper: 2 × 512).
        log_std_bounds: clamp of the Gaussian log-std before the tanh squash.
        correction_init_log_std: initial bias of the correction head's log-std outputs (the mean
            outputs start at zero: the untrained deterministic policy is the no-op; our choice).
        delta_max: bound |δx|, |δy|, |δθ| ≤ Δmax (metres, metres, radians); the environment's
            action spec overrides it in the trainer.
        critic_hidden: critic GNN width; critic_layers its depth (non-recurrent, gated).
        critic_projection: width of the joint projection (paper: 512).
        critic_mlp: hidden widths of the critic MLP after the projection (paper: 512, 256).
        base_features: the correction head reads the Gauss–Newton base step of the chosen edge
            and its quadratic model (agents.encoder.base_inputs), and the critic the executed
            correction (δ + Δ_GN, clipped) and its predicted gain; needs an environment with the
            base step (EnvModes.base = "gauss-newton"). False: the earlier actors' heads.
    """

    hidden: int = 128
    layers: int = 5
    edge_hidden: int = 16
    activation: str = "sigmoid"
    gate_hidden: int = 64
    gate_temperature: float = 2.0 / 3.0
    gate_inter_loop_bias: float = 0.5
    gate_init_logit: float = 2.0
    memory_layers: int = 2
    memory_hidden: int = 128
    edge_head_hidden: int = 200
    gumbel_temperature: float = 1.0
    correction_hidden: tuple[int, ...] = (512, 512)
    log_std_bounds: tuple[float, float] = (-5.0, 2.0)
    correction_init_log_std: float = -1.0
    delta_max: tuple[float, float, float] = (0.5, 0.5, 0.25)
    critic_hidden: int = 128
    critic_layers: int = 5
    critic_projection: int = 512
    critic_mlp: tuple[int, ...] = (512, 256)
    base_features: bool = False


@dataclass(frozen=True)
class AlgorithmConfig:
    """GA-SAC hyper-parameters (paper §IV-A) and the entropy / gate choices the paper leaves open.

    Attributes:
        gamma: discount (paper 0.99).
        buffer_size: replay capacity in transitions (paper 30,000).
        batch_size: minibatch (paper 64).
        warmup_frames: environment frames collected before the first update (paper 10,000).
        actor_lr / critic_lr / alpha_lr: Adam learning rates (paper: 3e-4 actors, 3e-5 critic).
        tau: soft target update rate, applied after every optimisation step (paper 1e-3).
        updates_per_batch: optimisation steps per collected batch.
        init_alpha_edge / init_alpha_delta: initial temperatures of the two heads.
        edge_entropy_ratio: target entropy of the edge head = ratio · log(#selectable edges),
            a per-state fraction of the uniform distribution's entropy (discrete-SAC convention).
        delta_target_entropy: target entropy of the correction head, measured on δ/Δmax
            ∈ (−1, 1)³; −3 = −dim(δ), the SAC heuristic.
        gate_l1: weight of the L1 penalty on the actor's gates z, applied to their mean over
            real edges and layers (paper: unspecified).
        reward_scale: SAC reward scale c: the critic's target uses c·r (agents.loss; paper: 1),
            so that the per-step reward is O(1) against the entropy bonus (docs/training.md).
        huber_delta: width of the critic's Huber loss on its TD error (scaled-reward units);
            None gives SAC's ½ δ² (paper: unspecified; agents.loss).
        critic_warmup_updates: updates in which only the critic and the temperatures learn
            (0 = SAC, the paper's; the supervised terms act from the first update).
        max_grad_norm: gradient clipping of every optimiser step.
        bc_weight, gate_weight: weights of the supervised terms (agents.loss "loss_bc", the
            expert's labels; "loss_gate", the injected outliers; 0 = none, the paper's).
        reward: the training environment's L (envs.core): "localisation" (the paper's, ground
            truth) or "F" (the local objective, what the robot observes).
        auto_reward_scale, auto_delta_entropy: c (agents.reward_scale) and the correction's
            target entropy set from the warm-up instead of reward_scale, delta_target_entropy.
        anchor_weight, anchor_updates: λ₀ of a KL term toward the start policy and the actor
            updates over which it decays to 0 (0 = none; 0 updates: held constant).
        terminal_bonus: the terminal log-ratio bonus (envs.core; the paper's; no state shows
            the episode's start it depends on).
        critic_patience: > 0: the actor starts once the critic's held-out TD error stopped
            falling for this many checks (every 16 updates); 0: after critic_warmup_updates.

    The options beyond the paper in detail: docs/training.md ("The options beyond the paper").
    """

    gamma: float = 0.99
    buffer_size: int = 30_000
    batch_size: int = 64
    warmup_frames: int = 10_000
    actor_lr: float = 3e-4
    critic_lr: float = 3e-5
    alpha_lr: float = 3e-4
    tau: float = 1e-3
    updates_per_batch: int = 1
    init_alpha_edge: float = 0.1
    init_alpha_delta: float = 0.1
    edge_entropy_ratio: float = 0.5
    delta_target_entropy: float = -3.0
    gate_l1: float = 1e-3
    reward_scale: float = 100.0
    huber_delta: float | None = 1.0
    critic_warmup_updates: int = 0
    max_grad_norm: float = 10.0
    bc_weight: float = 0.0
    gate_weight: float = 0.0
    reward: str = "localisation"
    auto_reward_scale: bool = False
    auto_delta_entropy: bool = False
    anchor_weight: float = 0.0
    anchor_updates: int = 1_000
    terminal_bonus: bool = True
    critic_patience: int = 0


@dataclass(frozen=True)
class ExperimentConfig:
    """What to train on and how long; where to write.

    Attributes:
        noise: training environment "V1", "V2" or "V3" (paper §IV-A; the main table uses V2).
        robots: team size n (the critic is built for this n).
        poses_per_robot: synthetic poses per robot (paper 60).
        num_envs: environments batched in one TorchRL env.
        seed: seeds the environment, torch and the replay sampler.
        frames: total environment frames (one frame = one batched env step of one env).
        frames_per_batch: frames per collector batch.
        device: "cpu" or "cuda".
        checkpoint_interval: frames between checkpoints.
        eval_interval: frames between held-out evaluations (F reduction).
        eval_problems: number of held-out synthetic problems.
        out_dir: run directory (checkpoints, CSV, PNG).
        progress: show a progress bar.
        outlier_rate_max: training problems get injected outliers (popbench.outliers, the
            loop-closure candidates) at a rate drawn per problem from U(0, outlier_rate_max);
            0 = clean problems (envs.make_problem_source). The held-out evaluation during
            training stays clean.
        start_noise: > 0: the synthetic problems start off their odometry, each measurement of
            the composition perturbed by that many standard deviations (envs.make_problem_source;
            the sanity task of tests/test_learning_checks.py); 0: the odometry start.
        init_actor: an actor checkpoint (.pt, e.g. a committed imitation actor) that GA-SAC
            starts from instead of the imitation phase; its model and task must be the run's.
            None: the imitation phase (when the preset has one) or a fresh actor.
    """

    noise: str = "V2"
    robots: int = 7
    poses_per_robot: int = 60
    num_envs: int = 32
    seed: int = 0
    frames: int = 1_000_000
    frames_per_batch: int = 1_024
    device: str = "cpu"
    checkpoint_interval: int = 50_000
    eval_interval: int = 50_000
    eval_problems: int = 8
    out_dir: str = "runs/ga-sac"
    progress: bool = True
    outlier_rate_max: float = 0.0
    start_noise: float = 0.0
    init_actor: str | None = None


@dataclass(frozen=True)
class ImitationConfig:
    """The imitation phase before GA-SAC (our addition, docs/training.md): DAgger-style
    behaviour cloning of the expert (envs.expert.Expert) on states the learner visits.

    Attributes:
        episodes: batched episodes (each of `num_envs` problems) of the phase; 0 skips it.
        num_envs: problems per batched episode.
        lr: Adam learning rate of the actor.
        beta_start, beta_decay: probability that an agent executes the expert's action instead
            of the learner's, β_k = beta_start · beta_decay^k in episode k (DAgger's mixture; the
            learner's own states dominate once β is small).
        delta_weight: weight of the correction loss against the edge loss.
        seconds: optional wall-clock cap of the phase [s].
        gate_weight: weight of the supervised gate loss against the injected outlier labels
            (agents.loss_terms; 0 = none; beyond the paper).
    """

    episodes: int = 0
    num_envs: int = 16
    lr: float = 1e-3
    beta_start: float = 1.0
    beta_decay: float = 0.9
    delta_weight: float = 1.0
    seconds: float | None = None
    gate_weight: float = 0.0


@dataclass(frozen=True)
class OutlierGateConfig:
    """Fitting the outlier gate of a trained actor (agents.gate_training, ``popbench
    train-gate``; beyond the paper, docs/outliers.md).

    Attributes:
        problems: training problems (synthetic, the actor's noise level and team size), each
            one reconciled state after the actor's episode and the consensus.
        validation: further problems, for the choice of the epoch (the best validation ROC AUC).
        epochs: passes over the training states (one problem per Adam step).
        lr: Adam learning rate.
        outlier_rate_max: each problem's outlier rate is drawn from U(0, outlier_rate_max).
        gate_l1: weight of the gates' L1 penalty beside the supervised gate loss (weight 1).
        consensus: the consensus the states are reconciled with (popbench.consensus.reconcile; None:
            its default, the one prop-v1 runs).
        seed: seed of the problem streams and the shuffling.
    """

    problems: int = 160
    validation: int = 16
    epochs: int = 10
    lr: float = 1e-3
    outlier_rate_max: float = 0.2
    gate_l1: float = 1e-5
    consensus: str | None = None
    seed: int = 0


ALGORITHMS = ("ga-sac", "mappo", "ippo")  # TrainConfig.algorithm_name


@dataclass(frozen=True)
class PPOConfig:
    """MAPPO / IPPO hyper-parameters (agents.ppo; docs/algorithms.md gives the reasons).

    Attributes:
        gamma: discount of the GAE and of the value targets.
        lmbda: GAE's λ (torchrl.objectives.value.GAE).
        clip_epsilon: PPO's ratio clip ε.
        epochs: passes over each collected batch.
        minibatch_size: transitions (joint steps of the n robots) per optimisation step.
        lr: Adam learning rate of the actor and the value function (one optimiser).
        entropy_coeff: weight of the entropy bonus (edge entropy + correction entropy).
        critic_coeff: weight of the value loss.
        max_grad_norm: gradient clipping of every optimiser step.
        normalize_advantage: standardise the advantages of each collected batch (over its
            transitions and robots: one shared policy).
    """

    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    epochs: int = 4
    minibatch_size: int = 64
    lr: float = 3e-4
    entropy_coeff: float = 1e-3
    critic_coeff: float = 1.0
    max_grad_norm: float = 10.0
    normalize_advantage: bool = True


@dataclass(frozen=True)
class TrainConfig:
    """The parts together (what `popbench train` builds and `agents.trainer.train` reads).

    `algorithm_name` selects the learner (ALGORITHMS): "ga-sac" reads `algorithm`, "mappo"
    (centralised value) and "ippo" (per-robot value) read `ppo`; both read the rest.
    """

    model: ModelConfig = field(default_factory=ModelConfig)
    algorithm: AlgorithmConfig = field(default_factory=AlgorithmConfig)
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    task: EnvModes = PAPER_MODES  # the environment's modes (envs.modes; a checkpoint without
    # a "task" entry reads as the paper's, which every checkpoint before the options was in)
    imitation: ImitationConfig = field(default_factory=ImitationConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    algorithm_name: str = "ga-sac"

    def __post_init__(self) -> None:
        if self.algorithm_name not in ALGORITHMS:
            raise ValueError(f"algorithm_name {self.algorithm_name!r} is not one of {ALGORITHMS}")

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (JSON-serialisable) for checkpoints."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """Inverse of `to_dict`; unknown keys raise TypeError, tuples are restored."""
        return cls(
            model=_build(ModelConfig, data.get("model", {})),
            algorithm=_build(AlgorithmConfig, data.get("algorithm", {})),
            experiment=_build(ExperimentConfig, data.get("experiment", {})),
            task=_build(EnvModes, data.get("task", {})),
            imitation=_build(ImitationConfig, data.get("imitation", {})),
            ppo=_build(PPOConfig, data.get("ppo", {})),
            algorithm_name=data.get("algorithm_name", "ga-sac"),
        )


def with_task(config: TrainConfig, task: Task) -> TrainConfig:
    """``config`` training on the benchmark ``task`` (envs.tasks): its modes, its reward and
    terminal bonus (reward None: the localisation reward of the synthetic problems), its robots,
    noise level, map size and training outliers; the networks and budgets stay ``config``'s."""
    return dataclasses.replace(
        config,
        task=task.modes,
        algorithm=dataclasses.replace(
            config.algorithm,
            reward=task.reward or "localisation",
            terminal_bonus=task.terminal_bonus,
        ),
        experiment=dataclasses.replace(
            config.experiment,
            robots=task.robots,
            noise=task.noise,
            poses_per_robot=task.poses_per_robot,
            outlier_rate_max=task.outlier_rate_max,
        ),
    )


def with_overrides(config: TrainConfig, settings: list[str]) -> TrainConfig:
    """``config`` with ``PART.FIELD=VALUE`` settings applied (``popbench train --set``), e.g.
    ``algorithm.anchor_weight=0.1``, ``model.correction_hidden=64,64``,
    ``experiment.init_actor=none``. The value is read as the field's default's type (bool:
    true/false; a tuple: comma-separated; none: None where the field allows it); a one-line
    `ValueRangeError` names a setting that does not fit."""
    from popbench.errors import ValueRangeError

    parts = [f.name for f in fields(config) if dataclasses.is_dataclass(getattr(config, f.name))]
    for setting in settings:
        key, equals, text = setting.partition("=")
        part, dot, name = key.strip().partition(".")
        section = getattr(config, part, None) if part in parts else None
        known = {f.name: f for f in fields(section)} if section is not None else {}
        if not (equals and dot and name in known):
            allowed = "PART.FIELD=VALUE with PART one of " + ", ".join(parts)
            if section is not None:
                allowed = f"{part}.FIELD=VALUE with FIELD one of " + ", ".join(known)
            raise ValueRangeError("--set", setting, allowed)
        current = getattr(section, name)
        try:
            value = _parse_setting(text.strip(), current, str(known[name].type))
        except ValueError:
            kind = type(current).__name__ if current is not None else str(known[name].type)
            raise ValueRangeError("--set", setting, f"a value of type {kind}") from None
        section = dataclasses.replace(section, **{name: value})
        config = dataclasses.replace(config, **{part: section})
    return config


def _parse_setting(text: str, current: Any, annotation: str) -> Any:
    if text.lower() == "none" and (current is None or "None" in annotation):
        return None
    if isinstance(current, bool):
        if text.lower() not in ("true", "false"):
            raise ValueError(text)
        return text.lower() == "true"
    if isinstance(current, tuple):
        kind = type(current[0]) if current else float
        return tuple(kind(item) for item in text.split(","))
    if isinstance(current, int):
        return int(text)
    if isinstance(current, float) or "float" in annotation:
        return float(text)
    return text


def _build(kind: type, values: dict[str, Any]) -> Any:
    tuple_fields = {f.name for f in fields(kind) if str(f.type).startswith("tuple")}
    return kind(**{k: tuple(v) if k in tuple_fields else v for k, v in values.items()})


# CPU-feasible deviation from the paper (the committed checkpoints): widths ÷ ~4, a 3/2-layer
# GNN, minibatch 32, warm-up and buffer at the ~10–25k frames a CPU run collects, and the rates a
# run of ~10³ updates needs. Each value's reason and measurement: docs/training.md, "Why the CPU
# presets' values".
CPU_SMALL = TrainConfig(
    model=ModelConfig(
        hidden=32,
        layers=3,
        edge_hidden=4,
        gate_hidden=16,
        memory_hidden=32,
        edge_head_hidden=64,
        correction_hidden=(128, 128),
        critic_hidden=32,
        critic_layers=2,
        critic_projection=128,
        critic_mlp=(128, 64),
    ),
    algorithm=AlgorithmConfig(
        buffer_size=10_000,
        batch_size=32,
        warmup_frames=1_024,
        updates_per_batch=16,
        critic_lr=3e-4,
        tau=5e-3,
        alpha_lr=3e-3,
        gate_l1=1e-5,
        gamma=0.9,
        critic_warmup_updates=256,
    ),
    experiment=ExperimentConfig(
        num_envs=8,
        frames=24_000,
        frames_per_batch=128,
        checkpoint_interval=1_024,
        eval_interval=2_048,
    ),
)
# The cpu-imitation recipe (docs/training.md): the cpu-small networks in the
# trajectory-parameterised, scale-free environment with the Gauss–Newton base step, an imitation
# phase of the expert, then a short GA-SAC fine-tuning from the imitation actor. Budgets fixed
# before evaluation.
CPU_IMITATION = TrainConfig(
    model=CPU_SMALL.model,
    # 4,096 frames give 384 updates after the 1,024-frame warm-up; 128 of them critic-only
    algorithm=dataclasses.replace(CPU_SMALL.algorithm, critic_warmup_updates=128),
    experiment=dataclasses.replace(CPU_SMALL.experiment, frames=4_096),
    task=TRAJECTORY_MODES,
    imitation=ImitationConfig(episodes=100, num_envs=8, lr=1e-3, beta_decay=0.8),
)
# cpu-imitation on problems with injected outliers (docs/training.md): rates
# U(0, 0.2) per training problem, and the supervised gate loss in both phases (weight 1; beyond
# the paper). The same budgets as cpu-imitation; no behaviour-cloning term in GA-SAC (its pilot
# did not show that it helps, docs/training.md).
CPU_IMITATION_ROBUST = TrainConfig(
    model=CPU_IMITATION.model,
    algorithm=dataclasses.replace(CPU_IMITATION.algorithm, gate_weight=1.0),
    experiment=dataclasses.replace(CPU_IMITATION.experiment, outlier_rate_max=0.2),
    task=CPU_IMITATION.task,
    imitation=dataclasses.replace(CPU_IMITATION.imitation, gate_weight=1.0),
)
# The cpu-residual recipe: cpu-imitation (clean problems) with a correction head that reads the
# base step it corrects, then GA-SAC on the local F anchored to the imitation actor. Each choice
# and its measurement: docs/training.md, "Why the CPU presets' values".
CPU_RESIDUAL = dataclasses.replace(
    CPU_IMITATION,
    model=dataclasses.replace(CPU_IMITATION.model, base_features=True),
    imitation=dataclasses.replace(CPU_IMITATION.imitation, episodes=40),
    algorithm=dataclasses.replace(
        CPU_IMITATION.algorithm,
        reward="F",
        terminal_bonus=False,
        auto_reward_scale=True,
        huber_delta=None,
        auto_delta_entropy=True,
        anchor_weight=1.0,
        anchor_updates=0,
        critic_warmup_updates=256,
        critic_patience=4,
    ),
)
# MAPPO / IPPO in cpu-residual's setting (docs/algorithms.md): its networks, task,
# reward (the local F, no terminal bonus), experiment and imitation phase; γ = 0.9 as GA-SAC's
# cpu presets. `--imitation-episodes 0` starts from scratch.
CPU_PPO = dataclasses.replace(CPU_RESIDUAL, ppo=PPOConfig(gamma=CPU_RESIDUAL.algorithm.gamma))
PRESETS: dict[str, TrainConfig] = {
    "paper": TrainConfig(),
    "cpu-small": CPU_SMALL,
    "cpu-imitation": CPU_IMITATION,
    "cpu-imitation-robust": CPU_IMITATION_ROBUST,
    "cpu-residual": CPU_RESIDUAL,
    "cpu-mappo": dataclasses.replace(CPU_PPO, algorithm_name="mappo"),
    "cpu-ippo": dataclasses.replace(CPU_PPO, algorithm_name="ippo"),
}
