"""GA-SAC agents: encoder equations against hand-made references, actor/critic contracts, loss."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import tiny_model
from torch import Tensor
from torch.distributions import Normal, TanhTransform, TransformedDistribution

from agents.actor import GASACPolicy, HybridActor, tanh_gaussian_log_prob
from agents.config import AlgorithmConfig, ModelConfig, TrainConfig
from agents.critic import CentralCritic
from agents.encoder import (
    HARD_CONCRETE_STRETCH,
    AdaptiveEdgeGate,
    EdgeConditionedConv,
    GraphBatch,
    GraphEncoder,
    chosen_edge_embedding,
    edge_embeddings,
    symlog,
)

NODE_DIM, EDGE_DIM = 6, 11
SMALL = tiny_model()


def random_graphs(graphs: int, vertices: int = 7, edges: int = 9, seed: int = 0) -> GraphBatch:
    """Padded random graphs: the last two edge slots and the last vertex are padding."""
    gen = torch.Generator().manual_seed(seed)
    edge_index = torch.randint(0, vertices - 1, (graphs, 2, edges), generator=gen)
    edge_mask = torch.ones(graphs, edges, dtype=torch.bool)
    edge_mask[:, -2:] = False
    edge_index[:, :, -2:] = 0
    node_mask = torch.ones(graphs, vertices, dtype=torch.bool)
    node_mask[:, -1] = False
    processed = torch.zeros(graphs, edges, dtype=torch.bool)
    processed[:, 0] = True
    action_mask = torch.cat([edge_mask & ~processed, torch.zeros(graphs, 1, dtype=torch.bool)], 1)
    return GraphBatch(
        node_features=torch.randn(graphs, vertices, NODE_DIM, generator=gen) * node_mask[..., None],
        edge_index=edge_index,
        edge_attr=torch.randn(graphs, edges, EDGE_DIM, generator=gen) * edge_mask[..., None],
        edge_mask=edge_mask,
        node_mask=node_mask,
        residuals=torch.randn(graphs, edges, 3, generator=gen) * edge_mask[..., None],
        processed=processed,
        action_mask=action_mask,
    )


def make_encoder(**overrides) -> GraphEncoder:
    options = dict(
        node_dim=NODE_DIM,
        edge_dim=EDGE_DIM,
        hidden=8,
        layers=2,
        edge_hidden=4,
        activation="sigmoid",
        gate_hidden=8,
        gate_temperature=2 / 3,
        gate_inter_loop_bias=0.5,
        gate_init_logit=2.0,
    )
    options.update(overrides)
    return GraphEncoder(**options)


# ----- encoder ------------------------------------------------------------------------------


def test_ecc_layer_matches_explicit_per_edge_matrices() -> None:
    """eqs. ecc_weight–node_update with W_pq materialised from φ_edge and a Python loop."""
    torch.manual_seed(1)
    conv = EdgeConditionedConv(in_dim=5, out_dim=4, edge_dim=3, edge_hidden=6, activation="sigmoid")
    x = torch.randn(4, 5)
    edge_index = torch.tensor([[1, 2, 3, 0], [0, 0, 1, 2]])  # (source q, target p)
    attr = torch.randn(4, 3)
    # φ_edge as a full MLP: its last linear layer maps [1, hidden] to vec(W) (d_out × d_in).
    bases = conv.bases.weight.view(conv.num_bases, 4, 5)
    hidden = conv.edge_net(attr)
    coefficients = torch.cat([torch.ones(4, 1), hidden], 1)
    weights = torch.einsum("mk,koi->moi", coefficients, bases)  # [M, d_out, d_in]
    expected_messages = torch.stack([weights[m] @ x[edge_index[0, m]] for m in range(4)])
    messages = conv.messages(x, edge_index, attr)
    torch.testing.assert_close(messages, expected_messages)

    degree = torch.tensor([2.0, 1.0, 1.0, 1.0])  # clamp(min=1) for the isolated vertex 3
    out = conv(x, edge_index, messages, degree)
    for p in range(4):
        incoming = [m for m in range(4) if edge_index[1, m] == p]
        mean = sum((expected_messages[m] for m in incoming), torch.zeros(4)) / max(len(incoming), 1)
        expected = torch.sigmoid(conv.update_net(torch.cat([x[p], mean])))
        torch.testing.assert_close(out[p], expected)


def test_hard_concrete_gate_matches_its_distribution() -> None:
    """z has point masses P(z=0) = σ(τ·logit(−a/(b−a)) − α), P(z=1) = σ(α − τ·logit(...))."""
    gate = AdaptiveEdgeGate(
        message_dim=2, hidden=4, temperature=2 / 3, inter_loop_bias=0.0, init_logit=0.0
    )
    alpha = torch.full((200_000,), 0.7)
    gate.logits = lambda *args: alpha  # isolate eqs. bernoulli/minmax from P_gate
    z = gate(None, None, None, None, deterministic=False)
    a, b = HARD_CONCRETE_STRETCH
    tau = 2 / 3

    def logit(p: float) -> float:
        return math.log(p / (1 - p))

    p_zero = torch.sigmoid(torch.tensor(tau * logit(-a / (b - a)) - 0.7)).item()
    p_one = torch.sigmoid(torch.tensor(0.7 - tau * logit((1 - a) / (b - a)))).item()
    assert (z == 0).float().mean().item() == pytest.approx(p_zero, abs=0.005)
    assert (z == 1).float().mean().item() == pytest.approx(p_one, abs=0.005)
    assert bool(((z >= 0) & (z <= 1)).all())
    z_eval = gate(None, None, None, None, deterministic=True)
    expected = min(1.0, max(0.0, (b - a) * torch.sigmoid(torch.tensor(0.7 / tau)).item() + a))
    torch.testing.assert_close(z_eval, torch.full_like(z_eval, expected))


def test_gate_bias_favours_inter_robot_loop_closures() -> None:
    gate = AdaptiveEdgeGate(
        message_dim=2, hidden=4, temperature=0.5, inter_loop_bias=1.5, init_logit=0.0
    )
    messages, residuals, info = torch.zeros(2, 2), torch.zeros(2, 3), torch.zeros(2, 3)
    logits = gate.logits(messages, residuals, info, torch.tensor([0.0, 1.0]))
    assert (logits[1] - logits[0]).item() == pytest.approx(1.5)


def test_closed_gates_silence_messages() -> None:
    """With every gate at z = 0 a node update sees only its own embedding (eq. mask)."""
    torch.manual_seed(0)
    encoder = make_encoder(gate_init_logit=-1e4, layers=1)
    graphs = random_graphs(2)
    encoding = encoder(graphs, deterministic=True)
    assert float(encoding.gates.detach().abs().max()) == 0.0
    conv = encoder.convs[0]
    x = graphs.node_features
    expected = torch.sigmoid(conv.update_net(torch.cat([x, torch.zeros(2, 7, 8)], -1)))
    real = graphs.node_mask.unsqueeze(-1)
    torch.testing.assert_close(encoding.nodes, expected * real)  # padding rows are 0
    assert not bool(encoding.inliers().any())


def test_encoder_is_invariant_to_padding_and_batching() -> None:
    torch.manual_seed(0)
    encoder = make_encoder()
    graphs = random_graphs(3)
    together = encoder(graphs, deterministic=True)
    for g in range(3):
        alone = encoder(
            GraphBatch(
                **{
                    f: None if value is None else value[g : g + 1]
                    for f, value in vars(graphs).items()
                }
            ),
            deterministic=True,
        )
        torch.testing.assert_close(alone.pooled, together.pooled[g : g + 1])
    # Garbage in padding slots must not leak into real outputs.
    noisy = random_graphs(3)
    noisy.edge_attr[:, -2:] = 100.0
    noisy.edge_index[:, :, -2:] = 3
    noisy.residuals[:, -2:] = 50.0
    noisy.node_features[:, -1] = 7.0
    out = encoder(noisy, deterministic=True)
    real = graphs.node_mask
    torch.testing.assert_close(out.nodes[real], together.nodes[real])
    torch.testing.assert_close(out.pooled, together.pooled)
    assert float(out.gates[:, :, -2:].abs().max()) == 0.0


# ----- actor ----------------------------------------------------------------------------------


def test_tanh_gaussian_log_prob_matches_torch_distributions() -> None:
    # float64 and a fixed seed: in float32 the tanh → atanh round trip of the reference loses
    # ~1e-4 for |pre| ≳ 4 (0.7 % of unseeded draws failed).
    generator = torch.Generator().manual_seed(0)
    mean = torch.randn(5, 3, generator=generator, dtype=torch.float64)
    log_std = 0.3 * torch.randn(5, 3, generator=generator, dtype=torch.float64)
    pre = mean + log_std.exp() * torch.randn(5, 3, generator=generator, dtype=torch.float64)
    reference = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()])
    expected = reference.log_prob(torch.tanh(pre)).sum(-1)
    torch.testing.assert_close(
        tanh_gaussian_log_prob(pre, mean, log_std), expected, rtol=1e-4, atol=1e-4
    )


def test_actor_respects_mask_bounds_and_entropy() -> None:
    torch.manual_seed(0)
    actor = HybridActor(NODE_DIM, EDGE_DIM, SMALL)
    graphs = random_graphs(64)
    graphs.action_mask[:5] = False
    graphs.action_mask[:5, -1] = True  # nothing left: only the no-op
    choices = graphs.action_mask.shape[-1]
    out = actor(
        graphs,
        actor.initial_memory(64),
        torch.zeros(64, choices),
        torch.zeros(64, 3),
        deterministic=False,
    )
    assert bool(graphs.action_mask.gather(1, out.edge[:, None]).all())
    assert bool((out.edge[:5] == choices - 1).all())
    assert bool((out.delta.abs() <= actor.delta_max).all())
    probs = out.edge_log_probs.exp()
    torch.testing.assert_close(probs.sum(-1), torch.ones(64))
    log_p = torch.where(probs > 0, out.edge_log_probs, torch.zeros_like(probs))
    torch.testing.assert_close(out.edge_entropy, -(probs * log_p).sum(-1))
    assert float(out.edge_entropy[:5].abs().max()) == 0.0
    torch.testing.assert_close(
        out.edge_weights.detach(), torch.nn.functional.one_hot(out.edge, choices).float()
    )
    assert out.memory.shape == (64, SMALL.memory_layers, SMALL.memory_hidden)

    det = actor(
        graphs,
        actor.initial_memory(64),
        torch.zeros(64, choices),
        torch.zeros(64, 3),
        deterministic=True,
    )
    torch.testing.assert_close(det.edge, det.edge_log_probs.argmax(-1))


def test_straight_through_edge_choice_carries_gradient_to_logits() -> None:
    torch.manual_seed(0)
    actor = HybridActor(NODE_DIM, EDGE_DIM, SMALL)
    graphs = random_graphs(4)
    choices = graphs.action_mask.shape[-1]
    out = actor(
        graphs,
        actor.initial_memory(4),
        torch.zeros(4, choices),
        torch.zeros(4, 3),
        deterministic=False,
    )
    (out.edge_weights * torch.arange(choices, dtype=torch.float32)).sum().backward()
    assert actor.edge_head[0].weight.grad.abs().sum() > 0


# ----- critic ---------------------------------------------------------------------------------


def test_critic_shapes_and_action_sensitivity() -> None:
    torch.manual_seed(0)
    critic = CentralCritic(NODE_DIM, EDGE_DIM, agents=3, config=SMALL)
    graphs = random_graphs(2 * 3)
    choices = graphs.action_mask.shape[-1]
    edges = torch.nn.functional.one_hot(torch.tensor([1, 2, 3, 4, 5, 6]), choices).float()
    q, _ = critic(graphs, edges, torch.zeros(6, 3), deterministic=True)
    assert q.shape == (2, 3, 2)
    q_other, _ = critic(graphs, edges, torch.full((6, 3), 0.1), deterministic=True)
    assert not torch.allclose(q, q_other)


def test_actor_loss_moves_each_correction_by_its_own_q_only() -> None:
    """own_action_only: same Q values; ∂Q_i/∂δ_j vanishes for j ≠ i and not for j = i (without
    it the cross terms are live: Q_i reads every agent's action through the joint input)."""
    torch.manual_seed(0)
    critic = CentralCritic(NODE_DIM, EDGE_DIM, agents=3, config=SMALL)
    graphs = random_graphs(2 * 3)
    choices = graphs.action_mask.shape[-1]
    edges = torch.nn.functional.one_hot(torch.tensor([1, 2, 3, 4, 5, 6]), choices).float()
    delta = (0.1 * torch.randn(6, 3)).requires_grad_(True)

    def jacobian(own_action_only: bool) -> tuple[Tensor, Tensor]:
        q, _ = critic(graphs, edges, delta, deterministic=True, own_action_only=own_action_only)
        rows = [
            torch.autograd.grad(q[:, i, 0].sum(), delta, retain_graph=True)[0].view(2, 3, 3)
            for i in range(3)
        ]
        return q.detach(), torch.stack(rows, 1)  # [B, i, j, 3]: ∂Q_i / ∂δ_j

    q_own, own = jacobian(True)
    q_all, live = jacobian(False)
    torch.testing.assert_close(q_own, q_all)
    diagonal = torch.eye(3, dtype=torch.bool)[None, :, :, None].expand_as(own)
    assert float(own[~diagonal].abs().max()) == 0.0
    assert float(own[diagonal].abs().min()) > 0.0
    assert float(live[~diagonal].abs().max()) > 0.0
    torch.testing.assert_close(own[diagonal], live[diagonal])


def test_edge_embeddings_carry_the_edge_residual_in_the_tail_frame() -> None:
    graphs = random_graphs(3)
    nodes = torch.randn(3, 7, 5)
    rows = edge_embeddings(nodes, graphs)
    assert rows.shape == (3, 9 + 1, 2 * 5 + EDGE_DIM + 3)
    torch.testing.assert_close(rows[:, :-1, -3:], symlog(graphs.residuals))
    assert float(rows[:, -1].abs().sum()) == 0.0  # the no-op row


def test_correction_sees_the_chosen_edge_residual() -> None:
    torch.manual_seed(0)
    actor = HybridActor(NODE_DIM, EDGE_DIM, SMALL)
    graphs = random_graphs(4)
    state = actor.initial_memory(4), torch.zeros(4, 10), torch.zeros(4, 3)
    out = actor(graphs, *state, deterministic=True)
    # Untrained, the deterministic correction is the no-op whatever the input.
    assert float(out.delta.abs().max()) == 0.0
    torch.nn.init.normal_(actor.correction_head[-1].weight, std=0.5)  # as if trained
    chosen = out.edge.unsqueeze(-1)
    # Change only the chosen edges' residuals and freeze the gates (their input changes too).
    for gate in actor.encoder.gates:
        gate.forward = lambda *args: torch.ones_like(args[3])
    before = actor(graphs, *state, deterministic=True)
    graphs.residuals = graphs.residuals.scatter_add(
        1, chosen.unsqueeze(-1).expand(-1, -1, 3), torch.ones(4, 1, 3)
    )
    torch.manual_seed(0)
    after = actor(graphs, *state, deterministic=True)
    torch.testing.assert_close(before.encoding.nodes, after.encoding.nodes)
    assert not torch.allclose(before.delta, after.delta)


def test_critic_features_post_correction_residual_and_progress() -> None:
    from agents.critic import corrected_residual, progress

    graphs = random_graphs(2)
    weights = torch.nn.functional.one_hot(torch.tensor([3, 9]), 10).float()  # 9 = the no-op
    delta = torch.tensor([[0.1, -0.2, 3.0], [0.5, 0.5, 0.5]])
    after = corrected_residual(graphs.residuals, weights, delta)
    # not wrapped: in the whitened units an angle of π is no half-turn
    torch.testing.assert_close(after[0], graphs.residuals[0, 3] + delta[0])
    torch.testing.assert_close(after[1], delta[1])  # the no-op row has no residual
    # 7 real edges, one processed; 6 selectable choices.
    torch.testing.assert_close(
        progress(graphs), torch.tensor([[6 / 7, math.log(7.0)], [6 / 7, math.log(7.0)]])
    )


# ----- config ---------------------------------------------------------------------------------


def test_config_round_trip_and_paper_defaults() -> None:
    config = TrainConfig(model=SMALL)
    assert TrainConfig.from_dict(config.to_dict()) == config
    algorithm = AlgorithmConfig()
    assert (algorithm.gamma, algorithm.buffer_size, algorithm.batch_size) == (0.99, 30_000, 64)
    assert (algorithm.actor_lr, algorithm.critic_lr, algorithm.tau) == (3e-4, 3e-5, 1e-3)
    assert (ModelConfig().hidden, ModelConfig().layers, ModelConfig().edge_head_hidden) == (
        128,
        5,
        200,
    )


# ----- policy in the environment + loss ---------------------------------------------------------


@pytest.fixture(scope="module")
def transitions():
    """A short rollout of the small policy in a 3-robot synthetic env (10 poses per robot)."""
    from torchrl.envs import TransformedEnv

    from envs import make_torchrl_env

    torch.manual_seed(0)
    env = make_torchrl_env(robots=3, batch_size=4, noise="V2", seed=0, poses_per_robot=10)
    actor = HybridActor(NODE_DIM, EDGE_DIM, SMALL)
    policy = GASACPolicy(actor)
    env = TransformedEnv(env, policy.primer(3, env.dims.edges + 1))
    rollout = env.rollout(30, policy, break_when_any_done=False)
    return actor, rollout


def test_policy_rollout_valid_actions_and_memory_resets(transitions) -> None:
    _, rollout = transitions
    # The env raises on an invalid edge, so a full rollout already proves masking; check resets.
    done = rollout["next", "done"][..., 0]
    env_index, step = done[:, :-1].nonzero(as_tuple=True)
    assert env_index.numel() > 0
    after = rollout["agents", "prev_edge"][env_index, step + 1]
    assert float(after.abs().sum()) == 0.0
    assert float(rollout["agents", "memory"][env_index, step + 1].abs().sum()) == 0.0
    torch.testing.assert_close(
        rollout["agents", "memory"][:, 1:],
        rollout["next", "agents", "memory"][:, :-1] * ~done[:, :-1, None, None, None],
    )


def make_loss(actor, **overrides):
    from torchrl.objectives import SoftUpdate

    from agents.loss import GASACLoss

    critic = CentralCritic(NODE_DIM, EDGE_DIM, agents=3, config=SMALL)
    loss = GASACLoss(actor, critic, AlgorithmConfig(**overrides))
    return loss, SoftUpdate(loss, tau=0.5)


def test_loss_shapes_and_gradients_reach_every_group(transitions) -> None:
    actor, rollout = transitions
    loss, _ = make_loss(actor)
    batch = rollout.reshape(-1)[:12]
    out = loss(batch)
    for key in ("loss_actor", "loss_qvalue", "loss_alpha_edge", "loss_alpha_delta"):
        assert out[key].shape == () and torch.isfinite(out[key])
    loss.zero_grad()
    sum(out[k] for k in out.keys() if k.startswith("loss_")).backward()
    groups = {
        "actor": loss.actor_parameters(),
        "critic": loss.critic_parameters(),
        "alpha": loss.alpha_parameters(),
    }
    for name, params in groups.items():
        grads = [p.grad for p in params]
        assert all(g is not None and torch.isfinite(g).all() for g in grads), name
        assert sum(float(g.abs().sum()) for g in grads) > 0, name
    # Every actor sub-network (encoder, gates, memory, both heads) receives gradient.
    for module in ("encoder.convs", "encoder.gates", "memory", "edge_head", "correction_head"):
        assert any(
            float(p.grad.abs().sum()) > 0
            for n, p in actor.named_parameters()
            if n.startswith(module)
        ), module
    # The actor loss must not train the critic, nor the critic loss the actor.
    loss.zero_grad()
    out = loss(batch)
    out["loss_actor"].backward()
    assert all(p.grad is None or float(p.grad.abs().sum()) == 0 for p in loss.critic_parameters())


def test_reward_scale_scales_the_reward_in_the_critic_target(transitions) -> None:
    """c·r under scale c gives the same critic loss as reward c·r under scale 1, not as r."""
    actor, rollout = transitions
    batch = rollout.reshape(-1)[:12].clone()
    reward = batch["next", "agents", "reward"].clone() + 0.05
    losses = []
    for scale, stored in ((3.0, reward), (1.0, 3.0 * reward), (1.0, reward)):
        batch["next", "agents", "reward"] = stored
        torch.manual_seed(0)
        loss, _ = make_loss(actor, reward_scale=scale)
        torch.manual_seed(1)
        losses.append(loss(batch)["loss_qvalue"])
    torch.testing.assert_close(losses[0], losses[1])
    assert not torch.allclose(losses[0], losses[2])


def test_critic_loss_has_no_gate_penalty(transitions) -> None:
    actor, rollout = transitions
    batch = rollout.reshape(-1)[:12]
    torch.manual_seed(0)
    with_penalty, _ = make_loss(actor, gate_l1=10.0)
    torch.manual_seed(0)
    without, _ = make_loss(actor, gate_l1=0.0)
    without.load_state_dict(with_penalty.state_dict())
    torch.manual_seed(1)
    first = with_penalty(batch)
    torch.manual_seed(1)
    second = without(batch)
    torch.testing.assert_close(first["loss_qvalue"], second["loss_qvalue"])
    assert float(first["loss_actor"] - second["loss_actor"]) > 0  # the actor's gates pay it


def test_target_network_moves_only_with_soft_update(transitions) -> None:
    actor, rollout = transitions
    loss, updater = make_loss(actor)
    target_before = loss.target_critic_network_params.clone()
    optimiser = torch.optim.SGD(loss.critic_parameters(), lr=0.1)
    loss(rollout.reshape(-1)[:16])["loss_qvalue"].backward()
    optimiser.step()
    assert (loss.target_critic_network_params == target_before).all()
    source = loss.critic_network_params.detach().clone()
    assert not (source == target_before).all()
    updater.step()
    expected = target_before.apply(lambda t, s: t + 0.5 * (s - t), source)
    torch.testing.assert_close(loss.target_critic_network_params.to_dict(), expected.to_dict())


@pytest.mark.parametrize(
    ("overrides", "edge_sign", "delta_sign"),
    [
        (dict(edge_entropy_ratio=1.0, delta_target_entropy=50.0), 1, 1),  # targets above
        (dict(edge_entropy_ratio=0.0, delta_target_entropy=-50.0), -1, -1),  # targets below
    ],
)
def test_temperatures_move_toward_their_targets(transitions, overrides, edge_sign, delta_sign):
    actor, rollout = transitions
    loss, _ = make_loss(actor, **overrides)
    optimiser = torch.optim.Adam(loss.alpha_parameters(), lr=0.05)
    start = (loss.log_alpha_edge.item(), loss.log_alpha_delta.item())
    for _ in range(3):
        out = loss(rollout.reshape(-1)[:8])
        optimiser.zero_grad()
        (out["loss_alpha_edge"] + out["loss_alpha_delta"]).backward()
        optimiser.step()
    assert edge_sign * (loss.log_alpha_edge.item() - start[0]) > 0.1
    assert delta_sign * (loss.log_alpha_delta.item() - start[1]) > 0.1


# ----- trainer / checkpoints --------------------------------------------------------------------


def test_tiny_training_run_checkpoints_and_resumes(tmp_path) -> None:
    import csv

    from agents.checkpoint import CheckpointError, load_actor, read_checkpoint
    from agents.config import ExperimentConfig
    from agents.trainer import train

    def config(frames: int) -> TrainConfig:
        return TrainConfig(
            model=SMALL,
            algorithm=AlgorithmConfig(warmup_frames=32, batch_size=8, buffer_size=256),
            experiment=ExperimentConfig(
                robots=3,
                poses_per_robot=10,
                num_envs=4,
                frames=frames,
                frames_per_batch=32,
                checkpoint_interval=32,
                eval_interval=64,
                eval_problems=2,
                out_dir=str(tmp_path),
                progress=False,
            ),
        )

    train(config(64), resume=False)
    first = read_checkpoint(tmp_path / "checkpoint.pt")
    assert (first["frames"], first["updates"]) == (64, 2)
    train(config(96), resume=True)
    second = read_checkpoint(tmp_path / "checkpoint.pt")
    assert (second["frames"], second["updates"]) == (96, 3)
    with (tmp_path / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["frames"]) for r in rows] == [32, 64, 96]
    assert [int(r["updates"]) for r in rows] == [1, 2, 3]
    assert math.isfinite(float(rows[1]["eval_f_reduction"]))
    assert math.isfinite(float(rows[2]["loss_qvalue"]))
    assert (tmp_path / "learning_curve.png").stat().st_size > 0

    actor, loaded = load_actor(tmp_path / "checkpoint.pt")
    assert loaded.model.hidden == SMALL.hidden and not actor.training
    torch.testing.assert_close(
        actor.state_dict()["edge_head.0.weight"], second["actor"]["edge_head.0.weight"]
    )
    (tmp_path / "broken.pt").write_text("not a checkpoint")
    with pytest.raises(CheckpointError, match="broken.pt"):
        load_actor(tmp_path / "broken.pt")


