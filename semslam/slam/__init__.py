"""semslam.slam: the semantic EKF-SLAM of Himri et al. (2018, 2019) and its evaluation.

``run_slam(mission, detections_by_scan | None, *, mode, config, seed) -> SlamResult`` is the entry point;
``run_montecarlo`` evaluates the modes over seeded missions.
"""

from .association import ObjectMeasurement, associate, associate_jcbb, innovation, measurement_from_detection
from .consensus import ConsensusInitializer, Observation, attitude_distance, quaternion_mean
from .detections import TruthDetectionConfig, read_detections_jsonl, simulate_detections, write_detections_jsonl
from .ekf import SemanticEkf
from .metrics import anees, chi2_band, nees, trajectory_metrics
from .montecarlo import MonteCarloResult, run_montecarlo, write_montecarlo
from .runner import MODES, LandmarkEstimate, SlamConfig, SlamResult, run_slam, write_run

__all__ = [
    "ObjectMeasurement", "associate", "associate_jcbb", "innovation", "measurement_from_detection",
    "ConsensusInitializer", "Observation", "attitude_distance", "quaternion_mean",
    "TruthDetectionConfig", "read_detections_jsonl", "simulate_detections", "write_detections_jsonl",
    "SemanticEkf", "anees", "chi2_band", "nees", "trajectory_metrics",
    "MonteCarloResult", "run_montecarlo", "write_montecarlo",
    "MODES", "LandmarkEstimate", "SlamConfig", "SlamResult", "run_slam", "write_run",
]
