"""A picture of the robots' local graphs (PettingZoo's ``render_mode="rgb_array"``): every robot's
local graph at its own current estimate, one colour per robot, drawn with matplotlib's Agg canvas
(no display, no pyplot state)."""

from __future__ import annotations

import numpy as np


def draw_local_graphs(
    local_poses: list[np.ndarray],
    arrays: dict[str, np.ndarray],
    size: tuple[float, float, int],
) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB image of ``n`` local graphs.

    Args:
        local_poses: each agent's current local copy ``(n_r, 3)`` (x [m], y [m], θ [rad]), rows in
            local vertex order.
        arrays: one problem's padded buffers of :class:`envs.core.PGOCore`, leading axis the
            agent: ``tails``/``heads (n, E+1)`` local ids, ``processed (n, E+1)``,
            ``num_edges (n,)``, ``owned (n, V)``.
        size: figure width, height [inches] and dots per inch (``H = height·dpi``).

    Edges processed this episode are drawn solid, the others faint; owned poses are dots
    (separator copies are not); the axes share one metric scale.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    width, height, dpi = size
    figure = Figure(figsize=(width, height), dpi=dpi)
    canvas = FigureCanvasAgg(figure)
    axes = figure.add_axes((0.02, 0.02, 0.96, 0.96))
    palette = [f"C{index % 10}" for index in range(len(local_poses))]
    for agent, (poses, colour) in enumerate(zip(local_poses, palette, strict=True)):
        count = int(arrays["num_edges"][agent])
        tails, heads = arrays["tails"][agent, :count], arrays["heads"][agent, :count]
        segments = np.stack([poses[tails, :2], poses[heads, :2]], axis=1)  # (E_i, 2, 2)
        done = arrays["processed"][agent, :count].astype(bool)
        alpha = np.where(done, 0.9, 0.25)
        lines = LineCollection(segments, colors=colour, linewidths=1.0)
        lines.set_alpha(alpha)
        axes.add_collection(lines)
        owned = poses[arrays["owned"][agent, : poses.shape[0]].astype(bool)]
        axes.scatter(owned[:, 0], owned[:, 1], s=4, color=colour)
    axes.set_aspect("equal")
    axes.autoscale_view()
    axes.set_axis_off()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
