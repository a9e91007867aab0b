"""TorchRL multi-agent PGO environment over :class:`envs.core.PGOCore`.

Tensordict layout (``B`` = env batch, ``n`` agents, ``V``/``E`` padding maxima)::

    ("agents", "observation", <key>)   (B, n, ...)   see PGOCore.observation
    ("agents", "action_mask")          (B, n, E+1)   bool: valid edge choices (E = no-op)
    ("agents", "action", "edge")       (B, n)        int64 Categorical(E+1), masked (below)
    ("agents", "action", "delta")      (B, n, 3)     float32 Bounded(−Δmax, Δmax)
    ("agents", "reward")               (B, n, 1)     float32
    ("agents", "done"/"terminated")    (B, n, 1)     bool, the episode end broadcast to agents
    "done" / "terminated"              (B, 1)        bool, every local edge was processed
    ("agents", "repaired")             (B, n, 1)     bool, ``invalid_edge="repair"`` only: the
                                                     agent's edge choice was replaced

``batch_size=()`` drops the leading ``B`` (one problem, unbatched). ``env.group_map`` is
``{"agents": ["agent_0", …]}`` (TorchRL's multi-agent grouping: one group, all robots).

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

The edge spec (:class:`envs.edge_spec.SharedMaskCategorical`) is rewritten in place from
``("agents", "action_mask")`` after every reset and step, and every copy of it shares the
buffer, so ``env.rand_action()``, ``RandomPolicy(env.full_action_spec)``, ``Collector(env,
None)``, transforms and ``check_env_specs`` draw only valid edges. A batched env
(``SerialEnv``/``ParallelEnv``) needs :func:`edge_mask_transform` over it (docs/environment.md).
An invalid edge raises by default (``invalid_edge="raise"``); ``"repair"`` replaces it and says
so in ``("agents", "repaired")``. Episodes end by termination (the horizon is part of the task),
never by truncation.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from envs.basestep import MODEL_FEATURES
from envs.core import DEFAULT_DELTA_MAX, PGOCore
from envs.edge_spec import EdgeActionMask, SharedMaskCategorical
from envs.observation import EDGE_FEATURES, NODE_FEATURES, Dimensions
from envs.sampler import ProblemSampler, ProblemSource

GROUP = "agents"
EDGE_ACTION_KEY = (GROUP, "action", "edge")
ACTION_MASK_KEY = (GROUP, "action_mask")


def edge_mask_transform() -> EdgeActionMask:
    """TorchRL's ``ActionMask`` pattern for this env's edge choice
    (:class:`envs.edge_spec.EdgeActionMask`): put it over a ``SerialEnv`` / ``ParallelEnv`` of
    :class:`PGOEnv` (whose spec is a copy that cannot follow its workers) so that random draws
    from the batched env's spec see the workers' ``("agents", "action_mask")``."""
    return EdgeActionMask(EDGE_ACTION_KEY, ACTION_MASK_KEY)


class PGOEnv(EnvBase):
    """Batched multi-agent PGO environment (paper §III-B); one agent per robot.

    Args:
        source: ``seed -> DistributedProblem`` (every problem must have ``num_agents`` robots
            and fit ``dims``).
        num_agents: robots per problem ``n``.
        dims: padding maxima (see :func:`envs.make_torchrl_env` for how they are chosen).
        batch_size: number of independent problems ``B``, or ``()``: one problem, unbatched.
        seed: seed of the problem streams (``_set_seed`` restarts them).
        device: torch device of the state and the tensordicts.
        delta_max: ``Δmax`` (δx [m], δy [m], δθ [rad]).
        reward: ``"localisation"`` (ground-truth χ², default) or ``"F"``.
        invalid_edge: ``"raise"`` (default: a processed or padding edge, or the no-op while
            edges remain, is an error) or ``"repair"`` (replaced by the agent's lowest-index
            unprocessed edge, flagged in ``("agents", "repaired")``; :class:`envs.core.PGOCore`).
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
        batch_size: int | Sequence[int] = 32,
        seed: int = 0,
        device: torch.device | str = "cpu",
        delta_max: Sequence[float] = DEFAULT_DELTA_MAX,
        reward: str = "localisation",
        invalid_edge: str = "raise",
        dtype: torch.dtype = torch.float64,
        labels: bool = False,
        **modes: str | bool | None,
    ) -> None:
        shape = torch.Size([batch_size] if isinstance(batch_size, int) else batch_size)
        if len(shape) > 1:
            from popbench.errors import ValueRangeError

            raise ValueRangeError("batch_size", tuple(shape), "an int B or () (unbatched)")
        super().__init__(device=device, batch_size=shape)
        self.num_agents, self.dims = num_agents, dims
        self.problems = shape.numel()  # B of the core: 1 when unbatched
        self.group_map = {GROUP: [f"agent_{index}" for index in range(num_agents)]}
        self.core = PGOCore(
            num_agents,
            dims,
            self.problems,
            delta_max,
            reward,
            invalid_edge,
            self.device,
            dtype,
            **modes,  # type: ignore[arg-type]
        )
        self.sampler = ProblemSampler(source, self.problems, seed, dims)
        self.expert = None
        if labels:
            from envs.expert import Expert

            self.expert = Expert(self.core)
        self._make_specs()

    # -- specs -----------------------------------------------------------------------------------

    def _make_specs(self) -> None:
        lead, n = tuple(self.batch_size), self.num_agents
        b = (*lead, n)  # the agents' leading shape
        v, e = self.dims.vertices, self.dims.edges
        device = self.device

        def flag(*shape: int) -> Categorical:
            return Categorical(2, (*b, *shape), dtype=torch.bool, device=device)

        def real(*shape: int) -> Unbounded:
            return Unbounded((*b, *shape), dtype=torch.float32, device=device)

        observation = Composite(
            node_features=real(v, NODE_FEATURES),
            node_mask=flag(v),
            edge_index=Bounded(0, max(v - 1, 0), (*b, 2, e), dtype=torch.int64, device=device),
            edge_attr=real(e, EDGE_FEATURES),
            edge_mask=flag(e),
            processed=flag(e),
            residuals=real(e, 3),
            shape=b,
            device=device,
        )
        if self.core.modes.base == "gauss-newton":
            observation["base_step"] = real(e, 3)
            observation["base_model"] = real(e, MODEL_FEATURES)
        agents = Composite(observation=observation, action_mask=flag(e + 1), shape=b, device=device)
        if self.core.invalid_edge == "repair":
            agents["repaired"] = flag(1)
        if self.expert is not None:
            agents["labels"] = Composite(
                right=flag(e + 1),
                expert_edge=Bounded(0, e, b, dtype=torch.int64, device=device),
                expert_delta=real(3),
                outlier=flag(e),
                shape=b,
                device=device,
            )
        self.observation_spec = Composite({GROUP: agents}, shape=lead, device=device)
        limit = self.core.action_bound.to(torch.float32).expand(*b, 3).clone()
        action = Composite(
            edge=SharedMaskCategorical(e + 1, b, device, torch.int64),
            delta=Bounded(-limit, limit, (*b, 3), dtype=torch.float32, device=device),
            shape=b,
            device=device,
        )
        self.full_action_spec = Composite(
            {GROUP: Composite(action=action, shape=b, device=device)}, shape=lead, device=device
        )
        self.full_reward_spec = Composite(
            {GROUP: Composite(reward=real(1), shape=b, device=device)}, shape=lead, device=device
        )
        root_flag = Categorical(2, (*lead, 1), dtype=torch.bool, device=device)
        self.full_done_spec = Composite(
            {
                "done": root_flag.clone(),
                "terminated": root_flag.clone(),
                GROUP: Composite(done=flag(1), terminated=flag(1), shape=b, device=device),
            },
            shape=lead,
            device=device,
        )
        self._edge_spec = self.full_action_spec[EDGE_ACTION_KEY]

    # -- EnvBase hooks ---------------------------------------------------------------------------

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: object) -> TensorDict:
        elements = self._elements_to_reset(tensordict)
        problems = [self.sampler.draw(element) for element in elements]
        self.core.load(problems, elements)
        done = self.core.state.remaining.sum(-1) == 0
        return self._output(done, reward=None)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        action = tensordict[GROUP, "action"]
        result = self.core.step(action["edge"], action["delta"])
        return self._output(result.done, reward=result.reward, repaired=result.repaired)

    def _set_seed(self, seed: int | None) -> None:
        self.sampler.seed(0 if seed is None else seed)

    # -- helpers ---------------------------------------------------------------------------------

    def _elements_to_reset(self, tensordict: TensorDictBase | None) -> list[int]:
        """Batch elements flagged by ``"_reset"`` (root ``(B, 1)`` or ``("agents", "_reset")``
        ``(B, n, 1)``); every element when there is no flag or no state yet."""
        every = list(range(self.problems))
        if tensordict is None or not self.core.loaded:
            return every
        flags = tensordict.get("_reset", None)
        if flags is None:
            agent_flags = tensordict.get((GROUP, "_reset"), None)
            if agent_flags is None:
                return every
            flags = agent_flags.reshape(self.problems, -1).any(-1)
        return flags.reshape(-1).nonzero().flatten().tolist()

    def _output(
        self,
        done: torch.Tensor,
        reward: torch.Tensor | None,
        repaired: torch.Tensor | None = None,
    ) -> TensorDict:
        b, n = self.problems, self.num_agents
        mask = self.core.action_mask()
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
        if self.core.invalid_edge == "repair":
            flags = torch.zeros(b, n, dtype=torch.bool) if repaired is None else repaired
            agents["repaired"] = flags.to(self.device).unsqueeze(-1)
        if self.expert is not None:
            agents["labels"] = self._labels()
        out = TensorDict(
            {GROUP: agents, "done": root_done.clone(), "terminated": root_done.clone()},
            batch_size=(b,),
            device=self.device,
        )
        if not self.batch_size:
            out = out.squeeze(0)
        self._edge_spec.update_mask(out.get(ACTION_MASK_KEY))
        return out

    @torch.no_grad()
    def _labels(self) -> TensorDict:
        """The labels of the current state (module docstring), ``(B, n)``."""
        b, n = self.problems, self.num_agents
        edge = self.expert.edge()
        return TensorDict(
            {
                "right": self.expert.right_edges(),
                "expert_edge": edge,
                "expert_delta": self.expert.actor_delta(edge),
                "outlier": self.core.state.outlier[..., : self.dims.edges].clone(),
            },
            batch_size=(b, n),
            device=self.device,
        )

    def local_poses(self, element: int) -> list:
        """Each agent's current local pose copy of batch element ``element`` (numpy, rows in
        ``problem.local_vertices(r)`` order); ``self.core.problems[element]`` is its problem."""
        return self.core.local_poses(element)
