"""popbench: learned and classical distributed planar pose-graph optimisation, benchmarked.

The core package holds the SE(2) maths, pose graphs, g2o/TORO I/O, datasets, the objective,
the centralised reference solver, partitioning, consensus and the experiment harness. The
learned agents (``agents``), the environments (``envs``) and the classical baselines
(``baselines``) build on it; the core never imports them except through the method registry.
"""

from popbench.errors import PopbenchError
from popbench.graph import EdgeKind, PoseGraph

__all__ = ["EdgeKind", "PoseGraph", "PopbenchError"]
__version__ = "0.1.0"
