"""popbench agents: the GA-SAC / MAPPO / IPPO actors, losses and trainers, and prop-v1.

Public API for users' own algorithms (docs/algorithms.md, "Bring your own algorithm"):
:class:`HybridActionDistribution`, the hybrid action's distribution π(e) · π(δ | s, e)
(agents.hybrid_distribution), imported on first use (it needs torch and tensordict).
"""

from __future__ import annotations

from typing import Any

__all__ = ["HybridActionDistribution"]


def __getattr__(name: str) -> Any:
    if name == "HybridActionDistribution":
        from agents.hybrid_distribution import HybridActionDistribution

        return HybridActionDistribution
    raise AttributeError(f"module 'agents' has no attribute {name!r}")
