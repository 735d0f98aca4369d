"""Factor-graph backends of the semantic SLAM on GTSAM: ``isam2`` (online) and ``batch`` (Levenberg-Marquardt).

:class:`GraphSession` has :class:`~semslam.slam.session.SlamSession`'s interface and outputs; see
:mod:`semslam.slam.graph.session`.
"""

from .backend import BACKENDS, GraphBackend
from .session import GraphSession

__all__ = ["BACKENDS", "GraphBackend", "GraphSession"]
