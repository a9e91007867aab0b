"""TorchRL multi-agent PGO environment over :class:`envs.core.PGOCore`.

Tensordict layout (``B`` = env batch, ``n`` agents, ``V``/``E`` padding maxima)::

    ("agents", "observation", <key>)   (B, n, ...)   see PGOCore.observation
    ("agents", "action_mask")          (B, n, E+1)   bool: valid edge choices (E = no-op)
    ("agents", "action", "edge")       (B, n)        int64 Categorical(E+1, mask=action_mask)
    ("agents", "action", "delta")      (B, n, 3)     float32 Bounded(−Δmax, Δmax)
    ("agents", "reward")               (B, n, 1)     float32
    ("agents", "done"/"terminated")    (B, n, 1)     bool, the episode end broadcast to agents
    "done" / "terminated"              (B, 1)        bool, every local edge was processed

With ``labels=True`` (training only: the labels are privileged) every reset and step also writes
the labels of the state it leaves, outside the observation (a policy reads only the
observation's keys)::

    ("agents", "labels", "right")          (B, n, E+1)  bool: edges the expert counts as right
    ("agents", "labels", "expert_edge")    (B, n)       int64: the expert's edge
    ("agents", "labels", "expert_delta")   (B, n, 3)    float32: the actor output that executes
                                                        the expert's Δ on it (envs.expert)
    ("agents", "labels", "outlier")        (B, n, E)    bool: the edge is an injected outlier

so a transition in a replay buffer carries the labels of its state (behaviour cloning and the
supervised gate loss of agents.loss read them there).

The edge spec's mask is updated after every reset and step, so ``env.rand_action()`` (and
``check_env_specs``) draw only valid edges. Episodes end by termination (the horizon is part of the
task), never by truncation.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from envs.basestep import MODEL_FEATURES
from envs.core import DEFAULT_DELTA_MAX, PGOCore
from envs.observation import EDGE_FEATURES, NODE_FEATURES, Dimensions
from envs.sampler import ProblemSampler, ProblemSource


class PGOEnv(EnvBase):
    """Batched multi-agent PGO environment (paper §III-B); one agent per robot.

    Args:
        source: ``seed -> DistributedProblem`` (every problem must have ``num_agents`` robots
            and fit ``dims``).
        num_agents: robots per problem ``n``.
        dims: padding maxima (see :func:`envs.make_torchrl_env` for how they are chosen).
        batch_size: number of independent problems ``B``.
        seed: seed of the problem streams (``_set_seed`` restarts them).
        device: torch device of the state and the tensordicts.
        delta_max: ``Δmax`` (δx [m], δy [m], δθ [rad]).
        reward: ``"localisation"`` (ground-truth χ², default) or ``"F"``.
        invalid_edge: ``"raise"`` or ``"repair"`` (see :class:`envs.core.PGOCore`).
        dtype: floating dtype of the pose state.
        labels: also write the expert's and the outlier labels (module docstring).
        modes: ``correction``, ``observation``, ``action_scale``, ``place_separators``, ``base``
            of :class:`envs.core.PGOCore`.
    """

    def __init__(
        self,
        source: ProblemSource,
        num_agents: int,
        dims: Dimensions,
        batch_size: int = 32,
        seed: int = 0,
        device: torch.device | str = "cpu",
        delta_max: Sequence[float] = DEFAULT_DELTA_MAX,
        reward: str = "localisation",
        invalid_edge: str = "raise",
        dtype: torch.dtype = torch.float64,
        labels: bool = False,
        **modes: str | bool | None,
    ) -> None:
        super().__init__(device=device, batch_size=torch.Size([batch_size]))
        self.num_agents, self.dims = num_agents, dims
        self.core = PGOCore(
            num_agents,
            dims,
            batch_size,
            delta_max,
            reward,
            invalid_edge,
            self.device,
            dtype,
            **modes,  # type: ignore[arg-type]
        )
        self.sampler = ProblemSampler(source, batch_size, seed)
        self.expert = None
        if labels:
            from envs.expert import Expert

            self.expert = Expert(self.core)
        self._make_specs()

    # -- specs -----------------------------------------------------------------------------------

    def _make_specs(self) -> None:
        b, n = self.batch_size[0], self.num_agents
        v, e = self.dims.vertices, self.dims.edges
        device = self.device

        def flag(*shape: int) -> Categorical:
            return Categorical(2, (b, n, *shape), dtype=torch.bool, device=device)

        def real(*shape: int) -> Unbounded:
            return Unbounded((b, n, *shape), dtype=torch.float32, device=device)

        observation = Composite(
            node_features=real(v, NODE_FEATURES),
            node_mask=flag(v),
            edge_index=Bounded(0, max(v - 1, 0), (b, n, 2, e), dtype=torch.int64, device=device),
            edge_attr=real(e, EDGE_FEATURES),
            edge_mask=flag(e),
            processed=flag(e),
            residuals=real(e, 3),
            shape=(b, n),
            device=device,
        )
        if self.core.base == "gauss-newton":
            observation["base_step"] = real(e, 3)
            observation["base_model"] = real(e, MODEL_FEATURES)
        agents = Composite(
            observation=observation, action_mask=flag(e + 1), shape=(b, n), device=device
        )
        if self.expert is not None:
            agents["labels"] = Composite(
                right=flag(e + 1),
                expert_edge=Bounded(0, e, (b, n), dtype=torch.int64, device=device),
                expert_delta=real(3),
                outlier=flag(e),
                shape=(b, n),
                device=device,
            )
        self.observation_spec = Composite(agents=agents, shape=(b,), device=device)
        limit = self.core.action_bound.to(torch.float32).expand(b, n, 3).clone()
        action = Composite(
            edge=Categorical(
                e + 1,
                (b, n),
                dtype=torch.int64,
                device=device,
                mask=torch.ones(b, n, e + 1, dtype=torch.bool, device=device),
            ),
            delta=Bounded(-limit, limit, (b, n, 3), dtype=torch.float32, device=device),
            shape=(b, n),
            device=device,
        )
        self.full_action_spec = Composite(
            agents=Composite(action=action, shape=(b, n), device=device),
            shape=(b,),
            device=device,
        )
        self.full_reward_spec = Composite(
            agents=Composite(reward=real(1), shape=(b, n), device=device),
            shape=(b,),
            device=device,
        )
        root_flag = Categorical(2, (b, 1), dtype=torch.bool, device=device)
        self.full_done_spec = Composite(
            done=root_flag.clone(),
            terminated=root_flag.clone(),
            agents=Composite(done=flag(1), terminated=flag(1), shape=(b, n), device=device),
            shape=(b,),
            device=device,
        )

    def _edge_spec(self) -> Categorical:
        return self.full_action_spec["agents", "action", "edge"]

    # -- EnvBase hooks ---------------------------------------------------------------------------

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: object) -> TensorDict:
        elements = self._elements_to_reset(tensordict)
        problems = [self.sampler.draw(element) for element in elements]
        self.core.load(problems, elements)
        done = self.core.state.remaining.sum(-1) == 0
        return self._output(done, reward=None)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        action = tensordict["agents", "action"]
        result = self.core.step(action["edge"], action["delta"])
        return self._output(result.done, reward=result.reward)

    def _set_seed(self, seed: int | None) -> None:
        self.sampler.seed(0 if seed is None else seed)

    # -- helpers ---------------------------------------------------------------------------------

    def _elements_to_reset(self, tensordict: TensorDictBase | None) -> list[int]:
        """Batch elements flagged by ``"_reset"`` (root ``(B, 1)`` or ``("agents", "_reset")``
        ``(B, n, 1)``); every element when there is no flag or no state yet."""
        every = list(range(self.batch_size[0]))
        if tensordict is None or not self.core.loaded:
            return every
        flags = tensordict.get("_reset", None)
        if flags is None:
            agent_flags = tensordict.get(("agents", "_reset"), None)
            if agent_flags is None:
                return every
            flags = agent_flags.reshape(self.batch_size[0], -1).any(-1)
        return flags.reshape(-1).nonzero().flatten().tolist()

    def _output(self, done: torch.Tensor, reward: torch.Tensor | None) -> TensorDict:
        b, n = self.batch_size[0], self.num_agents
        mask = self.core.action_mask()
        self._edge_spec().update_mask(mask)
        root_done = done.reshape(b, 1)
        agent_done = root_done.unsqueeze(1).expand(b, n, 1).clone()
        agents = TensorDict(
            {
                "observation": TensorDict(self.core.observation(), batch_size=(b, n)),
                "action_mask": mask,
                "done": agent_done,
                "terminated": agent_done.clone(),
            },
            batch_size=(b, n),
            device=self.device,
        )
        if reward is not None:
            agents["reward"] = reward.to(torch.float32).unsqueeze(-1)
        if self.expert is not None:
            agents["labels"] = self._labels()
        return TensorDict(
            {"agents": agents, "done": root_done.clone(), "terminated": root_done.clone()},
            batch_size=(b,),
            device=self.device,
        )

    @torch.no_grad()
    def _labels(self) -> TensorDict:
        """The labels of the current state (module docstring), ``(B, n)``."""
        b, n, e = self.batch_size[0], self.num_agents, self.dims.edges
        edge = self.expert.edge()
        return TensorDict(
            {
                "right": self.expert.right_edges(),
                "expert_edge": edge,
                "expert_delta": self.expert.actor_delta(edge),
                "outlier": self.core.state.outlier[..., :e].clone(),
            },
            batch_size=(b, n),
            device=self.device,
        )

    def local_poses(self, element: int) -> list:
        """Each agent's current local pose copy of batch element ``element`` (numpy, rows in
        ``problem.local_vertices(r)`` order); ``self.core.problems[element]`` is its problem."""
        return self.core.local_poses(element)
