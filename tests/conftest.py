"""Shared fixtures: real datasets come through the registry (POPBENCH_DATA in tests and CI)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from popbench import se2
from popbench.graph import make_graph


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture
def small_graph(rng: np.random.Generator):
    """A 30-pose noisy loop with a few loop closures and anisotropic information."""
    n = 30
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    truth = np.column_stack([5 * np.cos(angles), 5 * np.sin(angles), se2.wrap(angles + np.pi / 2)])
    tails = np.concatenate([np.arange(n - 1), [0, 5, 20]])
    heads = np.concatenate([np.arange(1, n), [n - 1, 15, 9]])
    z = se2.between(truth[tails], truth[heads]) + rng.normal(0, 0.05, (tails.size, 3))
    info = np.tile(
        np.array([[40.0, 5.0, 1.0], [5.0, 20.0, 2.0], [1.0, 2.0, 90.0]]), (tails.size, 1, 1)
    )
    graph = make_graph(np.zeros((n, 3)), tails, heads, z, info, ground_truth=truth, name="loop30")
    return graph.replace(poses=graph.odometry_initial())


def data_missing(reason: str) -> None:
    """A test's data is unavailable: skip it, or fail it when ``POPBENCH_REQUIRE_DATA=1`` (set by
    ``.ci/run``, so that CI can never pass with the dataset and GTSAM tests skipped)."""
    if os.environ.get("POPBENCH_REQUIRE_DATA") == "1":
        pytest.fail(f"{reason} (POPBENCH_REQUIRE_DATA=1)")
    pytest.skip(reason)


def dataset_missing(name: str, error: Exception) -> None:
    """The registered dataset ``name`` is nowhere on disk and cannot be downloaded: skip, even
    under ``POPBENCH_REQUIRE_DATA=1``, when its record expects no offline copy (no shared copy,
    no packaged source: popbench.datasets.Dataset), else :func:`data_missing`."""
    from popbench import datasets

    entry = datasets.get(name)
    if not entry.shared_copy and entry.packaged is None:
        pytest.skip(f"dataset {name} is not in the team's data folder (CI is offline): {error}")
    data_missing(f"dataset {name} unavailable: {error}")


def require_dataset(name: str):
    """The registered dataset ``name`` as a PoseGraph (from POPBENCH_DATA, the cache, its
    packaged source or a download); see :func:`dataset_missing` when it is nowhere on disk and
    cannot be downloaded. A checksum mismatch or a malformed file always fails the test."""
    from popbench import datasets

    try:
        return datasets.load(name)
    except datasets.DatasetUnavailableError as error:
        dataset_missing(name, error)


def ring_g2o(path, n: int = 8, dx: str = "0.77"):
    """Write a tiny g2o ring to ``path``: n poses, n odometry edges (the last closes the loop);
    ``dx`` is the forward measurement of the first edge (the others measure 0.77)."""
    lines = [f"VERTEX_SE2 {i} {np.cos(i):.3f} {np.sin(i):.3f} 0" for i in range(n)]
    lines += [
        f"EDGE_SE2 {i} {(i + 1) % n} {dx if i == 0 else 0.77} 0.01 0.8 100 0 0 100 0 400"
        for i in range(n)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def grid_g2o(path, seed: int = 0):
    """Write a 4×5 boustrophedon grid walk to ``path``: 19 odometry edges and 12 lattice loop
    closures, measurements with σ = 0.01 noise, information diag(100, 100, 400)."""
    rng = np.random.default_rng(seed)
    cells = [(x, y) for y in range(5) for x in (range(4) if y % 2 == 0 else range(3, -1, -1))]
    index = {cell: i for i, cell in enumerate(cells)}
    edges = [(i, i + 1) for i in range(len(cells) - 1)]
    edges += [
        (i, index[(x, y + 1)])
        for (x, y), i in index.items()
        if (x, y + 1) in index and abs(index[(x, y + 1)] - i) > 1
    ]
    lines = [f"VERTEX_SE2 {i} {x} {y} 0" for i, (x, y) in enumerate(cells)]
    for tail, head in edges:
        dx, dy = np.subtract(cells[head], cells[tail]) + rng.normal(0.0, 0.01, 2)
        dtheta = rng.normal(0.0, 0.01)
        lines.append(f"EDGE_SE2 {tail} {head} {dx:.5f} {dy:.5f} {dtheta:.5f} 100 0 0 100 0 400")
    path.write_text("\n".join(lines) + "\n")
    return path


def tiny_model():
    """The smallest agents.config.ModelConfig the agent tests train and run (fast on a CPU)."""
    from agents.config import ModelConfig

    return ModelConfig(
        hidden=8,
        layers=2,
        edge_hidden=4,
        gate_hidden=8,
        memory_hidden=8,
        edge_head_hidden=12,
        correction_hidden=(16, 16),
        critic_hidden=8,
        critic_layers=2,
        critic_projection=16,
        critic_mlp=(16, 8),
    )
