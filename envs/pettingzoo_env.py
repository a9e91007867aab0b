"""PettingZoo ``ParallelEnv`` of the multi-agent PGO task: :class:`envs.core.PGOCore`, ``B = 1``.

Agents are ``"agent_0" .. "agent_{n-1}"`` (robot ``i``), so TorchRL's ``PettingZooWrapper`` groups
them into one group ``"agent"``. Per agent:

* observation: a ``Dict`` of ``Box`` arrays — ``node_features (V, 6)``, ``edge_index (2, E)``
  int64, ``edge_attr (E, 11)``, ``residuals (E, 3)`` float32, the masks ``node_mask (V,)``,
  ``edge_mask (E,)``, ``processed (E,)`` as int8 0/1 and, with ``base="gauss-newton"``,
  ``base_step (E, 3)`` and ``base_model (E, 9)`` float32 (see :meth:`PGOCore.observation`);
* action: ``Dict(edge=Discrete(E + 1), delta=Box(−Δmax, Δmax, (3,)))``; ``edge = E`` is the
  no-op, valid only once the agent has processed all its local edges;
* info: ``"action_mask"`` — ``{"edge": int8 (E + 1,), "delta": None}``, gymnasium's mask of a
  ``Dict`` action space, so ``action_space(agent).sample(mask=info["action_mask"])`` draws a
  valid edge (``action_mask=False`` leaves it out: TorchRL 0.14's ``PettingZooWrapper`` reads
  an ``action_mask`` only for a ``Discrete`` action and fails on this one; docs/environment.md).

An invalid edge choice raises by default; ``invalid_edge="repair"`` replaces it by the agent's
lowest-index unprocessed edge and says so in ``infos[agent]["repaired"]``. Every agent
terminates on the same last step, after exactly ``max_i |E_i|`` steps.

``state()`` is the team's global state, every agent's observation stacked (``state_space``:
the observation's arrays with a leading ``n``), what a centralised critic reads.
``render_mode="rgb_array"``: ``render()`` draws every robot's local graph at its own current
estimate, one colour per robot (matplotlib, Agg), an ``(H, W, 3)`` uint8 array.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from gymnasium import spaces
from pettingzoo import ParallelEnv

from envs.basestep import MODEL_FEATURES
from envs.core import DEFAULT_DELTA_MAX, PGOCore
from envs.observation import EDGE_FEATURES, NODE_FEATURES, Dimensions
from envs.sampler import ProblemSampler, ProblemSource

_MASKS = ("node_mask", "edge_mask", "processed")
RENDER_SIZE = (6.0, 6.0, 80)  # render(): figure width, height [inches], dots per inch


class PGOParallelEnv(ParallelEnv):
    """One PGO problem at a time, all robots acting simultaneously (paper §III-B).

    Args:
        source: ``seed -> DistributedProblem`` with ``num_agents`` robots fitting ``dims``.
        num_agents: robots ``n``.
        dims: padding maxima.
        seed: seed of the problem stream (``reset(seed=...)`` restarts it).
        delta_max: ``Δmax`` (δx [m], δy [m], δθ [rad]).
        reward: ``"localisation"`` or ``"F"``.
        invalid_edge: ``"raise"`` (default) or ``"repair"`` (module docstring).
        action_mask: put ``"action_mask"`` in the infos (module docstring).
        render_mode: ``None`` or ``"rgb_array"``.
        modes: ``correction``, ``observation``, ``action_scale``, ``place_separators``,
            ``base``, ``terminal_bonus`` of :class:`envs.core.PGOCore`.
    """

    metadata = {
        "name": "popbench_pgo_v0",
        "is_parallelizable": True,
        "render_modes": ["rgb_array"],
    }

    def __init__(
        self,
        source: ProblemSource,
        num_agents: int,
        dims: Dimensions,
        seed: int = 0,
        delta_max: Sequence[float] = DEFAULT_DELTA_MAX,
        reward: str = "localisation",
        invalid_edge: str = "raise",
        action_mask: bool = True,
        render_mode: str | None = None,
        **modes: str | bool | None,
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            from popbench.errors import ValueRangeError

            raise ValueRangeError("render_mode", render_mode, "None, 'rgb_array'")
        self.core = PGOCore(num_agents, dims, 1, delta_max, reward, invalid_edge, **modes)  # type: ignore[arg-type]
        self.render_mode, self.with_action_mask = render_mode, action_mask
        self.sampler = ProblemSampler(source, 1, seed, dims)
        self.dims = dims
        self.delta_max = self.core.action_bound.numpy().astype(np.float32)
        self.possible_agents = [f"agent_{index}" for index in range(num_agents)]
        self.agents: list[str] = []
        # PettingZoo wants the very same space object on every call for an agent.
        self._observation_space = self._make_observation_space()
        self._action_space = self._make_action_space()
        self.state_space = spaces.Dict(
            {
                key: spaces.Box(
                    np.broadcast_to(space.low, (num_agents, *space.shape)),
                    np.broadcast_to(space.high, (num_agents, *space.shape)),
                    (num_agents, *space.shape),
                    space.dtype,
                )
                for key, space in self._observation_space.spaces.items()
            }
        )

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

        arrays = {
            "node_features": real(v, NODE_FEATURES),
            "node_mask": flag(v),
            "edge_index": spaces.Box(0, max(v - 1, 0), (2, e), np.int64),
            "edge_attr": real(e, EDGE_FEATURES),
            "edge_mask": flag(e),
            "processed": flag(e),
            "residuals": real(e, 3),
        }
        if self.core.modes.base == "gauss-newton":
            arrays["base_step"] = real(e, 3)
            arrays["base_model"] = real(e, MODEL_FEATURES)
        return spaces.Dict(arrays)

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
        self._last = self._observations()
        return self._last, self._infos(repaired)

    def step(self, actions: dict[str, dict]) -> tuple[dict, dict, dict, dict, dict]:
        n = len(self.possible_agents)
        edge = np.full(n, -1, np.int64)  # a missing action is invalid: repaired or refused
        delta = np.zeros((n, 3), np.float32)
        for index, agent in enumerate(self.possible_agents):
            if agent in actions:
                edge[index] = int(actions[agent]["edge"])
                delta[index] = actions[agent]["delta"]
        result = self.core.step(torch.from_numpy(edge)[None], torch.from_numpy(delta)[None])
        observations = self._last = self._observations()
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
        infos: dict[str, dict] = {agent: {} for agent in self.possible_agents}
        for index, agent in enumerate(self.possible_agents):
            if self.with_action_mask:
                infos[agent]["action_mask"] = {"edge": mask[index], "delta": None}
            if self.core.invalid_edge == "repair":
                infos[agent]["repaired"] = np.int8(repaired[index])
        return infos

    def state(self) -> dict[str, np.ndarray]:
        """The team's global state: every agent's last observation, stacked (``state_space``)."""
        return {
            key: np.stack([self._last[agent][key] for agent in self.possible_agents])
            for key in self.state_space.spaces
        }

    def render(self) -> np.ndarray | None:
        """``render_mode="rgb_array"``: an ``(H, W, 3)`` uint8 image of every robot's local
        graph at its own current estimate (edges processed this episode drawn solid, the others
        faint; owned poses as dots), one colour per robot; ``None`` without a render mode."""
        if self.render_mode is None:
            return None
        from envs.render import draw_local_graphs

        arrays = {
            key: getattr(self.core.state, key)[0].cpu().numpy()
            for key in ("tails", "heads", "processed", "num_edges", "owned")
        }
        return draw_local_graphs(self.local_poses(), arrays, RENDER_SIZE)

    def local_poses(self) -> list[np.ndarray]:
        """Each agent's current local pose copy (rows in ``problem.local_vertices(r)`` order);
        ``self.core.problems[0]`` is the problem."""
        return self.core.local_poses(0)
