"""PettingZoo ``ParallelEnv`` of the multi-agent PGO task: :class:`envs.core.PGOCore`, ``B = 1``.

Agents are ``"agent_0" .. "agent_{n-1}"`` (robot ``i``), so TorchRL's ``PettingZooWrapper`` groups
them into one group ``"agent"``. Per agent:

* observation: a ``Dict`` of ``Box`` arrays — ``node_features (V, 6)``, ``edge_index (2, E)``
  int64, ``edge_attr (E, 11)``, ``residuals (E, 3)`` float32 and the masks ``node_mask (V,)``,
  ``edge_mask (E,)``, ``processed (E,)`` as int8 0/1 (see :meth:`PGOCore.observation`);
* action: ``Dict(edge=Discrete(E + 1), delta=Box(−Δmax, Δmax, (3,)))``; ``edge = E`` is the
  no-op, valid only once the agent has processed all its local edges;
* info: ``"edge_action_mask"`` — the valid edge choices, int8 ``(E + 1,)`` (the action mask).

Invalid edge choices (e.g. from ``action_space.sample()``) are repaired by default: replaced by the
agent's lowest-index unprocessed edge, so the episode still ends after exactly ``max_i |E_i|``
steps; ``infos[agent]["repaired"]`` says when it happened. Every agent terminates on the same
last step.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from gymnasium import spaces
from pettingzoo import ParallelEnv

from envs.core import DEFAULT_DELTA_MAX, PGOCore
from envs.observation import EDGE_FEATURES, NODE_FEATURES, Dimensions
from envs.sampler import ProblemSampler, ProblemSource

_MASKS = ("node_mask", "edge_mask", "processed")


class PGOParallelEnv(ParallelEnv):
    """One PGO problem at a time, all robots acting simultaneously (paper §III-B).

    Args:
        source: ``seed -> DistributedProblem`` with ``num_agents`` robots fitting ``dims``.
        num_agents: robots ``n``.
        dims: padding maxima.
        seed: seed of the problem stream (``reset(seed=...)`` restarts it).
        delta_max: ``Δmax`` (δx [m], δy [m], δθ [rad]).
        reward: ``"localisation"`` or ``"F"``.
        invalid_edge: ``"repair"`` (default) or ``"raise"``.
        modes: ``correction``, ``observation``, ``action_scale``, ``place_separators`` of
            :class:`envs.core.PGOCore`.
    """

    metadata = {"name": "popbench_pgo_v0", "is_parallelizable": True}

    def __init__(
        self,
        source: ProblemSource,
        num_agents: int,
        dims: Dimensions,
        seed: int = 0,
        delta_max: Sequence[float] = DEFAULT_DELTA_MAX,
        reward: str = "localisation",
        invalid_edge: str = "repair",
        **modes: str | bool | None,
    ) -> None:
        self.core = PGOCore(num_agents, dims, 1, delta_max, reward, invalid_edge, **modes)  # type: ignore[arg-type]
        self.sampler = ProblemSampler(source, 1, seed)
        self.dims = dims
        self.delta_max = self.core.action_bound.numpy().astype(np.float32)
        self.possible_agents = [f"agent_{index}" for index in range(num_agents)]
        self.agents: list[str] = []
        # PettingZoo wants the very same space object on every call for an agent.
        self._observation_space = self._make_observation_space()
        self._action_space = self._make_action_space()

    def observation_space(self, agent: str) -> spaces.Dict:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Dict:
        return self._action_space

    def _make_observation_space(self) -> spaces.Dict:
        v, e = self.dims.vertices, self.dims.edges

        def real(*shape: int) -> spaces.Box:
            return spaces.Box(-np.inf, np.inf, shape, np.float32)

        def flag(size: int) -> spaces.Box:
            return spaces.Box(0, 1, (size,), np.int8)

        return spaces.Dict(
            {
                "node_features": real(v, NODE_FEATURES),
                "node_mask": flag(v),
                "edge_index": spaces.Box(0, max(v - 1, 0), (2, e), np.int64),
                "edge_attr": real(e, EDGE_FEATURES),
                "edge_mask": flag(e),
                "processed": flag(e),
                "residuals": real(e, 3),
            }
        )

    def _make_action_space(self) -> spaces.Dict:
        return spaces.Dict(
            {
                "edge": spaces.Discrete(self.dims.edges + 1),
                "delta": spaces.Box(-self.delta_max, self.delta_max, (3,), np.float32),
            }
        )

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, dict], dict[str, dict]]:
        if seed is not None:
            self.sampler.seed(seed)
        self.core.load([self.sampler.draw(0)], [0])
        self.agents = list(self.possible_agents)
        repaired = np.zeros(len(self.possible_agents), bool)
        return self._observations(), self._infos(repaired)

    def step(self, actions: dict[str, dict]) -> tuple[dict, dict, dict, dict, dict]:
        n = len(self.possible_agents)
        edge = np.full(n, -1, np.int64)  # a missing action is invalid: repaired or refused
        delta = np.zeros((n, 3), np.float32)
        for index, agent in enumerate(self.possible_agents):
            if agent in actions:
                edge[index] = int(actions[agent]["edge"])
                delta[index] = actions[agent]["delta"]
        result = self.core.step(torch.from_numpy(edge)[None], torch.from_numpy(delta)[None])
        observations = self._observations()
        rewards = dict(zip(self.possible_agents, result.reward[0].tolist(), strict=True))
        done = bool(result.done[0])
        terminations = dict.fromkeys(self.possible_agents, done)
        truncations = dict.fromkeys(self.possible_agents, False)
        infos = self._infos(result.repaired[0].numpy())
        if done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _observations(self) -> dict[str, dict[str, np.ndarray]]:
        arrays = {key: value[0].cpu().numpy() for key, value in self.core.observation().items()}
        for key in _MASKS:
            arrays[key] = arrays[key].astype(np.int8)
        return {
            agent: {key: value[index] for key, value in arrays.items()}
            for index, agent in enumerate(self.possible_agents)
        }

    def _infos(self, repaired: np.ndarray) -> dict[str, dict]:
        mask = self.core.action_mask()[0].cpu().numpy().astype(np.int8)
        return {
            agent: {"edge_action_mask": mask[index], "repaired": np.int8(repaired[index])}
            for index, agent in enumerate(self.possible_agents)
        }

    def local_poses(self) -> list[np.ndarray]:
        """Each agent's current local pose copy (rows in ``problem.local_vertices(r)`` order);
        ``self.core.problems[0]`` is the problem."""
        return self.core.local_poses(0)
