"""Batched torch core of the multi-agent PGO environment (paper §III-B; docs/environment.md).

One :class:`PGOCore` holds ``B`` independent problems of ``n`` robots (agents), behind the TorchRL
env (:mod:`envs.torchrl_env`, any ``B``) and the PettingZoo env (:mod:`envs.pettingzoo_env`,
``B = 1``); what the actor observes of it is read by :mod:`envs.readout`.

State layout: local copies
    Agent ``i`` holds its local graph (:class:`popbench.problems.distributed.LocalGraph`: owned
    vertices, then separator copies; every edge with at least one owned endpoint) and its *own copy*
    of the estimates of those vertices. A separator pose is therefore duplicated in several agents'
    copies and a move by one agent never touches another agent's copy: simultaneous actions never
    conflict, each agent's step costs O(degree of the moved vertex), and reconciling the copies
    is the consensus step that runs after the episode (paper Fig. 1;
    :mod:`popbench.consensus.admm`).

Padding: every agent's graph is padded to ``V`` vertices, ``E`` edges and ``D`` incident edges per
vertex (:class:`Dimensions`); one extra *trash* vertex (index ``V``) and edge slot (index ``E``)
absorb the writes of padding and of the no-op action, so a step is branch-free.

Action (per agent)
    ``edge`` ∈ {0..E}: a local edge ``p → q`` not processed yet; ``E`` is the *no-op*, valid only
    once every local edge of the agent was processed (agents with fewer edges than the longest one
    wait with it). ``delta = (δx [m], δy [m], δθ [rad])`` clipped to ``|δ| ≤ Δmax`` componentwise.
    The correction moves the head ``q`` in the tail's frame (eq. C; :mod:`envs.correction`)::

        x_q ← x_p ∘ (between(x_p, x_q) + Δ),     angle wrapped to [−π, π)

    i.e. the relative pose of ``q`` seen from ``p`` changes by exactly ``Δ``; ``x_p`` stays. The
    edge is then marked processed. Default ``Δmax = (0.5 m, 0.5 m, 0.3 rad)`` (why:
    docs/environment.md, "The action bound").

Modes (correction, observation, action scale, base step): see :class:`PGOCore`.
Reward (per agent, per step): the relative drop of its localisation error ``L`` (against ground
truth, or F with ``reward="F"``) plus a terminal bonus (docs/environment.md, "Localisation error").

Horizon: ``T = max_i |E_i|`` steps, so the episode ends exactly when every local edge of every
agent was processed once. Cost per step: only what the move changes is evaluated (the moved
rows, the edges at the moved vertex or crossing the moved subtree's boundary,
:func:`envs.basestep.boundary`, the chosen edge's base step); the full observation stays
O(V + E) (docs/environment.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol

import numpy as np
import torch

from envs.basestep import (
    BaseModel,
    Boundary,
    StepModes,
    base_model,
    boundary,
    chosen_model,
    chosen_step,
)
from envs.correction import (
    LINE_SEARCH_SCALES,
    candidate_changes,
    monotone_choice,
    move_subtree,
    nonmonotone_choice,
    refresh_boundary,
    refresh_edges,
    subtree_members,
)
from envs.geometry import _gather_rows, _scatter_rows, between, compose, residuals
from envs.modes import PAPER_MODES, EnvModes
from envs.observation import REWARDS, Dimensions, pack_problem, whiten_attributes
from envs.readout import ReadoutModes, chosen_base_observation, observation_changes, observe
from envs.state import DERIVED_FROM, CoreState, check_packed, derived_entries, empty_dynamics
from envs.team import TeamReward
from envs.tree import pack_trees, place_separators
from popbench.errors import ValueRangeError
from popbench.objective import edge_costs
from popbench.problems.distributed import DistributedProblem

DEFAULT_DELTA_MAX = (0.5, 0.5, 0.3)  # (δx [m], δy [m], δθ [rad])
EPSILON = 1e-6  # ε of the reward's normalisation and terminal log-ratio
INVALID_EDGE_MODES = ("raise", "repair")
WHITENED_DELTA_MAX = 5.0  # |Δ| bound [standard deviations] of the whitened action


# ----- the batched state ------------------------------------------------------------------------


class CoreTask(Protocol):
    """A record of the environment's modes (:meth:`PGOCore.for_problems`): its
    ``core_options()`` gives them as keywords (``mode: value``, envs.modes.MODE_NAMES), as
    :class:`envs.modes.EnvModes` and :class:`envs.tasks.Task` do."""

    def core_options(self) -> dict[str, str]: ...


class StepResult(NamedTuple):
    """Output of :meth:`PGOCore.step`: ``reward (B, n)``, ``done (B,)`` (the episode ended),
    ``agent_done (B, n)`` (the agent has no edge left) and ``repaired (B, n)`` (an invalid edge
    choice was replaced, ``invalid_edge="repair"`` only)."""

    reward: torch.Tensor
    done: torch.Tensor
    agent_done: torch.Tensor
    repaired: torch.Tensor


class PGOCore:
    """The batched environment state and its dynamics (see the module docstring).

    Args:
        num_agents: robots ``n`` per problem.
        dims: padding maxima.
        batch: number of independent problems ``B``.
        delta_max: ``Δmax`` (δx [m], δy [m], δθ [rad]).
        reward: ``"localisation"`` (ground truth) or ``"F"``.
        invalid_edge: ``"raise"`` (a :class:`ValueRangeError` on a processed/padding edge or on
            the no-op while edges remain) or ``"repair"`` (replace it by the agent's lowest-index
            unprocessed edge, or the no-op when none is left).
        device: torch device of every tensor.
        dtype: floating dtype of the pose state (observations are float32).
        modes: the environment's modes (:class:`envs.modes.EnvModes`; what each does:
            docs/environment.md, "Options beside the paper's"); ``mode_changes``, keywords of
            it (``step_rule="line-search"``), change single modes of it.
        place_separators: place the separator copies at each episode start (default: in the
            subtree mode only).
        terminal_bonus: add the terminal ``log`` ratio on the episode's last step (the
            paper's reward); without it the per-step rewards alone, which already telescope to
            the episode's reduction, and which a critic can read off the state.
    """

    def __init__(
        self,
        num_agents: int,
        dims: Dimensions,
        batch: int,
        delta_max: Sequence[float] = DEFAULT_DELTA_MAX,
        reward: str = "localisation",
        invalid_edge: str = "raise",
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float64,
        modes: EnvModes = PAPER_MODES,
        place_separators: bool | None = None,
        terminal_bonus: bool = True,
        **mode_changes: str,
    ) -> None:
        #: the environment's modes (envs.modes): ``modes`` with the keywords ``mode_changes``
        self.modes = modes.replace(**mode_changes) if mode_changes else modes
        modes = self.modes
        self.place = modes.correction == "subtree" if place_separators is None else place_separators
        self.terminal_bonus = terminal_bonus
        if reward not in REWARDS:
            raise ValueRangeError("reward", reward, ", ".join(REWARDS))
        if invalid_edge not in INVALID_EDGE_MODES:
            raise ValueRangeError("invalid_edge", invalid_edge, ", ".join(INVALID_EDGE_MODES))
        delta_max = tuple(float(value) for value in delta_max)
        if len(delta_max) != 3 or min(delta_max) <= 0:
            raise ValueRangeError("delta_max", delta_max, "three positive numbers")
        self.num_agents, self.dims, self.batch = num_agents, dims, batch
        self.reward_kind, self.invalid_edge = reward, invalid_edge
        self.device, self.dtype = torch.device(device), dtype
        self.delta_max = torch.tensor(delta_max, dtype=dtype, device=self.device)
        whitened = modes.action_scale == "whitened"
        #: the bound of the action's ``delta`` (its spec): Δmax, or WHITENED_DELTA_MAX
        self.action_bound = (
            torch.full((3,), WHITENED_DELTA_MAX, dtype=dtype, device=self.device)
            if whitened
            else self.delta_max
        )
        #: what the base step and the read-out need of the modes (envs.basestep, envs.readout)
        self.step_modes = StepModes(modes.correction, self.delta_max, self.action_bound, whitened)
        #: the modes of the executed base step: unbounded under the line search
        unbounded = torch.full((3,), torch.inf, dtype=dtype, device=self.device)
        self.execute_modes = (
            self.step_modes
            if modes.clips
            else StepModes(modes.correction, unbounded, unbounded, whitened)
        )
        #: the searching rules' step scales, α = 0 last (envs.correction.LINE_SEARCH_SCALES)
        self.search_scales = torch.tensor(LINE_SEARCH_SCALES, dtype=dtype, device=self.device)
        self.readout_modes = ReadoutModes(modes.observation == "invariant", whitened)
        self.problems: list[DistributedProblem | None] = [None] * batch
        #: the terminal team reward (envs.team), None under team_reward="none"
        self.team = TeamReward(modes.team_reward) if modes.team_reward != "none" else None
        self._state: CoreState | None = None
        #: what the last step rewrote: vertices ``(B·n, V+1)`` and edge slots ``(B·n, E+1)``
        self.last_moved: torch.Tensor | None = None
        self.last_refreshed: torch.Tensor | None = None
        self._base_model: BaseModel | None = None

    @classmethod
    def for_problems(
        cls,
        problems: Sequence[DistributedProblem],
        task: CoreTask | None = None,
        *,
        reward: str = "F",
        dims: Dimensions | None = None,
        **options: Any,
    ) -> PGOCore:
        """The environment's front door: a core over ``problems`` (``B = len(problems)``, their
        own robots), loaded with them.

        Args:
            problems: the problems, one per batch element, all with the same number of robots.
            task: the environment's modes: any record whose ``core_options()`` gives them
                (:class:`envs.modes.EnvModes`, :class:`envs.tasks.Task`); None: the paper's.
            reward: ``"F"`` (default: no ground truth needed) or ``"localisation"``.
            dims: padding maxima (default: the problems' own, :meth:`Dimensions.of`).
            options: further keywords of :class:`PGOCore` (``delta_max``, ``place_separators``,
                ``terminal_bonus``, ``invalid_edge``, ``device``, ``dtype``; a mode given here
                overrides the task's).
        """
        if not problems:
            raise ValueRangeError("problems", 0, "at least one problem")
        modes = PAPER_MODES if task is None else EnvModes(**task.core_options())
        dims = dims or Dimensions.of(problems)
        robots = problems[0].num_robots
        core = cls(robots, dims, len(problems), reward=reward, modes=modes, **options)
        core.load(problems, range(len(problems)))
        return core

    @property
    def state(self) -> CoreState:
        """The declared state (:class:`envs.state.CoreState`); loading problems creates it."""
        if self._state is None:
            raise RuntimeError("the core holds no problem yet: load problems first")
        return self._state

    @property
    def loaded(self) -> bool:
        """Whether problems were loaded (the state exists)."""
        return self._state is not None

    @property
    def horizon(self) -> int:
        """``T = max_i |E_i|`` over the batch: the steps after which every episode has ended."""
        return int(self.state.num_edges.max())

    # -- episode start ---------------------------------------------------------------------------

    def load(self, problems: Sequence[DistributedProblem], elements: Sequence[int]) -> None:
        """Start new episodes on the batch elements ``elements`` with ``problems``.

        Static buffers are replaced out of place (tensors handed out earlier stay valid); the
        first call must cover every element.
        """
        elements = list(elements)
        for problem in problems:
            if problem.num_robots != self.num_agents:
                raise ValueRangeError(
                    "robots", problem.num_robots, f"{self.num_agents} (this environment's agents)"
                )
        packs = []
        for problem in problems:
            start = place_separators(problem) if self.place else None
            pack = pack_problem(problem, self.dims, self.reward_kind, start)
            pack.update(pack_trees(problem, self.dims.vertices, self.dims.edges))
            if self.modes.action_scale == "whitened":
                whiten_attributes(pack)
            packs.append(pack)
        fresh = {
            key: torch.as_tensor(np.stack([pack[key] for pack in packs])).to(self.device)
            for key in packs[0]
        }
        for key, value in fresh.items():
            if value.is_floating_point() and key != "edge_attr":
                fresh[key] = value.to(self.dtype)
        if self._state is None:
            if sorted(elements) != list(range(self.batch)):
                raise ValueError("the first load must start every batch element")
            check_packed(fresh)
            order = torch.as_tensor(np.argsort(elements), device=self.device)
            packed = {key: value[order] for key, value in fresh.items()}
            dynamics = empty_dynamics(
                self.batch, self.num_agents, self.dims.edges, self.dtype, self.device
            )
            derived = derived_entries(*(packed[key] for key in DERIVED_FROM))
            self._state = CoreState(**packed, **derived, **dynamics)
        else:
            self._state.replace_elements(torch.as_tensor(elements, device=self.device), fresh)
            derived = derived_entries(*(getattr(self._state, key) for key in DERIVED_FROM))
            for key, value in derived.items():
                setattr(self._state, key, value)
        for problem, element in zip(problems, elements, strict=True):
            self.problems[element] = problem
        self._restart(torch.as_tensor(elements, device=self.device))

    def restart_at(self, element: int, poses: np.ndarray) -> None:
        """Restart the episode of batch element ``element`` with every local copy, owned or a
        separator copy, at its global value ``poses (N, 3)`` (e.g. the reconciled estimate after
        the consensus): the residuals, costs and processed flags as at an episode's start."""
        t = self.state
        ids = t.vertex_ids[element]
        local = torch.as_tensor(np.asarray(poses), dtype=self.dtype, device=self.device)
        restarted = torch.zeros_like(t.poses[element])
        restarted[:, :-1][ids >= 0] = local[ids[ids >= 0]]
        replaced = t.poses.clone()  # out of place: copies handed out earlier stay valid
        replaced[element] = restarted
        t.poses = replaced
        self._restart(torch.as_tensor([element], device=self.device))

    def _restart(self, index: torch.Tensor) -> None:
        """Recompute the dynamic buffers of the elements ``index`` from their initial poses."""
        t = self.state
        poses = t.poses[index]
        tails, heads = t.tails[index], t.heads[index]
        flat_poses = poses.flatten(0, 1)
        tail_poses = _gather_rows(flat_poses, tails.flatten(0, 1)).view(tails.shape + (3,))
        head_poses = _gather_rows(flat_poses, heads.flatten(0, 1)).view(heads.shape + (3,))
        costs = edge_costs(
            residuals(tail_poses, head_poses, t.targets[index]), t.kappa[index], t.tau[index]
        )
        processed = torch.zeros(tails.shape, dtype=torch.bool, device=self.device)
        processed[..., -1] = True  # the no-op slot
        t.residuals[index] = residuals(tail_poses, head_poses, t.measurements[index])
        t.costs[index] = costs
        t.processed[index] = processed
        t.loss[index] = costs.sum(-1)
        t.remaining[index] = t.num_edges[index]
        t.initial_loss[index] = t.loss[index]
        local_f = edge_costs(t.residuals[index], t.kappa[index], t.tau[index]).sum(-1)
        t.recent_f[index] = local_f.unsqueeze(-1).expand(-1, -1, t.recent_f.shape[-1])
        self._base_model = None
        if self.team is not None:
            self.team.started(self, index.tolist())

    # -- dynamics --------------------------------------------------------------------------------

    def action_mask(self) -> torch.Tensor:
        """``(B, n, E + 1)`` bool: unprocessed local edges, or only the no-op (index ``E``) when
        the agent has none left."""
        t = self.state
        edges_left = t.edge_mask & ~t.processed[..., :-1]
        none_left = (t.remaining == 0).unsqueeze(-1)
        return torch.cat([edges_left, none_left], -1)

    def step(self, edge: torch.Tensor, delta: torch.Tensor) -> StepResult:
        """Apply one joint action: ``edge (B, n)`` int, ``delta (B, n, 3)``."""
        t = self.state
        b, n, e = self.batch, self.num_agents, self.dims.edges
        mask = self.action_mask()
        edge = edge.to(self.device, torch.int64).reshape(b, n)
        in_range = (edge >= 0) & (edge <= e)
        chosen = torch.gather(mask, 2, edge.clamp(0, e).unsqueeze(-1)).squeeze(-1) & in_range
        repaired = ~chosen
        if self.invalid_edge == "raise":
            if bool(repaired.any()):
                bad = repaired.nonzero()[0].tolist()
                raise ValueRangeError(
                    "edge action",
                    int(edge[bad[0], bad[1]]),
                    f"an unprocessed local edge (action mask) for element {bad[0]}, agent {bad[1]}",
                )
        else:
            edge = torch.where(chosen, edge, mask.to(torch.int8).argmax(-1))
        was_done = t.remaining.sum(-1) == 0

        g = b * n
        flat_edge = edge.reshape(g, 1)
        poses = t.poses.view(g, -1, 3)
        tail = torch.gather(t.tails.view(g, -1), 1, flat_edge)  # (G, 1); no-op → trash
        head = torch.gather(t.heads.view(g, -1), 1, flat_edge)
        action = delta.to(self.device, self.dtype).reshape(g, 1, 3)
        inside = subtree_members(t, self.modes.correction, flat_edge)
        crossing = boundary(t, inside)  # the same edges before and after the move
        executed = self.metric_delta(flat_edge, action + self._base_step(flat_edge, crossing))
        if not self.modes.clips:
            candidates = executed * self.search_scales.view(1, -1, 1)  # (G, K, 3)
            if self.modes.step_rule == "search-with-clip":  # and the clip rule's own step
                clipped = action + self._base_step(flat_edge, crossing, self.step_modes)
                clipped = self.metric_delta(flat_edge, clipped, clip=True)
                candidates = torch.cat([candidates[:, :-1], clipped, candidates[:, -1:]], 1)
            executed = self._searched_step(poses, flat_edge, candidates, crossing)
        previous = t.loss.clone()
        if self.modes.correction == "subtree":
            move_subtree(t, self.modes.correction, poses, flat_edge, executed, inside)
            change = refresh_boundary(t, crossing, self.reward_kind)
            refreshed = crossing.crossing
        else:
            x_p, x_q = _gather_rows(poses, tail), _gather_rows(poses, head)
            moved = compose(x_p, between(x_p, x_q) + executed)  # eq. C
            _scatter_rows(poses, head, moved)
            incident = _gather_rows(t.incident.view(g, -1, self.dims.degree), head).squeeze(1)
            change = refresh_edges(t, incident)
            refreshed = torch.zeros(g, e + 1, dtype=torch.bool, device=self.device)
            refreshed.scatter_(1, incident, True)
        self.last_moved, self.last_refreshed = inside, refreshed
        self._base_model = None

        processed = t.processed.view(g, -1)
        processed.scatter_(1, flat_edge, True)
        t.remaining -= (edge < e).to(torch.int64)
        t.loss += change.view(b, n)
        gain = (previous - t.loss) / (previous + EPSILON)
        reward = torch.tanh(gain).clamp(-1.0, 1.0)
        agent_done = t.remaining == 0
        done = agent_done.all(-1)
        finishing = (done & ~was_done).unsqueeze(-1) & self.terminal_bonus
        bonus = torch.log((t.initial_loss + EPSILON) / (t.loss + EPSILON))
        reward = reward + torch.where(finishing, bonus, torch.zeros_like(bonus))
        if self.team is not None:
            reward = self.team.reward(self, reward, done & ~was_done)
        return StepResult(reward, done, agent_done, repaired)

    def _base_step(
        self, edge: torch.Tensor, crossing: Boundary, modes: StepModes | None = None
    ) -> torch.Tensor:
        """``(G, 1, 3)``: the Gauss–Newton base step on the edge slots ``edge (G, 1)`` in the
        executed ``modes`` (default: the rule's, unbounded unless it clips); 0 without a base."""
        if self.modes.base != "gauss-newton":
            return torch.zeros(edge.shape[0], 1, 3, dtype=self.dtype, device=self.device)
        step = chosen_step(self.state, modes or self.execute_modes, edge, crossing)
        return step.view(edge.shape[0], 1, 3)

    def _searched_step(
        self, poses: torch.Tensor, edge: torch.Tensor, candidates: torch.Tensor, crossing: Boundary
    ) -> torch.Tensor:
        """``(G, 1, 3)``: the metric correction each agent executes of its ``candidates (G, K,
        3)`` (α = 0 last) under a searching step rule; the ``nonmonotone`` rule's window of local
        F values moves on by the chosen step."""
        t = self.state
        change = candidate_changes(t, self.modes.correction, poses, edge, candidates, crossing)
        if self.modes.step_rule == "nonmonotone":
            recent = t.recent_f.view(edge.shape[0], -1)
            choice = nonmonotone_choice(change, recent)
            now = recent[:, -1] + change.gather(1, choice.unsqueeze(-1)).squeeze(-1)
            t.recent_f = torch.cat([recent[:, 1:], now.unsqueeze(-1)], -1).view_as(t.recent_f)
        else:
            choice = monotone_choice(change)
        return candidates.gather(1, choice.view(-1, 1, 1).expand(-1, 1, 3))

    def base_model(self) -> BaseModel:
        """The Gauss–Newton quadratic model of every edge slot at the current state
        (:func:`envs.basestep.base_model`), computed once per state."""
        if self._base_model is None:
            self._base_model = base_model(self.state, self.step_modes)
        return self._base_model

    def chosen_base_model(self, edge: torch.Tensor) -> BaseModel:
        """The model of each agent's ``edge (B, n)`` alone (:func:`envs.basestep.chosen_model`:
        O(the edges crossing the moved subtree's boundary)), fields ``(B·n, 1, ...)``."""
        return chosen_model(self.state, self.step_modes, *self._chosen_boundary(edge))

    def base_step(self, edge: torch.Tensor) -> torch.Tensor:
        """``(B, n, 3)`` the Gauss–Newton step Δ_GN of each agent's ``edge (B, n)`` (0 off the
        tree), in the action's units (:func:`envs.basestep.chosen_step`)."""
        step = chosen_step(self.state, self.execute_modes, *self._chosen_boundary(edge))
        return step.view(self.batch, self.num_agents, 3)

    def _chosen_boundary(self, edge: torch.Tensor) -> tuple[torch.Tensor, Boundary]:
        """The edge slots ``(B·n, 1)`` of ``edge (B, n)`` and the boundary of what a correction of
        each would move, at the current state."""
        flat_edge = edge.to(self.device, torch.int64).reshape(self.batch * self.num_agents, 1)
        inside = subtree_members(self.state, self.modes.correction, flat_edge)
        return flat_edge, boundary(self.state, inside)

    def metric_delta(
        self, edge: torch.Tensor, delta: torch.Tensor, clip: bool | None = None
    ) -> torch.Tensor:
        """The metric correction ``(G, 1, 3)`` of an action ``delta (G, 1, 3)`` on the edge slots
        ``edge (G, 1)`` (``G = B·n``): clipped to the action bound, converted back from the
        whitened units (``action_scale="whitened"``), clipped to ``Δmax``; under a searching step
        rule (``clip`` False; default: whether the rule is ``"clip"``) converted only."""
        clip = self.modes.clips if clip is None else clip
        if clip:
            delta = torch.maximum(torch.minimum(delta, self.action_bound), -self.action_bound)
        if self.modes.action_scale == "whitened":
            g = edge.shape[0]
            inverse_root = self.state.inverse_sqrt_information.view(g, -1, 3, 3)
            delta = (_gather_rows(inverse_root, edge) @ delta.unsqueeze(-1)).squeeze(-1)
        if not clip:
            return delta
        return torch.maximum(torch.minimum(delta, self.delta_max), -self.delta_max)

    def subtree_move(
        self, poses: torch.Tensor, edge: torch.Tensor, delta: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The correction, out of place: ``(moved poses (G, V+1, 3), inside (G, V+1))`` for
        ``poses (G, V+1, 3)``, edge slots ``edge (G, 1)`` and metric ``delta (G, 1, 3)``;
        ``inside``: :func:`envs.correction.subtree_members`."""
        inside = subtree_members(self.state, self.modes.correction, edge)
        moved = poses.clone()
        move_subtree(self.state, self.modes.correction, moved, edge, delta, inside)
        return moved, inside

    # -- observation (envs.readout) ---------------------------------------------------------------

    def observation(self) -> dict[str, torch.Tensor]:
        """Per-agent padded observation (:func:`envs.readout.observe`; entries and widths in
        :mod:`envs.features`)."""
        base = self.base_model() if self.modes.base == "gauss-newton" else None
        return observe(self.state, self.readout_modes, base)

    def graph_batch(self, element: int | None = None) -> dict[str, torch.Tensor]:
        """The observation and ``action_mask`` as padded graphs for a GNN (the fields of
        ``agents.encoder.GraphBatch``): leading ``(n,)`` for batch element ``element``, else
        ``(B·n,)`` for the whole batch."""
        entries = {**self.observation(), "action_mask": self.action_mask()}
        if element is not None:
            return {key: value[element] for key, value in entries.items()}
        g = self.batch * self.num_agents
        return {key: value.reshape(g, *value.shape[2:]) for key, value in entries.items()}

    def chosen_base_observation(self, edge: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(base_step (B·n, 3), base_model (B·n, 9))`` float32 of each agent's ``edge (B, n)``
        alone (:func:`envs.readout.chosen_base_observation`), O(the moved subtree's boundary)."""
        return chosen_base_observation(self.chosen_base_model(edge))

    def observation_update(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """What the last :meth:`step` may have changed in :meth:`observation`
        (:func:`envs.readout.observation_changes`)."""
        if self.last_moved is None or self.last_refreshed is None:
            raise RuntimeError("observation_update before the first step")
        return observation_changes(
            self.state, self.readout_modes, self.last_moved, self.last_refreshed
        )

    # -- read-out --------------------------------------------------------------------------------

    def local_poses(self, element: int) -> list[np.ndarray]:
        """Each agent's current local copy ``(n_r, 3)`` of element ``element``, rows in
        ``problem.local_vertices(r)`` order (feed to consensus / ``problem.assemble``)."""
        t = self.state
        poses = t.poses[element].detach().cpu().numpy()
        counts = t.node_mask[element].sum(-1).cpu().numpy()
        return [poses[agent, :count] for agent, count in enumerate(counts)]
