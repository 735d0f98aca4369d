"""SLAM on a simulated mission with truth-based detections: the simulator's stand-in for the recognition
pipeline, for filter studies (Monte Carlo, tests) that need no laser scans."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._validation import as_rng
from ..dataset import Dataset
from ..errors import SimulationError
from ..geometry import RigidTransform
from ..slam import SlamConfig, SlamResult
from ..slam.survey import Survey
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


def simulated_survey(mission: Dataset, names, *, config: SlamConfig | None = None, seed=0) -> Survey:
    """A survey of the named objects as a surveyor would give it: each true pose plus an N(0, sigma) error
    (``config.initialisation.survey_position_sigma_m`` / ``survey_rotation_sigma_rad``), seeded. The simulator
    plays the surveyor; the run reads the survey like a real one and never the truth.

    Frame: a mission with position fixes runs in the world frame, and so is the survey; one without runs in the
    local frame of its start point (:mod:`semslam.slam.initial`), so the survey is given relative to the launch
    mark (north and east of the true start taken off), as a surveyor in a tank measures the structure from it."""
    from ..slam import _ekf_kernels as kern

    cfg = SlamConfig() if config is None else config
    init = cfg.initialisation
    names = tuple(names)
    if isinstance(names, str) or not all(isinstance(n, str) for n in names):
        raise SimulationError(f"The surveyed objects must be a sequence of object names. Got {names!r} instead.")
    byname = {o.name: o for o in mission.objects}
    missing = [n for n in names if n not in byname]
    if missing:
        raise SimulationError(f"The surveyed objects must name objects of the mission ({sorted(byname)}). Got "
                              f"{missing} instead.")
    rng = seed if isinstance(seed, np.random.Generator) else \
        np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
    shift = np.zeros(3)
    if mission.fixes is None and mission.truth is not None and len(mission.attitude):
        shift[0:2] = mission.truth.interpolate_position(mission.attitude.stamp_s[0])[0, 0:2]
    labels, poses = [], []
    for name in names:
        o = byname[name]
        R = kern.so3_exp(rng.normal(0.0, init.survey_rotation_sigma_rad, 3)) @ o.T_world_object.rotation
        p = o.T_world_object.translation_m - shift + rng.normal(0.0, init.survey_position_sigma_m, 3)
        labels.append(o.label)
        poses.append(RigidTransform.from_rotation_translation(R, p))
    return Survey(names, tuple(labels), tuple(poses), source="simulated survey")


def run_truth_slam(mission: Dataset, *, mode: str = "pose", config: SlamConfig | None = None, seed=0,
                   symmetries: dict[str, Symmetry] | None = None,
                   detection_config: TruthDetectionConfig | dict | None = None, surveyed=(),
                   backend: str = "ekf", survey: Survey | None = None) -> SlamResult:
    """``mission`` through the streaming runner (:func:`semslam.run.run_stream`, as ``semslam run``) with truth-based
    detections (seeded by ``seed``, the same
    detections in every mode). ``detection_config``: a :class:`TruthDetectionConfig`, or overrides of the
    default one as a dict. ``surveyed``: names of objects given to the run as a survey
    (:func:`simulated_survey`, seeded by ``seed``); ``survey``: a survey or an earlier dive's map
    (:func:`semslam.slam.read_survey`), instead."""
    symmetries = builtin_symmetries() if symmetries is None else symmetries
    if not isinstance(detection_config, TruthDetectionConfig):
        detection_config = truth_detection_config(mission, **(detection_config or {}))
    rng = as_rng(seed, caller="run_truth_slam")
    if len(surveyed):
        survey = simulated_survey(mission, surveyed, config=config, seed=rng.spawn(1)[0]
                                  if isinstance(seed, np.random.Generator) else seed)
    dets = {}
    if mode != "dr":
        dets = simulate_detections(mission, detection_config, seed=rng, symmetries=symmetries)
    # the user's path: the dive streamed through the one runner (semslam.run), truth read only by its evaluation
    from ..run import open_dive, run_stream

    out = run_stream(open_dive(mission, scans=False), modes=(mode,), detections_by_scan=dets, config=config,
                     symmetries=symmetries, backend=backend, survey=survey)
    from ..evaluation.slam_run import evaluate_run

    return evaluate_run(out.results[mode], mission, symmetries)  # after the run
