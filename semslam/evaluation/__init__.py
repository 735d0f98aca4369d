"""semslam.evaluation: how good a run was, against ground truth, after the run (never during it).

* :mod:`~semslam.evaluation.slam_run`: a finished SLAM run against the dataset's truth (trajectory and landmark
  errors, NEES, a local frame aligned by its start); :func:`load_reference` reads a source's truth.
* :mod:`~semslam.evaluation.metrics`: ATE, NEES and ANEES (NumPy).
* :mod:`~semslam.evaluation.classifier`: leave-one-out evaluation of a classifier on a view database.
* :mod:`~semslam.evaluation.motion_noise`: the unaided motion of a vehicle measured from its DVL logs (a
  calibration of the filter's process noise).
"""

from .slam_run import evaluate_landmark, evaluate_results, evaluate_run, load_reference

__all__ = ["evaluate_landmark", "evaluate_results", "evaluate_run", "load_reference"]
