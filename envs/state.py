"""The declared state of :class:`envs.core.PGOCore`: every tensor it holds, named once here.

A typed record (like TorchRL's specs, declared once): a misspelt name fails at once, on reading
and on writing (the record has ``__slots__``). ``B`` problems of ``n`` agents, padded to ``V``
vertices, ``E`` edges and ``D`` incident edges per vertex (:class:`envs.observation.Dimensions`);
index ``V`` is the trash vertex and index ``E`` the trash edge slot (padding and the no-op
action write there, :mod:`envs.core`). Floating entries have the core's dtype unless noted.

Three kinds of entries (``field(metadata={"kind": ...})``):

* ``packed``: one problem's arrays as :func:`envs.observation.pack_problem` and
  :func:`envs.tree.pack_trees` write them, replaced when a batch element starts a new problem;
* ``derived``: recomputed from the packed entries at every load;
* ``dynamic``: rewritten by every step, reset at the start of an episode.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from envs.geometry import matrix_parts
from envs.modes import NONMONOTONE_WINDOW


def _entry(kind: str) -> dataclasses.Field:
    return dataclasses.field(metadata={"kind": kind})


@dataclasses.dataclass(slots=True, eq=False)
class CoreState:
    """Every tensor of the batched core, shapes with leading ``(B, n)`` unless noted.

    Packed (per agent's padded local graph):
        vertex_ids ``(V,)`` int64 global ids (−1 on padding); node_mask, owned ``(V,)`` bool
        (real vertex; owned pose, else a separator copy); log_degree ``(V,)`` log(1 + degree);
        poses ``(V+1, 3)`` the agent's own copies (x [m], y [m], θ [rad]); tails, heads
        ``(E+1,)`` int64 local endpoints (pad and no-op → trash ``V``); edge_ids ``(E,)`` int64
        global ids (−1 on padding); edge_mask ``(E,)`` bool real edges; measurements, targets
        ``(E+1, 3)`` z̃ and the reward's z* (:mod:`envs.core`); kappa, tau ``(E+1,)`` the
        weights of F (0 on pads); edge_attr ``(E, 11)`` float32 (:data:`envs.features.EDGE`);
        incident ``(V+1, D)`` int64 edge slots at each vertex (pad → ``E``); num_edges ``()``
        int64 |E_i|; sqrt_information, inverse_sqrt_information ``(E+1, 3, 3)`` Λ^½, Λ^−½
        (identity on pads); outlier ``(E,)`` bool injected outlier (a label, never observed);
        tree_position, tree_end, tree_parent ``(V+1,)`` int64 pre-order position, subtree end,
        parent; tree_edge ``(E+1,)`` bool; mover, lca ``(E+1,)`` int64 (:mod:`envs.tree`).
    Derived:
        edge_index ``(2, E)`` int64 local (tail, head), 0 on padding; sqrt_information_parts,
        inverse_sqrt_information_parts ``(3, 3, B·n, E+1)`` the matrices' components
        (:func:`envs.geometry.matrix_parts`).
    Dynamic:
        residuals ``(E+1, 3)`` against the measurements; costs ``(E+1,)`` each edge's term of
        ``L`` (against the targets); processed ``(E+1,)`` bool (the no-op slot always);
        loss, initial_loss ``()`` ``L_i`` now and at the episode's start; remaining ``()``
        int64 edges left to process; recent_f ``(M,)`` the agent's local F (the measurements as
        targets) after its last ``M`` steps, the current one last (filled with the start's value;
        kept under the ``nonmonotone`` step rule only, :func:`envs.correction.nonmonotone_choice`).
    """

    vertex_ids: Tensor = _entry("packed")
    node_mask: Tensor = _entry("packed")
    owned: Tensor = _entry("packed")
    log_degree: Tensor = _entry("packed")
    poses: Tensor = _entry("packed")
    tails: Tensor = _entry("packed")
    heads: Tensor = _entry("packed")
    edge_ids: Tensor = _entry("packed")
    edge_mask: Tensor = _entry("packed")
    measurements: Tensor = _entry("packed")
    targets: Tensor = _entry("packed")
    kappa: Tensor = _entry("packed")
    tau: Tensor = _entry("packed")
    edge_attr: Tensor = _entry("packed")
    incident: Tensor = _entry("packed")
    num_edges: Tensor = _entry("packed")
    sqrt_information: Tensor = _entry("packed")
    inverse_sqrt_information: Tensor = _entry("packed")
    outlier: Tensor = _entry("packed")
    tree_position: Tensor = _entry("packed")
    tree_end: Tensor = _entry("packed")
    tree_parent: Tensor = _entry("packed")
    tree_edge: Tensor = _entry("packed")
    mover: Tensor = _entry("packed")
    lca: Tensor = _entry("packed")
    edge_index: Tensor = _entry("derived")
    sqrt_information_parts: Tensor = _entry("derived")
    inverse_sqrt_information_parts: Tensor = _entry("derived")
    residuals: Tensor = _entry("dynamic")
    costs: Tensor = _entry("dynamic")
    processed: Tensor = _entry("dynamic")
    loss: Tensor = _entry("dynamic")
    initial_loss: Tensor = _entry("dynamic")
    remaining: Tensor = _entry("dynamic")
    recent_f: Tensor = _entry("dynamic")

    def replace_elements(self, index: Tensor, packed: dict[str, Tensor]) -> None:
        """Replace the packed entries of the batch elements ``index`` out of place (tensors
        handed out earlier stay valid); ``packed`` must name every packed entry."""
        check_packed(packed)
        for name, value in packed.items():
            replaced = getattr(self, name).clone()
            replaced[index] = value
            setattr(self, name, replaced)


def names(kind: str) -> tuple[str, ...]:
    """The entries of one kind (``"packed"``, ``"derived"`` or ``"dynamic"``), in order."""
    return tuple(f.name for f in dataclasses.fields(CoreState) if f.metadata["kind"] == kind)


PACKED = names("packed")


def check_packed(packed: dict[str, object]) -> None:
    """Raise ``KeyError`` naming the difference when ``packed``'s keys are not :data:`PACKED`."""
    missing, extra = set(PACKED) - set(packed), set(packed) - set(PACKED)
    if missing or extra:
        raise KeyError(f"packed entries: missing {sorted(missing)}, undeclared {sorted(extra)}")


