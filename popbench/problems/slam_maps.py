"""Synthetic single-trajectory SLAM maps cut into robots (training distribution, docs/training.md).

Unlike :mod:`popbench.problems.synthetic` (every robot its own walk, fixed σ), a map here is what
the registered datasets are: ONE trajectory, split into ``robots`` parts by the same METIS split the
tables use (:meth:`DistributedProblem.from_graph`, seed 0), so odometry edges cross robots and
loop closures span the map.

Trajectory (Olson et al. 2006's Manhattan world): a 1 m grid random walk of ``N = robots · P``
poses, P drawn log-uniformly in ``poses_per_robot``; before each step the heading stays with a
per-map probability ``p`` ∈ :data:`STRAIGHT` and turns ±90° with ``(1 − p)/2`` each. A loop
closure joins two poses at the same grid point at least :data:`MIN_LOOP_GAP` steps apart (a
revisited place); ``round(d · N)`` of those pairs are kept, d ∈ :data:`LOOP_DENSITY` per map.

Noise, drawn per map from ranges that cover the registered datasets' (measured 2026-12-04,
docs/training.md "SLAM-shaped maps"), log-uniform unless stated:

* odometry σ_θ ∈ :data:`ROTATION_SIGMA` [rad] and σ_t ∈ :data:`TRANSLATION_SIGMA` [m per 1 m
  step]; the two translation axes differ by a factor ∈ :data:`ANISOTROPY` (either axis the
  larger), so information matrices are anisotropic, ``Λ = diag(1/σ_x², 1/σ_y², 1/σ_θ²)``;
* loop closures: the odometry's σ times a factor ∈ :data:`LOOP_FACTOR` (one per map);
* every edge's σ (all three axes together) times ``2^u``, ``u ~ U(−j, j)``, j ∈
  :data:`EDGE_JITTER` per map: the per-edge spread inside one real map.

A measurement is ``z̃ = between(x_p, x_q) ∘ exp(ξ)``, ``ξ ~ N(0, Λ⁻¹)``. Ground truth is in
the frame of vertex 0; the start is the odometry composition.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from popbench import se2
from popbench.choices import SLAM_LEVEL
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph, make_graph
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.initial import with_start

POSES_PER_ROBOT = (100, 1500)  # default range of P (poses per robot)
STRAIGHT = (0.3, 0.8)  # probability of no turn before a step (uniform)
LOOP_DENSITY = (0.02, 1.2)  # loop closures per pose (mit 0.025 … frh 1.14, city10k 1.07)
ROTATION_SIGMA = (0.005, 0.35)  # [rad] odometry σ_θ (grid1000_2 0.0096 … m3500c 0.335)
TRANSLATION_SIGMA = (0.01, 0.5)  # [m per m] odometry σ_t (grid1000_2 0.010 … intel 0.49)
ANISOTROPY = (1.0, 5.0)  # σ_x / σ_y (or its inverse) of one edge
LOOP_FACTOR = (0.5, 3.0)  # loop closure σ / odometry σ (datasets 0.5 … 2.5)
EDGE_JITTER = (0.0, 1.0)  # j: each edge's σ times 2^U(−j, j)
# the noise-level name under which popbench.problems.synthetic.make_problem draws these
LEVEL = SLAM_LEVEL
MIN_LOOP_GAP = 10  # a revisit is at least this many steps after the earlier visit


def level_sizes(poses_per_robot: int) -> tuple[int, int]:
    """The range ``(P, 2P)`` of poses per robot drawn for the noise level :data:`LEVEL` at
    ``poses_per_robot = P`` (one octave of map sizes per nominal size)."""
    return poses_per_robot, 2 * poses_per_robot


def log_uniform(rng: np.random.Generator, bounds: tuple[float, float], size=None) -> np.ndarray:
    """Samples ``exp(U(log lo, log hi))``."""
    low, high = np.log(bounds[0]), np.log(bounds[1])
    return np.exp(rng.uniform(low, high, size))


def manhattan_walk(rng: np.random.Generator, num_poses: int, straight: float) -> np.ndarray:
    """``(num_poses, 3)`` grid walk from the origin, heading 0, 1 m steps; each step keeps the
    heading with probability ``straight`` and turns ±90° otherwise."""
    turn = (1.0 - straight) / 2.0
    turns = rng.choice([-1, 0, 1], size=num_poses - 1, p=[turn, straight, turn])
    quarter_turns = np.concatenate([[0], np.cumsum(turns)])
    headings = quarter_turns * (np.pi / 2)
    steps = np.round(np.stack([np.cos(headings[1:]), np.sin(headings[1:])], -1))
    positions = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return np.column_stack([positions, se2.wrap(headings)])


def revisits(rng: np.random.Generator, truth: np.ndarray, count: int) -> np.ndarray:
    """``(K, 2)`` loop-closure pairs ``tail < head``: poses at the same grid point at least
    :data:`MIN_LOOP_GAP` steps apart, ``K = min(count, #such pairs)`` drawn uniformly."""
    pairs = cKDTree(truth[:, :2]).query_pairs(0.5, output_type="ndarray")
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[pairs[:, 1] - pairs[:, 0] >= MIN_LOOP_GAP]
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]  # canonical order: reproducible
    chosen = np.sort(rng.choice(pairs.shape[0], size=min(count, pairs.shape[0]), replace=False))
    return pairs[chosen]


