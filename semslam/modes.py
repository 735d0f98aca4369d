"""The names of the SLAM modes and estimators, defined once (a light module: the CLI's parsers read it without
loading the filter).

* ``MODES``: what the filter uses of the detections — ``dr`` none (dead reckoning), ``position`` their position,
  ``pose`` their full pose, ``pose+heading`` their pose and a heading-bias state (Himri et al. 2019).
* ``BACKENDS``: the estimator — ``ekf`` (the papers' filter, :mod:`semslam.slam`), or a factor graph with GTSAM
  (:mod:`semslam.slam.graph`): ``isam2`` incremental, ``batch`` Levenberg-Marquardt over the whole dive.
"""

MODES = ("dr", "position", "pose", "pose+heading")
BACKENDS = ("ekf", "isam2", "batch")
#: the factor-graph backends (:class:`semslam.slam.graph.GraphSession`)
GRAPH_BACKENDS = BACKENDS[1:]
