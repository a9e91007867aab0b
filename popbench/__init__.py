"""popbench: learned and classical distributed planar pose-graph optimisation, benchmarked.

The core package holds the SE(2) maths, pose graphs, g2o/TORO I/O, datasets, the objective,
the centralised reference solver, partitioning, consensus and the experiment harness. The
learned agents (``agents``), the environments (``envs``) and the classical baselines
(``baselines``) build on it; the core never imports them except through the method registry.
"""

from popbench.errors import PopbenchError

__all__ = ["EdgeKind", "PoseGraph", "PopbenchError"]
__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    # EdgeKind and PoseGraph load NumPy/SciPy on first use, so `popbench --help` stays fast.
    if name in ("EdgeKind", "PoseGraph"):
        from popbench import graph

        return getattr(graph, name)
    raise AttributeError(f"module 'popbench' has no attribute {name!r}")
