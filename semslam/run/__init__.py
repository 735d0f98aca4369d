"""semslam.run: sources -> runner -> sinks. One streaming path from any dive (a ROS bag, a dataset directory, the
simulator in memory, live topics) to trajectories, a map and a health verdict.

* :func:`open_dive` (``sources``): a dive as one time-ordered stream of typed messages (``messages``).
* :class:`Runner` (``runner``): the stream through the recogniser and one SLAM session per mode.
* :func:`run_dive` (``dive``): the whole job ``semslam run`` does, as a library call.
* :func:`health_verdict` (``health``): whether a run went right, per sensor and for the map.
* :func:`run_slam` (``dataset_loop``): the filter over a :class:`~semslam.dataset.Dataset` in memory with
  detections given, then evaluated against its truth when it has one (tests, Monte Carlo).
"""

from .dataset_loop import BACKENDS, run_slam
from .messages import Attitude, Depth, Dvl, Fix, Message, Scan
from .runner import Runner, RunOutcome, run_stream
from .sources import Dive, open_dive

__all__ = ["Attitude", "Depth", "Dvl", "Fix", "Message", "Scan", "Runner", "RunOutcome", "run_stream", "Dive",
           "open_dive", "BACKENDS", "run_slam"]