def empty_dynamics(
    batch: int, agents: int, edges: int, dtype: torch.dtype, device: torch.device
) -> dict[str, Tensor]:
    """Uninitialised dynamic entries (:class:`CoreState`) for ``edges`` = E edge slots."""
    slots = (batch, agents, edges + 1)
    return {
        "residuals": torch.empty(slots + (3,), dtype=dtype, device=device),
        "costs": torch.empty(slots, dtype=dtype, device=device),
        "processed": torch.empty(slots, dtype=torch.bool, device=device),
        "loss": torch.empty((batch, agents), dtype=dtype, device=device),
        "initial_loss": torch.empty((batch, agents), dtype=dtype, device=device),
        "remaining": torch.empty((batch, agents), dtype=torch.int64, device=device),
        "recent_f": torch.empty((batch, agents, NONMONOTONE_WINDOW), dtype=dtype, device=device),
    }


#: the packed entries the derived ones are computed from, in :func:`derived_entries`' order
DERIVED_FROM = ("tails", "heads", "edge_mask", "sqrt_information", "inverse_sqrt_information")


def derived_entries(
    tails: Tensor, heads: Tensor, edge_mask: Tensor, root: Tensor, inverse_root: Tensor
) -> dict[str, Tensor]:
    """The derived entries (:class:`CoreState`) of the packed ``tails``, ``heads``,
    ``edge_mask``, ``sqrt_information`` and ``inverse_sqrt_information`` (new tensors)."""
    e = edge_mask.shape[-1]
    index = torch.stack([tails[..., :e], heads[..., :e]], -2)
    return {
        "edge_index": torch.where(edge_mask.unsqueeze(-2), index, 0),
        "sqrt_information_parts": matrix_parts(root.flatten(0, 1)),
        "inverse_sqrt_information_parts": matrix_parts(inverse_root.flatten(0, 1)),
    }