def test_critic_warmup_leaves_the_actor_unchanged(transitions) -> None:
    from agents.config import ExperimentConfig
    from agents.gasac_trainer import optimise
    from agents.session import build_session

    experiment = ExperimentConfig(robots=3, poses_per_robot=10, num_envs=4, progress=False)
    for warmup, actor_moves in ((5, False), (0, True)):
        algorithm = AlgorithmConfig(critic_warmup_updates=warmup)
        session = build_session(
            TrainConfig(model=SMALL, algorithm=algorithm, experiment=experiment)
        )
        _, rollout = transitions
        actor_before = {k: v.clone() for k, v in session.actor.state_dict().items()}
        critic_before = session.loss.critic_network_params.clone()
        optimise(session, rollout.reshape(-1)[:8])
        moved = any(
            not torch.equal(actor_before[k], v) for k, v in session.actor.state_dict().items()
        )
        assert moved == actor_moves
        assert not (session.loss.critic_network_params == critic_before).all()


# ----- the fast training path against the dense computation it replaced ----------------------


def dense_encoding(encoder: GraphEncoder, graphs: GraphBatch) -> tuple[Tensor, Tensor]:
    """(nodes [G, V, d], gates [L, G, E]) computed the direct way: every padded edge slot, each
    message as mix_bases of the per-node basis products B_k h (the incremental path's form),
    padding masked out by its zero weight (deterministic gates)."""
    from agents.encoder import INTER_LOOP_COLUMN, LOG_INFO_COLUMNS, mix_bases

    count, vertices, _ = graphs.node_features.shape
    edges = graphs.edge_index.shape[-1]
    offsets = torch.arange(count).view(-1, 1) * vertices
    local = graphs.edge_index.clamp(0, vertices - 1)
    tails, heads = (local[:, 0] + offsets).reshape(-1), (local[:, 1] + offsets).reshape(-1)
    attr = graphs.edge_attr.reshape(count * edges, -1)
    valid = graphs.edge_mask.reshape(-1).float()
    degree = torch.zeros(count * vertices).index_add(0, tails, valid).index_add(0, heads, valid)
    h = graphs.node_features.reshape(count * vertices, -1)
    gates = []
    for conv, gate in zip(encoder.convs, encoder.gates, strict=True):
        products = conv.bases(h)
        coefficients = [
            torch.cat(
                [torch.ones_like(attr[:, :1]), conv.edge_net(torch.cat([attr, flag], -1))], -1
            )
            for flag in (torch.zeros_like(attr[:, :1]), torch.ones_like(attr[:, :1]))
        ]
        forward = mix_bases(coefficients[0], products[heads], conv.out_dim)  # to the tail
        reverse = mix_bases(coefficients[1], products[tails], conv.out_dim)  # to the head
        z = gate(
            0.5 * (forward + reverse),
            graphs.residuals.reshape(-1, 3),
            attr[:, LOG_INFO_COLUMNS],
            attr[:, INTER_LOOP_COLUMN],
            deterministic=True,
        )
        z = z * valid
        summed = torch.zeros(count * vertices, conv.out_dim)
        summed = summed.index_add(0, tails, z[:, None] * forward)
        summed = summed.index_add(0, heads, z[:, None] * reverse)
        mean = summed / degree.clamp(min=1.0)[:, None]
        h = conv.activation(conv.update_net(torch.cat([h, mean], -1)))
        gates.append(z.view(count, edges))
    return h.view(count, vertices, -1), torch.stack(gates)


