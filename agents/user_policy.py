"""A user's policy as a row of ``popbench run heldout --policy`` (docs/algorithms.md, "Bring
your own algorithm").

``--policy MODULE:ATTR`` (or ``path/to/file.py:ATTR``) names either

* a TorchRL actor module (a ``tensordict.nn.TensorDictModuleBase``, e.g. a
  ``ProbabilisticActor``) that reads the TorchRL env's tensordict and writes
  ("agents", "action", "edge" | "delta"), or
* a plain callable ``policy(agents) -> (edge [n], delta [n, 3])`` over the observation of one
  problem: ``agents`` is the env's ("agents",) entry, a TensorDict of batch shape [n] holding
  "observation" (the graph fields) and "action_mask";

or, with ``--policy-arg ARG``, a factory that ``ATTR(ARG)`` turns into one of them (e.g. a
function that loads trained weights from the file ARG). A recurrent module declares its state
TorchRL's way (``make_tensordict_primer``, as ``GRUModule`` does; the env is then wrapped in
that primer).

The policy runs one deterministic episode (TorchRL's DETERMINISTIC exploration type, as the
shipped learned rows run) of the TorchRL env (envs.torchrl_env.PGOEnv, B = 1) built with
``--policy-env`` (the keyword options of ``envs.make_torchrl_env``: the env the policy was
trained in; its defaults, the paper's game, when absent), loaded with the held-out problem;
the robots' local copies then go through the consensus and the scoring of every row
(agents.heldout.evaluate_row). The padding is the env's default for the protocol's synthetic
problems (``make_problem_source``), widened where a held-out problem needs more;
``max_vertices`` / ``max_edges`` / ``max_degree`` set it.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import os
import sys
from collections.abc import Mapping
from dataclasses import astuple
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import torch

from popbench.errors import ValueRangeError
from popbench.problems.distributed import DistributedProblem

PADDING_OPTIONS = ("max_vertices", "max_edges", "max_degree")
_FIXED = {"self", "source", "num_agents", "dims", "batch_size", "batch", "seed", "device", "labels"}


def load_entry_point(name: str) -> Any:
    """The object ``"module:attr"`` or ``"path/to/file.py:attr"`` names (a module is imported
    with the working directory on ``sys.path``, as ``python -m`` would); a one-line
    ValueRangeError when it cannot be found."""
    module_name, _, attribute = name.rpartition(":")
    allowed = "MODULE:ATTR or path/to/file.py:ATTR"
    if not module_name or not attribute:
        raise ValueRangeError("--policy", name, allowed)
    try:
        if module_name.endswith(".py"):
            path = Path(module_name)
            if not path.is_file():
                raise ValueRangeError("--policy", name, f"{allowed} (no file {path})")
            spec = importlib.util.spec_from_file_location(path.stem, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        else:
            if os.getcwd() not in sys.path:
                sys.path.insert(0, os.getcwd())
            module = importlib.import_module(module_name)
    except ImportError as error:
        raise ValueRangeError("--policy", name, f"{allowed} ({error})") from None
    if not hasattr(module, attribute):
        raise ValueRangeError("--policy", name, f"{allowed} (no {attribute!r} in {module_name})")
    return getattr(module, attribute)


def module_file(name: str) -> str | None:
    """The source file of the module ``"module:attr"`` / ``"file.py:attr"`` names (None when
    it has none)."""
    module_name = name.rpartition(":")[0]
    if module_name.endswith(".py"):
        return module_name
    spec = importlib.util.find_spec(module_name)
    return None if spec is None else spec.origin


def env_option_names() -> tuple[str, ...]:
    """The ``--policy-env`` keys: PGOEnv's and PGOCore's keyword options and the padding."""
    from envs.core import PGOCore
    from envs.modes import MODE_NAMES
    from envs.torchrl_env import PGOEnv

    names = {*inspect.signature(PGOEnv).parameters, *inspect.signature(PGOCore).parameters}
    names = names - _FIXED - {"modes", "mode_changes"} | set(MODE_NAMES)  # the modes one by one
    return tuple(sorted(names)) + PADDING_OPTIONS


@lru_cache(maxsize=4)
def cached_policy(name: str, arg: str | None) -> Any:
    """The policy ``name`` names (``ATTR(arg)`` when ``arg`` is given), loaded once per process;
    an ``nn.Module`` in eval mode."""
    policy = load_entry_point(name)
    policy = policy(arg) if arg is not None else policy
    if not callable(policy):
        raise ValueRangeError("--policy", name, "a TorchRL actor module or a callable")
    return policy.eval() if isinstance(policy, torch.nn.Module) else policy


def describe_policy(name: str, arg: str | None, env: dict[str, Any]) -> dict[str, Any]:
    """The spec entries of the policy row: ``policy``, ``policy_arg`` (when given),
    ``policy_env``, ``label`` (the attribute's name) and ``policy_sha256``, a digest of the
    module's file, of ARG's file when ARG is one, and of the policy's state_dict when it is an
    ``nn.Module`` (a retrained policy is scored again, not read from the cell cache)."""
    unknown = sorted(set(env) - set(env_option_names()))
    if unknown:
        allowed = ", ".join(env_option_names())
        raise ValueRangeError("--policy-env", ",".join(unknown), f"options among {allowed}")
    policy = cached_policy(name, arg)
    digest = hashlib.sha256()
    for path in (module_file(name), arg):
        if path is not None and Path(path).is_file():
            digest.update(Path(path).read_bytes())
    if isinstance(policy, torch.nn.Module):
        for key, tensor in policy.state_dict().items():
            digest.update(key.encode() + tensor.detach().cpu().numpy().tobytes())
    described = {"policy": name, "policy_env": dict(env), "policy_sha256": digest.hexdigest()}
    if arg is not None:
        described["policy_arg"] = arg
    return {**described, "label": name.rpartition(":")[2]}


@lru_cache(maxsize=8)
def default_padding(robots: int, noise: str, poses_per_robot: int) -> tuple[int, int, int]:
    """The padding ``envs.make_torchrl_env`` gives these synthetic problems (V, E, D)."""
    from envs import make_problem_source

    dims = make_problem_source(robots, noise, poses_per_robot=poses_per_robot)[1]
    return dims.vertices, dims.edges, dims.degree


def problem_env(
    problem: DistributedProblem, entries: Mapping[str, Any], protocol: tuple[int, str, int]
) -> Any:
    """The TorchRL env (B = 1) of ``entries["policy_env"]`` (the row's :func:`describe_policy`
    entries), loaded with ``problem``, padded as the held-out ``protocol`` (robots, noise level,
    poses per robot) pads its problems (module docstring; reward "F" unless the options say
    otherwise)."""
    from envs.observation import Dimensions
    from envs.torchrl_env import PGOEnv

    options = {"reward": "F", **entries["policy_env"]}
    default = default_padding(*protocol)
    needed = Dimensions.of([problem])
    dims = Dimensions(
        *(
            int(options.pop(key, max(size, need)))
            for key, size, need in zip(PADDING_OPTIONS, default, astuple(needed), strict=True)
        )
    )
    return PGOEnv(lambda seed: problem, problem.num_robots, dims, 1, **options)


def policy_episode(
    problem: DistributedProblem, entries: Mapping[str, Any], protocol: tuple[int, str, int]
) -> list[np.ndarray]:
    """The robots' local copies after the deterministic episode of the policy ``entries``
    describe (:func:`describe_policy`) in :func:`problem_env` (module docstring)."""
    from tensordict.nn import TensorDictModuleBase
    from torchrl.envs import TransformedEnv
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    from torchrl.modules.utils import get_primers_from_module

    policy = cached_policy(entries["policy"], entries.get("policy_arg"))
    env = base = problem_env(problem, entries, protocol)
    if isinstance(policy, torch.nn.Module):  # a recurrent module's state, as TorchRL primes it
        primers = get_primers_from_module(policy, warn=False)
        env = base if primers is None else TransformedEnv(base, primers)
    if not isinstance(policy, TensorDictModuleBase):
        policy = _acting_on_tensordict(policy, problem.num_robots)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        steps = env.rollout(base.dims.edges + 1, policy, break_when_any_done=True)
    if not bool(steps["next", "done"][0, -1].all()):
        raise ValueRangeError("--policy", entries["policy"], "a policy whose episode ends")
    return base.local_poses(0)


def _acting_on_tensordict(policy: Any, n: int) -> Any:
    """A plain callable over one problem's ("agents",) entry as a tensordict → tensordict step."""

    def act(tensordict: Any) -> Any:
        edge, delta = policy(tensordict["agents"][0])
        tensordict["agents", "action", "edge"] = torch.as_tensor(edge).long().view(1, n)
        delta = torch.as_tensor(delta, dtype=torch.float32)
        tensordict["agents", "action", "delta"] = delta.view(1, n, 3)
        return tensordict

    return act
