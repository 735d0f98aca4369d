"""SLAM on a simulated mission with truth-based detections: the simulator's stand-in for the recognition
pipeline, for filter studies (Monte Carlo, tests) that need no laser scans."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._validation import as_rng
from ..dataset import Dataset
from ..slam import SlamConfig, SlamResult, run_slam
from ..symmetry import Symmetry
from .detections import TruthDetectionConfig, simulate_detections


def builtin_symmetries() -> dict[str, Symmetry]:
    """Symmetry per class of the simulator's built-in objects."""
    from .objects import builtin_objects

    return {k: v.symmetry for k, v in builtin_objects().items()}


def truth_detection_config(mission: Dataset, **overrides) -> TruthDetectionConfig:
    """The truth-based source with the vehicle's scanner geometry (range window, field of view, rate)."""
    sc = mission.vehicle.scanner
    base = TruthDetectionConfig(fov_rad=sc.fov_rad, min_range_m=sc.min_range_m, max_range_m=sc.max_range_m,
                                scan_rate_hz=sc.rate_hz)
    return replace(base, **overrides)


def run_truth_slam(mission: Dataset, *, mode: str = "pose", config: SlamConfig | None = None, seed=0,
                   symmetries: dict[str, Symmetry] | None = None,
                   detection_config: TruthDetectionConfig | dict | None = None) -> SlamResult:
    """:func:`semslam.slam.run_slam` on ``mission`` with truth-based detections (seeded by ``seed``, the same
    detections in every mode). ``detection_config``: a :class:`TruthDetectionConfig`, or overrides of the
    default one as a dict."""
    symmetries = builtin_symmetries() if symmetries is None else symmetries
    if not isinstance(detection_config, TruthDetectionConfig):
        detection_config = truth_detection_config(mission, **(detection_config or {}))
    rng = as_rng(seed, caller="run_truth_slam")
    dets = {}
    if mode != "dr":
        dets = simulate_detections(mission, detection_config, seed=rng, symmetries=symmetries)
    return run_slam(mission, dets, mode=mode, config=config, seed=rng if isinstance(seed, np.random.Generator) else seed,
                    symmetries=symmetries)
