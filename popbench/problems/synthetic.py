"""Synthetic multi-robot pose graphs for training and tests (paper §IV-A).

World: robots drive random walks on a 1 m Manhattan grid (each step 1 m along the current
heading; before each step the heading stays with probability 1/2 and turns ±90° with probability
1/4 each), all starting at random grid points of one shared square, so that their trajectories
cross and inter-robot loop closures exist.

Graph (``R`` robots × ``P`` poses, ``N = R·P``):

* vertex ids are contiguous per robot: robot ``r`` owns ``r·P .. r·P + P − 1``;
* odometry ``k → k+1`` inside each robot;
* one inter-robot relative edge ``r·P + P − 1 → (r+1)·P`` between consecutive robots (the last
  pose of ``r`` seen from the first of ``r+1``), so the graph is connected and the chain
  ``0 → 1 → … → N−1`` is complete;
* ``round(loop_ratio · N)`` loop closures, sampled uniformly without replacement among vertex
  pairs closer than ``loop_radius`` (ground truth) that are not already joined and, within one
  robot, at least ``MIN_LOOP_GAP`` steps apart; intra-robot pairs become LOOP, inter-robot pairs
  INTER_LOOP. If fewer pairs qualify, all of them are used.

Noise (isotropic SE(2), one σ per edge kind, :data:`NOISE_LEVELS`): the paper gives three σ per
environment for four kinds; we use σ₁ for odometry, σ₂ for intra-robot loop closures and σ₃ for
both inter-robot kinds (relative estimates and loop closures). A measurement is
``z̃ = between(x_p, x_q) ∘ exp(ξ)``, ``ξ ~ N(0, σ² I₃)`` — the same σ on x [m], y [m] and θ [rad] —
and its information is ``I₃ / σ²``.

Ground truth is expressed in the frame of vertex 0 (the gauge) and the initial estimate is the
odometry composition of the chain (robot by robot through the inter-robot relative edges).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from popbench import se2
from popbench.choices import NOISE_LEVELS
from popbench.errors import ValueRangeError
from popbench.graph import odometry_composition, robot_kinds
from popbench.problems import slam_maps
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.initial import with_start

MIN_LOOP_GAP = 5  # intra-robot loop closures join poses at least this many steps apart
STEP_LENGTH = 1.0  # [m]
TURN_PROBABILITIES = (0.25, 0.5, 0.25)  # turn −90°, straight, +90°


def kind_sigmas(noise: str) -> np.ndarray:
    """σ per :class:`EdgeKind` value, ``(4,)``: (odometry, loop, inter-relative, inter-loop)."""
    if noise not in NOISE_LEVELS:
        raise ValueRangeError("noise level", noise, ", ".join(NOISE_LEVELS))
    odometry, loop, inter = NOISE_LEVELS[noise]
    return np.array([odometry, loop, inter, inter])


def random_walks(
    rng: np.random.Generator, robots: int, poses_per_robot: int, world_size: float
) -> np.ndarray:
    """Ground-truth Manhattan random walks, ``(robots, poses_per_robot, 3)`` in the world frame.

    Starts are uniform grid points in ``[0, world_size)²`` with a uniform heading in
    ``{0, ±π/2, π}``.
    """
    starts = rng.integers(0, max(int(world_size), 1), size=(robots, 2)).astype(float)
    first_heading = rng.integers(0, 4, size=(robots, 1))
    turns = rng.choice([-1, 0, 1], size=(robots, poses_per_robot - 1), p=TURN_PROBABILITIES)
    quarter_turns = np.cumsum(np.concatenate([first_heading, turns], axis=1), axis=1)
    headings = quarter_turns * (np.pi / 2)
    steps = STEP_LENGTH * np.stack([np.cos(headings[:, 1:]), np.sin(headings[:, 1:])], -1)
    steps = np.round(steps)  # exact grid moves
    positions = starts[:, None, :] + np.concatenate(
        [np.zeros((robots, 1, 2)), np.cumsum(steps, axis=1)], axis=1
    )
    return np.concatenate([positions, se2.wrap(headings)[..., None]], axis=-1)


def sample_loop_closures(
    rng: np.random.Generator,
    truth: np.ndarray,
    robots: np.ndarray,
    count: int,
    radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` loop-closure pairs ``(tails, heads)`` (``tail < head``) among vertices closer
    than ``radius`` [m], excluding consecutive ids and intra-robot pairs under ``MIN_LOOP_GAP``
    steps apart; all qualifying pairs if there are fewer than ``count``."""
    pairs = cKDTree(truth[:, :2]).query_pairs(radius, output_type="ndarray")
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]  # canonical order: reproducible
    gap = pairs[:, 1] - pairs[:, 0]
    same_robot = robots[pairs[:, 0]] == robots[pairs[:, 1]]
    keep = (gap > 1) & ~(same_robot & (gap < MIN_LOOP_GAP))
    pairs = pairs[keep]
    chosen = rng.choice(pairs.shape[0], size=min(count, pairs.shape[0]), replace=False)
    chosen.sort()
    return pairs[chosen, 0], pairs[chosen, 1]


