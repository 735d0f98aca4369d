"""semslam.pipeline: scans to detections. :class:`ScanRecognizer` turns one scan into detections
(:mod:`semslam.pipeline.scan`); :func:`detect_mission` runs it over every scan of a dataset
(:mod:`semslam.pipeline.mission`).

The mission-level names are imported on first use (PEP 562): recognising one scan (``semslam recognize``)
does not load :mod:`semslam.dataset`."""

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

_MISSION_NAMES = ("MissionDetections", "detect_mission", "scan_seed")


def __getattr__(name: str):
    if name in _MISSION_NAMES:
        from . import mission

        return getattr(mission, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
