"""The observation of the PGO environment, declared once: every entry an agent observes, the
columns of its node and edge features, and what padding means (paper §III-C).

Each agent observes its padded local graph: ``V`` vertex slots and ``E`` edge slots
(:class:`envs.observation.Dimensions`). **Padding**: a vertex slot is real where ``node_mask``,
an edge slot where ``edge_mask``; every padding entry is 0, so a padding edge's ``edge_index``
column is ``(0, 0)`` — it points at vertex 0, a real vertex, and a message-passing layer must
drop it by ``edge_mask`` (an unmasked padding edge would pass messages along vertex 0's
self-loop). The action's edge index ranges over ``0..E``; ``E`` is the no-op (``action_mask``).

:data:`NODE` and :data:`EDGE` give the feature columns in order; :data:`ENTRIES` the entries of
one agent's observation (TorchRL: under ``("agents", "observation")`` with leading ``(B, n)``;
PettingZoo: one dict per agent). docs/environment.md renders these tables.
"""

from __future__ import annotations

from typing import NamedTuple


class Column(NamedTuple):
    """One feature column: its ``name``, ``meaning`` and ``unit`` (``""``: unitless)."""

    name: str
    meaning: str
    unit: str = ""


class Entry(NamedTuple):
    """One observation entry: its ``name``, per-agent ``shape`` (symbols V, E, and the widths),
    ``dtype`` and ``meaning``; ``base_step_only``: present only with ``base="gauss-newton"``."""

    name: str
    shape: str
    dtype: str
    meaning: str
    base_step_only: bool = False


NODE = (
    Column("x", "position in the frame vertex's frame (first owned pose, or tree parent)", "m"),
    Column("y", "the same, second coordinate", "m"),
    Column("sin_theta", "sine of the heading relative to the frame vertex"),
    Column("cos_theta", "cosine of the same"),
    Column("log_degree", "log(1 + degree) in the local graph"),
    Column("owned", "1: the agent's own pose; 0: a separator copy of a neighbour's pose"),
)
EDGE = (
    Column("odometry", "kind one-hot: consecutive poses of one robot"),
    Column("loop", "kind one-hot: intra-robot loop closure"),
    Column("inter_relative", "kind one-hot: consecutive poses owned by two robots"),
    Column("inter_loop", "kind one-hot: loop closure between two robots"),
    Column("log_info_x", "log Λ_xx (whitened action: centred on the agent's mean)"),
    Column("log_info_y", "log Λ_yy (likewise)"),
    Column("log_info_theta", "log Λ_θθ (likewise)"),
    Column("gap", "log(1 + d) / log(N), d the distance of the endpoints' global ids; (0, 1]"),
    Column("length", "‖t̃‖ of the measurement (whitened action: √τ ‖t̃‖, unitless)", "m"),
    Column("sin_theta", "sine of the measured rotation θ̃"),
    Column("cos_theta", "cosine of the same"),
)
EDGE_COLUMN = {column.name: index for index, column in enumerate(EDGE)}
BASE_MODEL = 9  # g / F (3) and the upper triangle of H / F (6), envs.basestep.observed_model

ENTRIES = (
    Entry("node_features", f"(V, {len(NODE)})", "float32", "node features (NODE), 0 on padding"),
    Entry("node_mask", "(V,)", "bool", "real vertex slots"),
    Entry("edge_index", "(2, E)", "int64", "local (tail p, head q); (0, 0) on padding"),
    Entry("edge_attr", f"(E, {len(EDGE)})", "float32", "edge features (EDGE), 0 on padding"),
    Entry("edge_mask", "(E,)", "bool", "real edge slots"),
    Entry("processed", "(E,)", "bool", "edges already corrected in this episode"),
    Entry("residuals", "(E, 3)", "float32", "r = (r_x, r_y [m], r_θ [rad]); whitened: Λ^½ r"),
    Entry("base_step", "(E, 3)", "float32", "Gauss–Newton step Δ_GN, action units", True),
    Entry("base_model", f"(E, {BASE_MODEL})", "float32", "its quadratic model / local F", True),
)


def markdown_table(columns: tuple[Column, ...]) -> str:
    """A markdown table of feature ``columns`` (index, name, unit, meaning)."""
    rows = ["| # | name | unit | meaning |", "|---|---|---|---|"]
    rows += [f"| {i} | `{c.name}` | {c.unit or '–'} | {c.meaning} |" for i, c in enumerate(columns)]
    return "\n".join(rows)
