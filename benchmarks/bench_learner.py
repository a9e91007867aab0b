"""Cost of the learners (MAPPO, IPPO, GA-SAC): end-to-end frames/s and one training step against
a plain PyG floor, both measured in this run (docs/algorithms.md, "Cost").

1. **End to end**: `agents.trainer.train` from scratch (no imitation, no held-out evaluation in
   the window) for ``--frames`` frames with the cpu presets; frames/s over the batches that
   learn (GA-SAC's warm-up batches, which only collect, are left out), from `metrics.csv`.
2. **One training step** on one minibatch of collected transitions (PPO: ``minibatch_size``
   joint transitions; GA-SAC: ``batch_size``): loss forward + backward + optimiser step, median
   of ``--repeats``; next to it, **the floor**: one forward + backward of a plain PyG
   message-passing network of the actor's width and depth plus one of the critic's (value's),
   over the same batched graphs (their real edges, both directions, as one PyG batch):
   `GraphConv` layers (``floor``), and PyG's edge-conditioned `NNConv` of the same edge-network
   width (``nnconv``, the operator of the paper's eq. 3 as PyG ships it).

    .venv/bin/python benchmarks/bench_learner.py [--frames 1024] [--repeats 5] [--threads 2]

Time it alone: another process on the two cores changes every number.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

import torch
from torch import nn
from torch_geometric.nn import GraphConv, NNConv

from agents.config import PRESETS, TrainConfig
from agents.encoder import GraphBatch
from agents.trainer import train

ALGORITHMS = {  # name: (preset, the config overrides of a from-scratch run)
    "mappo": ("cpu-mappo", {}),
    "ippo": ("cpu-ippo", {}),
    "ga-sac": ("cpu-residual", {"anchor_weight": 0.0}),
}


def scratch_config(name: str, frames: int, out_dir: Path) -> TrainConfig:
    """The preset of `name`, from scratch, `frames` frames, no evaluation in the window."""
    preset, algorithm = ALGORITHMS[name]
    config = PRESETS[preset]
    experiment = dataclasses.replace(
        config.experiment,
        frames=frames,
        out_dir=str(out_dir),
        progress=False,
        eval_interval=10 * frames,
        checkpoint_interval=10 * frames,
    )
    return dataclasses.replace(
        config,
        experiment=experiment,
        imitation=dataclasses.replace(config.imitation, episodes=0),
        algorithm=dataclasses.replace(config.algorithm, **algorithm),
    )


def end_to_end(name: str, frames: int) -> float:
    """Frames per second of `train` over its learning batches."""
    with tempfile.TemporaryDirectory() as folder:
        config = scratch_config(name, frames, Path(folder))
        train(config, resume=False)
        with (Path(folder) / "metrics.csv").open() as handle:
            rows = list(csv.DictReader(handle))
    learning = [row for row in rows if int(row["updates"]) > 0]
    first = rows[rows.index(learning[0]) - 1] if rows.index(learning[0]) > 0 else None
    start_frames = int(first["frames"]) if first else 0
    start_wall = float(first["wall_s"]) if first else 0.0
    elapsed = float(learning[-1]["wall_s"]) - start_wall
    return (int(learning[-1]["frames"]) - start_frames) / elapsed


def median_seconds(step, repeats: int) -> float:
    """Median wall time of `step()` over `repeats` calls, after one untimed call."""
    step()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        step()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def pyg_batch(graphs: GraphBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(x [N, d_v], edge_index [2, 2M], edge_attr [2M, d_e + 1]) of the real edges of the G
    graphs in both directions, as one PyG batch (padding vertices kept, edges dropped)."""
    count, vertices, _ = graphs.node_features.shape
    x = graphs.node_features.reshape(count * vertices, -1)
    offsets = torch.arange(count).view(-1, 1) * vertices
    ends = (graphs.edge_index.clamp(0, vertices - 1) + offsets.unsqueeze(1)).transpose(0, 1)
    ends = ends.reshape(2, -1)[:, graphs.edge_mask.reshape(-1)]
    attr = graphs.edge_attr.reshape(-1, graphs.edge_attr.shape[-1])[graphs.edge_mask.reshape(-1)]
    flags = torch.cat([torch.zeros(len(attr), 1), torch.ones(len(attr), 1)])
    edge_attr = torch.cat([torch.cat([attr, attr]), flags], -1)
    return x, torch.cat([ends, ends.flip(0)], 1), edge_attr