def make_problem(
    robots: int = 7,
    noise: str = "V2",
    poses_per_robot: int = 60,
    loop_ratio: float = 0.15,
    seed: int = 0,
    loop_radius: float = 1.5,
) -> DistributedProblem:
    """A seeded synthetic multi-robot problem with ground truth (see the module docstring).

    Args:
        robots: number of robots ``R ≥ 1``.
        noise: ``"V1"``, ``"V2"`` or ``"V3"`` (:data:`NOISE_LEVELS`), or ``"SLAM"``: a
            single-trajectory map of :mod:`popbench.problems.slam_maps` with ``poses_per_robot``
            drawn in ``[P, 2P]`` (``loop_ratio`` and ``loop_radius`` unused there).
        poses_per_robot: ``P ≥ 2`` poses per robot.
        loop_ratio: loop closures per pose; ``round(loop_ratio · R · P)`` are sampled.
        seed: seed of ``np.random.default_rng``; equal arguments give identical problems.
        loop_radius: largest ground-truth distance [m] between loop-closed poses.

    Returns:
        A :class:`DistributedProblem` whose graph has ``poses`` = odometry composition,
        ``ground_truth`` (frame of vertex 0), ``robots`` = trajectory owner, and kinds from
        :func:`popbench.graph.robot_kinds`; ``initial == "odometry"``.

    Raises:
        ValueRangeError: an argument outside its range.
    """
    if noise == slam_maps.LEVEL:
        return slam_maps.make_problem(robots, slam_maps.level_sizes(poses_per_robot), seed)
    if isinstance(robots, bool) or not isinstance(robots, int | np.integer) or robots < 1:
        raise ValueRangeError("robots", robots, "an integer ≥ 1")
    if not isinstance(poses_per_robot, int | np.integer) or poses_per_robot < 2:
        raise ValueRangeError("poses_per_robot", poses_per_robot, "an integer ≥ 2")
    if not 0.0 <= loop_ratio <= 1.0:
        raise ValueRangeError("loop_ratio", loop_ratio, "0 to 1")
    if not loop_radius > 0.0:
        raise ValueRangeError("loop_radius", loop_radius, "> 0 m")
    sigmas = kind_sigmas(noise)
    rng = np.random.default_rng(seed)

    num_poses = robots * poses_per_robot
    # A shared square whose area grows with the number of poses keeps the density of revisits
    # (and so the supply of loop-closure candidates) similar for every team size.
    world_size = np.sqrt(num_poses) / 2.0
    walks = random_walks(rng, robots, poses_per_robot, world_size).reshape(num_poses, 3)
    truth = se2.between(walks[0], walks)  # gauge: vertex 0 at the origin
    owner = np.repeat(np.arange(robots, dtype=np.int64), poses_per_robot)

    chain_tails = np.arange(num_poses - 1)  # odometry and inter-robot relative edges
    loop_tails, loop_heads = sample_loop_closures(
        rng, truth, owner, int(round(loop_ratio * num_poses)), loop_radius
    )
    tails = np.concatenate([chain_tails, loop_tails])
    heads = np.concatenate([chain_tails + 1, loop_heads])
    kinds = robot_kinds(tails, heads, owner)

    sigma = np.repeat(sigmas[kinds][:, None], 3, axis=1)  # isotropic: one σ per edge kind
    name = f"synthetic-{noise}-R{robots}x{poses_per_robot}-seed{seed}"
    graph = slam_maps.measured_graph(
        rng, truth, tails, heads, sigma, kinds=kinds, robots=owner, name=name
    )
    return with_start(DistributedProblem(graph), "odometry")


def perturbed_start(problem: DistributedProblem, scale: float, seed: int) -> DistributedProblem:
    """``problem`` started off its odometry: the composition of the measurements, each
    perturbed by a twist ``N(0, (scale · σ)²)`` per component (σ the edge's own standard
    deviation; only the odometry chain's enter the composition). The best correction of each
    odometry step is then to undo its perturbation, which the step's residual shows: the
    sanity task of the agents' tests (a learner must map the residual to the correction).
    The start is recorded as ``"given"``.
    """
    if not scale >= 0.0:
        raise ValueRangeError("start noise", scale, "≥ 0 (standard deviations)")
    graph = problem.graph
    sigma = 1.0 / np.sqrt(np.diagonal(graph.information, axis1=1, axis2=2))
    twists = np.random.default_rng(seed).normal(size=sigma.shape) * scale * sigma
    steps = se2.compose(graph.measurements, se2.exp(twists))
    poses = odometry_composition(graph.num_poses, graph.tails, graph.heads, steps)
    return DistributedProblem(graph.replace(poses=poses), "given", problem.outlier_mask)
