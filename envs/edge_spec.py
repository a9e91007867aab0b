"""The edge-choice action spec: a TorchRL ``Categorical`` whose action mask every copy shares.

TorchRL copies an env's specs wherever it composes the env: ``RandomPolicy`` (and so
``Collector(env, None)``) clones ``env.full_action_spec`` once, ``TransformedEnv`` caches a
clone of its parent's specs, ``check_env_specs`` rolls out from that cache. A ``Categorical``
clones its mask with it, so a mask updated after the copy was made (the valid edges change at
every step) is stale in every copy, and a random draw picks a processed edge.

:class:`SharedMaskCategorical` keeps one mask buffer per spec *family*: ``clone()`` (and
``to()`` on the same device, indexing, ``squeeze``/``unsqueeze``) return specs that view the
same buffer, and :meth:`~SharedMaskCategorical.update_mask` writes into it in place — the env's
own update after a reset or step, or TorchRL's ``ActionMask`` transform's. Every copy therefore
samples (``rand``) and checks (``is_in``) against the current valid edges.

A copy with a different batch shape (``expand``, as ``SerialEnv``/``ParallelEnv`` build their
specs from a throw-away instance of the env) or on another device starts a family of its own,
all choices allowed, until something writes its mask: a batched env's spec cannot follow its
workers' masks: :class:`EdgeActionMask` over the batched env writes it from the data.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical
from torchrl.envs import ActionMask


class SharedMaskCategorical(Categorical):
    """``Categorical(n, shape)`` whose mask ``(*shape, n)`` is shared by its copies (module
    docstring); the mask starts all ``True`` unless ``mask`` is given."""

    def __init__(
        self,
        n: int,
        shape: torch.Size | tuple[int, ...] = (),
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.int64,
        mask: torch.Tensor | None = None,
    ) -> None:
        shape = torch.Size(shape)
        self._buffer = torch.ones(*shape, n, dtype=torch.bool, device=device)
        super().__init__(n, shape, device, dtype, mask=self._buffer)
        if mask is not None:
            self.update_mask(mask)

    def update_mask(self, mask: torch.Tensor | None) -> None:
        """Write ``mask`` (broadcast to ``(*shape, n)``; ``None``: all allowed) into the shared
        buffer, in place."""
        buffer = getattr(self, "_buffer", None)
        if buffer is None:  # Categorical.__init__'s own call, before the buffer exists
            super().update_mask(mask)
            return
        if mask is None:
            buffer.fill_(True)
        else:
            buffer.copy_(torch.as_tensor(mask, device=buffer.device).expand_as(buffer))
        self.mask = buffer

    def _view(self, buffer: torch.Tensor, shape: torch.Size) -> SharedMaskCategorical:
        """A copy of this spec with ``shape`` over ``buffer`` (a view of the shared one)."""
        copy = SharedMaskCategorical.__new__(SharedMaskCategorical)
        Categorical.__init__(copy, self.space.n, shape, self.device, self.dtype, mask=buffer)
        copy._buffer = buffer
        return copy

    def clone(self) -> SharedMaskCategorical:
        return self._view(self._buffer, self.shape)

    def to(self, dest: torch.dtype | torch.device | str | None) -> SharedMaskCategorical:
        if dest is None:
            return self
        if isinstance(dest, torch.dtype):
            if dest == self.dtype:
                return self
            copy = self.clone()
            copy.dtype = dest
            return copy
        if torch.device(dest) == self.device:
            return self
        return SharedMaskCategorical(
            self.space.n, self.shape, dest, self.dtype, self._buffer.to(dest)
        )

    def expand(self, *shape: int) -> SharedMaskCategorical:
        if len(shape) == 1 and isinstance(shape[0], (tuple, list, torch.Size)):
            shape = tuple(shape[0])
        shape = torch.Size(shape)
        if shape == self.shape:
            return self.clone()
        return SharedMaskCategorical(self.space.n, shape, self.device, self.dtype)

    def __getitem__(self, index) -> SharedMaskCategorical:
        view = self._buffer[index]
        return self._view(view, view.shape[:-1])

    def unbind(self, dim: int = 0) -> tuple[SharedMaskCategorical, ...]:
        dim = dim if dim >= 0 else dim + len(self.shape)
        return tuple(self._view(view, view.shape[:-1]) for view in self._buffer.unbind(dim))

    def squeeze(self, dim: int | None = None) -> SharedMaskCategorical:
        body = self._buffer[..., 0]
        squeezed = body.squeeze() if dim is None else body.squeeze(dim)
        view = self._buffer.view(*squeezed.shape, self.space.n)
        return self._view(view, squeezed.shape)

    def unsqueeze(self, dim: int) -> SharedMaskCategorical:
        shape = self._buffer[..., 0].unsqueeze(dim).shape
        return self._view(self._buffer.view(*shape, self.space.n), shape)


class EdgeActionMask(ActionMask):
    """TorchRL's ``ActionMask`` (the container's action spec follows the mask in the data after
    every step and reset) that keeps, on a partial reset, the masks of the batch elements that
    were not reset: ``ActionMask`` reads them from the reset's output, where a batched env
    leaves those elements' entries unset (zeros: a mask with no valid choice)."""

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        spec = self.action_spec
        mask = tensordict_reset.get(self.in_keys[1]).to(spec.device)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is not None and not reset.all() and spec.mask is not None:
            flags = reset.reshape(*reset.shape[:-1], *(1,) * (mask.ndim - reset.ndim + 1))
            mask = torch.where(flags.to(spec.device), mask, spec.mask)
        spec.update_mask(mask)
        return tensordict_reset