def test_the_packed_encoder_and_split_edge_head_equal_the_dense_computation() -> None:
    """A committed actor on a real observation (two problems of seven robots, mid-episode, so
    that processed edges are masked): the training path's nodes, gates and log π(e | s) equal
    the dense computation's to float32 round-off, and so do their arg-max edges."""
    from pathlib import Path

    import envs
    from agents.actor import masked_log_softmax
    from agents.checkpoint import load_actor

    root = Path(__file__).resolve().parents[1]
    actor, config = load_actor(root / "agents/checkpoints/actor-V2-n7-residual.pt")
    env = envs.make_torchrl_env(task="actors", batch_size=2, seed=11)
    tensordict = env.rand_step(env.reset())["next"]
    tensordict = env.rand_step(tensordict)["next"]
    mask = tensordict["agents", "action_mask"]
    graphs = GraphBatch.from_observation(tensordict["agents", "observation"], mask)
    with torch.no_grad():
        encoding = actor.encoder(graphs, deterministic=True)
        nodes, gates = dense_encoding(actor.encoder, graphs)
        real = graphs.node_mask.unsqueeze(-1)  # the packed encoder leaves padding rows at 0
        torch.testing.assert_close(encoding.nodes, nodes * real, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(encoding.gates, gates, rtol=1e-5, atol=1e-5)
        embeddings = edge_embeddings(nodes, graphs)
        context = torch.randn(graphs.num_graphs, actor.memory.hidden)
        features = torch.cat([embeddings, context[:, None].expand(-1, embeddings.shape[1], -1)], -1)
        dense = masked_log_softmax(actor.edge_head(features).squeeze(-1), graphs.action_mask)
        split = masked_log_softmax(actor.edge_scores(nodes, graphs, context), graphs.action_mask)
        weights = torch.softmax(torch.randn(graphs.num_graphs, embeddings.shape[1]), -1)
        weights = weights * graphs.action_mask
        torch.testing.assert_close(
            chosen_edge_embedding(nodes, graphs, weights),
            torch.einsum("ge,ged->gd", weights, embeddings),
            rtol=1e-5,
            atol=1e-5,
        )
    assert torch.equal(torch.isfinite(dense), graphs.action_mask)
    torch.testing.assert_close(split, dense, rtol=1e-5, atol=1e-5)
    assert torch.equal(split.argmax(-1), dense.argmax(-1))


def test_retain_freed_memory_sets_glibc_thresholds() -> None:
    """On glibc both mallopt calls succeed (mallopt returns 0 for a value it refuses)."""
    import platform

    from agents.allocator import retain_freed_memory

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("mallopt is glibc's")
    assert retain_freed_memory() is True
