"""Throughput of the multi-agent PGO environment (envs/).

Prints agent-steps per second (one agent-step = one agent's action in one env step; B·n per env
step, including agents waiting with the no-op) for B problems of n robots × P poses:

* ``core``: :meth:`envs.core.PGOCore.step` alone (dynamics, incremental residuals and rewards);
* ``env``: ``PGOEnv.step`` with a ready action (core step + observation + tensordict);
* ``rollout``: ``PGOEnv.rollout`` with random masked actions drawn from the action spec.

Then the per-step cost against the local-graph size, next to a reference measured in the same run:
a full recompute of every local residual each step (what a non-incremental step would cost).

    .venv/bin/python benchmarks/bench_env.py [--device cuda] [--batch 32] [--robots 7]
        [--correction subtree] [--observation invariant] [--action-scale whitened]
        [--base gauss-newton]
"""

from __future__ import annotations

import argparse
import time

import torch

from envs import make_torchrl_env
from envs.geometry import _gather_rows, residuals
from envs.modes import ACTION_SCALES, BASES, CORRECTIONS, OBSERVATIONS, PAPER_MODES


def first_valid_action(env, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """The lowest-index valid edge per agent and a random correction within Δmax."""
    core = env.core
    edge = core.action_mask().to(torch.int8).argmax(-1)
    unit = torch.rand(edge.shape + (3,), generator=generator).to(core.device, core.dtype)
    return edge, (2 * unit - 1) * core.delta_max


def _horizon(env, max_steps: int | None) -> int:
    """Steps timed per episode: the whole episode, or its first ``max_steps``."""
    horizon = env.core.horizon
    return horizon if max_steps is None else min(horizon, max_steps)


def time_core(env, episodes: int, max_steps: int | None = None) -> tuple[float, int]:
    """Seconds and agent-steps of core steps over full episodes, or their first ``max_steps``
    (resets excluded; the timed loop includes drawing the lowest-valid-edge action from the
    mask)."""
    generator = torch.Generator().manual_seed(0)
    seconds, agent_steps = 0.0, 0
    for _ in range(episodes):
        env.reset()
        core = env.core
        horizon = _horizon(env, max_steps)
        _sync(core.device)
        start = time.perf_counter()
        for _ in range(horizon):
            core.step(*first_valid_action(env, generator))
        _sync(core.device)
        seconds += time.perf_counter() - start
        agent_steps += horizon * core.batch * core.num_agents
    return seconds, agent_steps


def time_env(env, episodes: int, max_steps: int | None = None) -> tuple[float, int]:
    """Seconds and agent-steps of ``PGOEnv.step`` over full episodes, or their first
    ``max_steps`` (action drawing excluded)."""
    generator = torch.Generator().manual_seed(0)
    seconds, agent_steps = 0.0, 0
    for _ in range(episodes):
        td = env.reset()
        horizon = _horizon(env, max_steps)
        for _ in range(horizon):
            edge, delta = first_valid_action(env, generator)
            td["agents", "action", "edge"] = edge
            td["agents", "action", "delta"] = delta.to(torch.float32)
            _sync(env.device)
            start = time.perf_counter()
            td = env.step(td)
            _sync(env.device)
            seconds += time.perf_counter() - start
            td = td["next"]
        agent_steps += horizon * env.core.batch * env.core.num_agents
    return seconds, agent_steps


def time_rollout(env, episodes: int, max_steps: int | None = None) -> tuple[float, int]:
    """Seconds and agent-steps of ``env.rollout`` with random masked actions."""
    seconds, agent_steps = 0.0, 0
    for _ in range(episodes):
        env.reset()
        horizon = _horizon(env, max_steps)
        _sync(env.device)
        start = time.perf_counter()
        td = env.rollout(
            horizon, break_when_any_done=False, auto_reset=False, tensordict=env.reset()
        )
        _sync(env.device)
        seconds += time.perf_counter() - start
        agent_steps += td.shape[1] * env.core.batch * env.core.num_agents
    return seconds, agent_steps


def time_full_recompute(env, steps: int) -> float:
    """Seconds per step of recomputing every local residual (the non-incremental reference)."""
    core = env.core
    t = core.state
    g = core.batch * core.num_agents
    poses = t.poses.view(g, -1, 3)
    tails, heads = t.tails.view(g, -1), t.heads.view(g, -1)
    measurements = t.measurements.view(g, -1, 3)
    _sync(core.device)
    start = time.perf_counter()
    for _ in range(steps):
        r = residuals(_gather_rows(poses, tails), _gather_rows(poses, heads), measurements)
        (t.kappa.view(g, -1) * r[..., 2] ** 2).sum(-1)
    _sync(core.device)
    return (time.perf_counter() - start) / steps


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def throughput(args: argparse.Namespace, device: str) -> None:
    env = make_torchrl_env(
        robots=args.robots,
        batch_size=args.batch,
        seed=0,
        device=device,
        poses_per_robot=args.poses,
        **modes(args),
    )
    print(
        f"\n[{device}] B={args.batch} problems × n={args.robots} robots × {args.poses} poses;"
        f" padding {env.dims}; {modes(args)}"
    )
    start = time.perf_counter()
    env.reset()
    print(f"  reset (problem generation + packing): {time.perf_counter() - start:.3f} s")
    timers = [("core", time_core), ("env", time_env), ("rollout", time_rollout)]
    for name, timer in timers if args.rollout else timers[:2]:
        seconds, agent_steps = timer(env, args.episodes, args.max_steps)
        env_steps = agent_steps / (args.batch * args.robots)
        print(
            f"  {name:8s} {agent_steps / seconds:12,.0f} agent-steps/s"
            f"  ({env_steps / seconds:8,.1f} env steps/s, {1e3 * seconds / env_steps:.3f} ms/step)"
        )


def scaling(args: argparse.Namespace, device: str) -> None:
    print(
        f"\n[{device}] per-step cost vs local-graph size (B={args.batch}, core step vs full"
        " recompute of all local residuals, same run)"
    )
    print(
        f"  {'robots':>6} {'poses/robot':>11} {'E_max':>6} {'core ms':>8} {'full ms':>8}"
        f" {'env ms':>8} {'core/full':>9}"
    )
    sizes = [(7, poses) for poses in args.scaling_poses] or [
        (7, 20),
        (7, 60),
        (7, 180),
        (7, 540),
        (3, 60),
        (14, 60),
    ]
    for robots, poses in sizes:
        env = make_torchrl_env(
            robots=robots,
            batch_size=args.batch,
            seed=0,
            device=device,
            poses_per_robot=poses,
            **modes(args),
        )
        seconds, agent_steps = time_core(env, 1, args.max_steps)
        core_ms = 1e3 * seconds / (agent_steps / (args.batch * robots))
        seconds, agent_steps = time_env(env, 1, args.max_steps)
        env_ms = 1e3 * seconds / (agent_steps / (args.batch * robots))
        full_ms = 1e3 * time_full_recompute(env, 50)
        print(
            f"  {robots:6d} {poses:11d} {env.dims.edges:6d} {core_ms:8.3f} {full_ms:8.3f}"
            f" {env_ms:8.3f} {core_ms / full_ms:9.2f}"
        )


def modes(args: argparse.Namespace) -> dict[str, str]:
    """The env's correction / observation / action-scale / base options of this run."""
    return {
        "correction": args.correction,
        "observation": args.observation,
        "action_scale": args.action_scale,
        "base": args.base,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--device", action="append", help="cpu and/or cuda (default: all found)")
    parser.add_argument("--no-scaling", action="store_true")
    parser.add_argument(
        "--max-steps",
        type=int,
        default=None,
        help="time only the first steps of each episode (large graphs: an episode has one step"
        " per local edge)",
    )
    parser.add_argument(
        "--rollout",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also time env.rollout (it keeps every step's observation: off for large graphs)",
    )
    parser.add_argument(
        "--scaling-poses",
        type=lambda text: [int(item) for item in text.split(",")],
        default=[],
        help="poses per robot of the scaling table at n = 7, e.g. 60,250,1000,1500 (default: a"
        " fixed set of sizes and team sizes)",
    )
    parser.add_argument("--correction", default=PAPER_MODES.correction, choices=CORRECTIONS)
    parser.add_argument("--observation", default=PAPER_MODES.observation, choices=OBSERVATIONS)
    parser.add_argument("--action-scale", default=PAPER_MODES.action_scale, choices=ACTION_SCALES)
    parser.add_argument("--base", default=PAPER_MODES.base, choices=BASES)
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch intra-op threads (default 1: on a shared 2-core machine, parallel kernels on"
        " these small tensors wait for descheduled threads and run 10-40x slower)",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    devices = args.device or ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    for device in devices:
        throughput(args, device)
        if not args.no_scaling:
            scaling(args, device)


if __name__ == "__main__":
    main()
