"""semslam.slam: the semantic EKF-SLAM of Himri et al. (2018, 2019), fed by detections and navigation.

Estimation only: ``SlamSession`` takes messages as they come (streaming); ``initial_state`` finds a run's start
from the dive's own data (``initial``); ``read_survey`` reads landmarks known a priori (``survey``). Modules:
``session`` (time and events), ``sensors`` (attitude input, DVL, depth models), ``mapping`` (association,
landmark updates, consensus initialisation), ``ekf`` (the filter and its named state blocks), ``smoother`` (RTS),
``consistency`` (NIS bands). The factor-graph backends live in :mod:`semslam.slam.graph` (``GraphSession``, same
interface as ``SlamSession``; imported on demand: GTSAM).

Elsewhere: feeding a whole dive is :mod:`semslam.run`; the run directory and exports are
:mod:`semslam.run.rundir` and :mod:`semslam.run.export` (detection files: :mod:`semslam.io.detections`);
evaluation against ground truth, after a run, is :mod:`semslam.evaluation`.
"""

from .association import ObjectMeasurement, associate, associate_jcbb, innovation, measurement_from_detection
from .config import MODES, SlamConfig
from .consistency import chi2_band, nis_summary
from .consensus import ConsensusInitializer, Observation, attitude_distance, quaternion_mean
from .ekf import SemanticEkf
from .results import LandmarkEstimate, SlamEstimate, SlamResult
from .initial import InitialState, initial_state, initial_state_of
from .session import SlamSession
from .survey import Survey, read_survey

__all__ = [
    "ObjectMeasurement", "associate", "associate_jcbb", "innovation", "measurement_from_detection",
    "MODES", "SlamConfig", "ConsensusInitializer", "Observation", "attitude_distance", "quaternion_mean",
    "SemanticEkf", "nis_summary", 
    "chi2_band", "LandmarkEstimate", "SlamEstimate", "SlamResult",
    "SlamSession", "InitialState", "initial_state",
    "initial_state_of", "Survey", "read_survey",
]