class FloorNetwork(nn.Module):
    """`layers` PyG layers of width `hidden` (GraphConv, or NNConv with an edge MLP of width
    `edge_hidden`), sigmoid between them; the output is the sum of the last embeddings."""

    def __init__(
        self,
        node_dim: int,
        edge_dim: int,
        hidden: int,
        layers: int,
        edge_hidden: int,
        edge_conditioned: bool,
    ) -> None:
        super().__init__()
        dims = [node_dim] + [hidden] * layers
        self.edge_conditioned = edge_conditioned
        if edge_conditioned:
            self.convs = nn.ModuleList(
                NNConv(
                    d_in,
                    d_out,
                    nn.Sequential(
                        nn.Linear(edge_dim, edge_hidden),
                        nn.ReLU(),
                        nn.Linear(edge_hidden, d_in * d_out),
                    ),
                    aggr="mean",
                )
                for d_in, d_out in zip(dims[:-1], dims[1:], strict=True)
            )
        else:
            self.convs = nn.ModuleList(
                GraphConv(d_in, d_out, aggr="mean")
                for d_in, d_out in zip(dims[:-1], dims[1:], strict=True)
            )

    def forward(self, x: torch.Tensor, edge_index: torch.Tensor, edge_attr: torch.Tensor):
        for conv in self.convs:
            x = conv(x, edge_index, edge_attr) if self.edge_conditioned else conv(x, edge_index)
            x = torch.sigmoid(x)
        return x.sum()


def floor_step(config: TrainConfig, graphs: GraphBatch, edge_conditioned: bool):
    """A callable: forward + backward of the actor-sized and critic-sized floor networks."""
    model = config.model
    x, edge_index, edge_attr = pyg_batch(graphs)
    networks = [
        FloorNetwork(
            x.shape[1], edge_attr.shape[1], width, depth, model.edge_hidden, edge_conditioned
        )
        for width, depth in (
            (model.hidden, model.layers),
            (model.critic_hidden, model.critic_layers),
        )
    ]

    def step() -> None:
        total = sum(network(x, edge_index, edge_attr) for network in networks)
        total.backward()

    return step


def training_step(name: str, repeats: int) -> tuple[float, float, float, int]:
    """(step s, GraphConv floor s, NNConv floor s, transitions) on one collected minibatch."""
    from torchrl.collectors import Collector

    from agents.algorithms import learner_of

    with tempfile.TemporaryDirectory() as folder:
        config = scratch_config(name, 1, Path(folder))
        learner = learner_of(config)
        session = learner.build(config)
        collector = Collector(
            session.env,
            session.policy,
            frames_per_batch=256,
            total_frames=256,
            auto_register_policy_transforms=False,
        )
        data = next(iter(collector))
        collector.shutdown()
    if name == "ga-sac":
        from agents.gasac_trainer import optimise

        session.actor_learns = True
        size = config.algorithm.batch_size
        minibatch = data.reshape(-1)[:size]
        step = lambda: optimise(session, minibatch)  # noqa: E731
    else:
        from agents.ppo_trainer import PPOBatches, optimise_ppo

        size = config.ppo.minibatch_size
        minibatch = PPOBatches(session).prepare(data).reshape(-1)[:size]
        step = lambda: optimise_ppo(session, minibatch)  # noqa: E731
    observation = minibatch.get(("agents", "observation"))
    graphs = GraphBatch.from_observation(observation, minibatch.get(("agents", "action_mask")))
    return (
        median_seconds(step, repeats),
        median_seconds(floor_step(config, graphs, edge_conditioned=False), repeats),
        median_seconds(floor_step(config, graphs, edge_conditioned=True), repeats),
        size,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1024, help="frames per end-to-end run")
    parser.add_argument("--repeats", type=int, default=5, help="timed training steps")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--algorithms", default="mappo,ippo,ga-sac")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"threads {args.threads}, n = 7, 60 poses per robot, cpu presets, from scratch")
    print(
        "algorithm | frames/s end to end | step ms (transitions) | GraphConv floor ms | "
        "step / floor | NNConv ms | step / NNConv"
    )
    for name in args.algorithms.split(","):
        warmup = PRESETS[ALGORITHMS[name][0]].algorithm.warmup_frames if name == "ga-sac" else 0
        rate = end_to_end(name, args.frames + warmup)
        step, floor, nnconv, size = training_step(name, args.repeats)
        print(
            f"{name} | {rate:.1f} | {1e3 * step:.1f} ({size}) | {1e3 * floor:.1f} | "
            f"{step / floor:.2f} | {1e3 * nnconv:.1f} | {step / nnconv:.2f}"
        )


if __name__ == "__main__":
    main()