def edge_sigmas(
    rng: np.random.Generator, is_loop: np.ndarray, jitter: float
) -> tuple[np.ndarray, dict[str, float]]:
    """``(M, 3)`` σ per edge (x [m], y [m], θ [rad]) and the map's drawn noise parameters."""
    params = {
        "sigma_rotation": float(log_uniform(rng, ROTATION_SIGMA)),
        "sigma_translation": float(log_uniform(rng, TRANSLATION_SIGMA)),
        "anisotropy": float(log_uniform(rng, ANISOTROPY)),
        "loop_factor": float(log_uniform(rng, LOOP_FACTOR)),
    }
    root = np.sqrt(params["anisotropy"])
    axes = (root, 1.0 / root) if rng.random() < 0.5 else (1.0 / root, root)
    odometry = np.array(
        [
            params["sigma_translation"] * axes[0],
            params["sigma_translation"] * axes[1],
            params["sigma_rotation"],
        ]
    )
    scale = np.where(is_loop, params["loop_factor"], 1.0)
    scale = scale * 2.0 ** rng.uniform(-jitter, jitter, is_loop.size)
    return odometry[None, :] * scale[:, None], params


def measured_graph(
    rng: np.random.Generator,
    truth: np.ndarray,
    tails: np.ndarray,
    heads: np.ndarray,
    sigma: np.ndarray,
    **fields: object,
) -> PoseGraph:
    """The graph of edges ``tails → heads`` ``(M,)`` measuring the true relative poses of
    ``truth`` ``(N, 3)`` with Gaussian noise ``exp(ε)``, ``ε ~ N(0, diag σ²)`` drawn from
    ``rng``, ``sigma`` ``(M, 3)`` (x [m], y [m], θ [rad]); information ``diag(1/σ²)``, poses
    zero (a start is set later), ``ground_truth=truth`` and ``fields`` passed to
    :func:`popbench.graph.make_graph`."""
    noise = rng.normal(size=sigma.shape) * sigma
    measurements = se2.compose(se2.between(truth[tails], truth[heads]), se2.exp(noise))
    information = np.zeros((tails.size, 3, 3))
    information[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sigma**2
    zeros = np.zeros((truth.shape[0], 3))
    return make_graph(zeros, tails, heads, measurements, information, ground_truth=truth, **fields)


def make_map(
    robots: int = 7,
    poses_per_robot: int | tuple[int, int] = POSES_PER_ROBOT,
    seed: int = 0,
):
    """The uncut map: ``(graph, params)``, a single-robot :class:`PoseGraph` (poses: the
    odometry composition; ground truth in vertex 0's frame) and the drawn parameters."""
    rng = np.random.default_rng(seed)
    low, high = (
        (poses_per_robot, poses_per_robot) if np.isscalar(poses_per_robot) else poses_per_robot
    )
    per_robot = int(round(log_uniform(rng, (low, high))))
    num_poses = robots * per_robot
    straight = float(rng.uniform(*STRAIGHT))
    density = float(log_uniform(rng, LOOP_DENSITY))
    jitter = float(rng.uniform(*EDGE_JITTER))
    truth = manhattan_walk(rng, num_poses, straight)

    loops = revisits(rng, truth, int(round(density * num_poses)))
    chain = np.arange(num_poses - 1)
    tails = np.concatenate([chain, loops[:, 0]])
    heads = np.concatenate([chain + 1, loops[:, 1]])
    sigma, params = edge_sigmas(rng, np.arange(tails.size) >= chain.size, jitter)
    name = f"slam-map-R{robots}x{per_robot}-seed{seed}"
    graph = measured_graph(rng, truth, tails, heads, sigma, name=name)
    params |= {
        "poses_per_robot": per_robot,
        "straight": straight,
        "loop_density": loops.shape[0] / num_poses,
        "edge_jitter": jitter,
    }
    return graph, params


def make_problem(
    robots: int = 7,
    poses_per_robot: int | tuple[int, int] = POSES_PER_ROBOT,
    seed: int = 0,
) -> DistributedProblem:
    """A seeded SLAM-shaped map split among ``robots`` by METIS (seed 0), odometry start.

    Args:
        robots: number of robots ``R ≥ 1``.
        poses_per_robot: ``P`` or a range ``(low, high)`` it is drawn from log-uniformly
            (``2 ≤ low ≤ high``); the map has ``R · P`` poses.
        seed: seed of ``np.random.default_rng``; equal arguments give identical problems.

    Raises:
        ValueRangeError: an argument outside its range.
    """
    if isinstance(robots, bool) or not isinstance(robots, int | np.integer) or robots < 1:
        raise ValueRangeError("robots", robots, "an integer ≥ 1")
    bounds = np.atleast_1d(poses_per_robot)
    if bounds.size not in (1, 2) or bounds.min() < 2 or bounds[0] > bounds[-1]:
        raise ValueRangeError(
            "poses_per_robot", poses_per_robot, "P ≥ 2 or (low, high), low ≤ high"
        )
    graph, _ = make_map(robots, poses_per_robot, seed)
    problem = DistributedProblem.from_graph(graph, robots, "metis", seed=0)
    return with_start(problem, "odometry")
