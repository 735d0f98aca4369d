"""semslam.pipeline: scans to detections. :class:`ScanRecognizer` turns one scan into detections
(:mod:`semslam.pipeline.scan`); :func:`~semslam.pipeline.dataset_detection.detect_dataset` runs it over every scan of a
dataset (:mod:`semslam.pipeline.dataset_detection`, imported from there: recognising one scan does not load
:mod:`semslam.dataset`)."""

from .scan import ClusterOutcome, PipelineConfig, RecognitionResult, ScanRecognizer, recognize_scan

__all__ = ["ClusterOutcome", "PipelineConfig", "RecognitionResult", "ScanRecognizer", "recognize_scan"]
