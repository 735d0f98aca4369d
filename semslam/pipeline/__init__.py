"""semslam.pipeline: scans to detections. :class:`ScanRecognizer` turns one scan into detections
(:mod:`semslam.pipeline.scan`); :func:`detect_mission` runs it over every scan of a dataset
(:mod:`semslam.pipeline.mission`)."""

from .mission import MissionDetections, detect_mission, scan_seed
from .scan import (
    ClusterOutcome,
    PipelineConfig,
    RecognitionResult,
    ScanRecognizer,
    _input_indices,  # noqa: F401  (kernel oracles in tests)
    _scan_angular_extent,  # noqa: F401
    recognize_scan,
)

__all__ = ["MissionDetections", "detect_mission", "scan_seed", "ClusterOutcome", "PipelineConfig",
           "RecognitionResult", "ScanRecognizer", "recognize_scan"]
