"""semslam.slam: the semantic EKF-SLAM of Himri et al. (2018, 2019), fed by detections and navigation.

``SlamSession`` takes messages as they come (streaming); ``run_slam(dataset, detections_by_scan, *, mode,
config) -> SlamResult`` is the loop over a whole :class:`~semslam.dataset.Dataset`; ``initial_state`` finds a
run's start from the dive's own data (``initial``); ``read_survey`` reads landmarks known a priori (``survey``); ``write_run`` writes a
run directory (:mod:`semslam.slam.rundir`). Modules: ``session`` (time and events), ``sensors`` (attitude
input, DVL, depth models), ``mapping`` (association, landmark updates, consensus initialisation), ``ekf`` (the
filter and its named state blocks), ``smoother`` (RTS), ``evaluation`` (against ground truth).

Backends: ``run_slam(..., backend="ekf" | "isam2" | "batch")``; the factor-graph ones live in
:mod:`semslam.slam.graph` (``GraphSession``, same interface as ``SlamSession``; imported on demand: GTSAM).
"""

from .association import ObjectMeasurement, associate, associate_jcbb, innovation, measurement_from_detection
from .config import MODES, SlamConfig
from .consensus import ConsensusInitializer, Observation, attitude_distance, quaternion_mean
from .detections import read_detections_jsonl, write_detections_jsonl
from .ekf import SemanticEkf
from .evaluation import evaluate_landmark, evaluate_run
from .metrics import anees, chi2_band, nees, trajectory_metrics
from .results import LandmarkEstimate, SlamEstimate, SlamResult
from .rundir import write_run
from .initial import InitialState, initial_state, initial_state_of
from .runner import BACKENDS, feed_message, make_session, merged_messages, run_slam
from .session import SlamSession
from .survey import Survey, read_survey

__all__ = [
    "ObjectMeasurement", "associate", "associate_jcbb", "innovation", "measurement_from_detection",
    "MODES", "SlamConfig", "ConsensusInitializer", "Observation", "attitude_distance", "quaternion_mean",
    "read_detections_jsonl", "write_detections_jsonl", "SemanticEkf", "evaluate_landmark", "evaluate_run",
    "anees", "chi2_band", "nees", "trajectory_metrics", "LandmarkEstimate", "SlamEstimate", "SlamResult",
    "write_run", "feed_message", "merged_messages", "run_slam", "SlamSession", "InitialState", "initial_state",
    "initial_state_of", "BACKENDS", "make_session", "Survey", "read_survey",
]
