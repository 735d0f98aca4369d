"""Run the semantic EKF over a whole dataset: a short loop feeding a :class:`~semslam.slam.session.SlamSession`
with the time-ordered merge of the dataset's logs and the given detections, then the evaluation pass against
the dataset's ground truth when it has one."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from .._validation import as_rng, check_choice
from ..dataset import Dataset
from ..detection import Detection
from ..errors import SlamError
from ..geometry import RigidTransform
from ..symmetry import Symmetry
from . import _ekf_kernels as kern
from .config import MODES, SlamConfig
from .evaluation import evaluate_run
from .results import SlamResult
from .session import SlamSession

#: the estimators behind a run (see :func:`run_slam`)
BACKENDS = ("ekf", "isam2", "batch")


def _start(dataset: Dataset) -> float:
    """The run starts with the first navigation (or truth) sample that has an attitude at or before it."""
    starts = [s[0] for s in (dataset.attitude.stamp_s, dataset.dvl.stamp_s, dataset.depth.stamp_s) if len(s)]
    if dataset.truth is not None:
        starts.append(dataset.truth.stamp_s[0])
    return float(max(min(starts), dataset.attitude.stamp_s[0]))


def feed_message(session: Any, stamp_s: float, kind: str, payload: tuple) -> None:
    """Give one message of :func:`merged_messages` to a session (any :class:`SlamSession`: its ``add_*``)."""
    if kind == "attitude":
        session.add_attitude(stamp_s, *payload)
    elif kind == "dvl":
        session.add_dvl(stamp_s, payload[0], valid=payload[1], beam_range_m=payload[2])
    elif kind == "depth":
        session.add_depth(stamp_s, *payload)
    elif kind == "detections":
        session.add_detections(stamp_s, *payload)
    else:
        raise SlamError(f"The 'kind' argument of feed_message must be attitude, dvl, depth or detections. Got {kind!r} "
                        "instead.")


def merged_messages(dataset: Dataset, detections_by_scan: dict[int, list[Detection]]):
    """Every message of the dataset and the detections, in processing order ``(stamp, kind, payload)``: by
    stamp, then attitude, DVL, depth, detections. Detections are grouped by (stamp, scan)."""
    a, d, z = dataset.attitude, dataset.dvl, dataset.depth
    beams = d.beam_range_m
    msgs = [(float(t), 0, i, "attitude") for i, t in enumerate(a.stamp_s)]
    msgs += [(float(t), 1, i, "dvl") for i, t in enumerate(d.stamp_s)]
    msgs += [(float(t), 2, i, "depth") for i, t in enumerate(z.stamp_s)]
    groups: dict = {}
    for sid, dets in detections_by_scan.items():
        for det in dets:
            st = float(det.stamp_s)
            if not math.isfinite(st):
                raise SlamError(f"Every detection given to run_slam needs a finite 'stamp_s'. Got {det.stamp_s!r} "
                                f"in scan {sid} instead.")
            groups.setdefault((st, sid), []).append(det)
    keys = list(groups)
    msgs += [(k[0], 3, i, "detections") for i, k in enumerate(keys)]
    msgs.sort(key=lambda m: (m[0], m[1], m[2]))
    for t, _, i, kind in msgs:
        if kind == "attitude":
            yield t, kind, (a.rpy_rad[i],)
        elif kind == "dvl":
            yield t, kind, (d.velocity_body_mps[i], bool(d.valid[i]), None if beams is None else beams[i])
        elif kind == "depth":
            yield t, kind, (float(z.depth_m[i]),)
        else:
            yield t, kind, (groups[keys[i]],)


def run_slam(dataset: Dataset, detections_by_scan: dict[int, list[Detection]] | None = None, *, mode: str = "pose",
             config: SlamConfig | None = None, seed=0, symmetries: dict[str, Symmetry] | None = None,
             backend: str = "ekf", huber_k: float | None = None) -> SlamResult:
    """Run the filter over ``dataset`` in ``mode`` (see :mod:`semslam.slam.session`) and evaluate it against the
    dataset's ground truth when present.

    Parameters
    ----------
    dataset : Dataset
        Vehicle description, navigation logs (and ground truth for the metrics).
    detections_by_scan : dict, optional
        ``{scan_id: [Detection]}`` in the scanner frame, each with ``stamp_s`` (from :func:`detect_mission`, a
        detections file, or the simulator's truth-based source). None or empty: no object measurements.
    mode : {"dr", "position", "pose", "pose+heading"}
    config : SlamConfig, optional
    seed : int or numpy Generator
        Seeds the launch-fix error and the survey error drawn around the ground truth (simulated data only).
    symmetries : dict, optional
        Symmetry per class label.
    backend : {"ekf", "isam2", "batch"}
        The EKF (:class:`SlamSession`) or a GTSAM factor graph (:class:`semslam.slam.graph.GraphSession`).
    huber_k : float, optional
        Graph backends: Huber threshold of the detection factors (None: Gaussian).
    """
    check_choice("mode", mode, MODES, caller="run_slam")
    check_choice("backend", backend, BACKENDS, caller="run_slam")
    if not isinstance(dataset, Dataset):
        raise SlamError(f"The 'dataset' argument of run_slam must be a Dataset. Got {type(dataset).__name__} instead.")
    if len(dataset.attitude) == 0:
        raise SlamError("The dataset has no attitude samples: the filter needs the attitude as input.")
    cfg = SlamConfig() if config is None else config
    rng = as_rng(seed, caller="run_slam")
    # initial-state and survey errors: their own stream (spawning draws nothing), the same in every mode
    init_rng = rng.spawn(1)[0] if isinstance(seed, np.random.Generator) else \
        np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
    t0 = _start(dataset)
    # the launch point: truth + an N(0, initial_position_sigma) fix error where truth exists (drawn so that the
    # initial NEES is chi-square like every later one), the origin otherwise; the first valid DVL velocity
    p0 = dataset.truth.interpolate_position(t0)[0] if dataset.truth is not None else np.zeros(3)
    dp0 = init_rng.normal(0.0, cfg.initialisation.initial_position_sigma_m, 3)
    if dataset.truth is not None and cfg.initialisation.perturb_initial_position:
        p0 = p0 + dp0
    # the initial velocity: the first valid DVL sample if it is at the start (a later one would be the future's
    # velocity given as the start's), else unknown (zero, known to the vehicle's velocity spread)
    valid = np.flatnonzero(dataset.dvl.valid & (dataset.dvl.stamp_s <= t0 + cfg.motion.unaided_after_s))
    v0 = dataset.dvl.velocity_body_mps[valid[0]] if len(valid) else None
    kw = dict(mode=mode, config=cfg, symmetries=symmetries, start_stamp_s=t0, initial_position_ned_m=p0,
              initial_velocity_body_mps=v0)
    if backend == "ekf":
        session = SlamSession(dataset.vehicle, **kw)
    else:
        from .graph import GraphSession  # lazily: GTSAM is imported only for the graph backends

        session = GraphSession(dataset.vehicle, backend=backend, huber_k=huber_k, **kw)
    if cfg.initialisation.surveyed_objects:
        session.add_surveyed_landmarks(*_surveyed(dataset, cfg, init_rng))
    # the filter's matrices are small: BLAS threads only spin on them (6x slower on 2 busy cores, measured)
    with threadpool_limits(limits=1, user_api="blas"):
        for t, kind, payload in merged_messages(dataset, (detections_by_scan or {}) if mode != "dr" else {}):
            feed_message(session, t, kind, payload)
        result = session.finish()
    return evaluate_run(result, dataset, symmetries)


def _surveyed(dataset: Dataset, cfg: SlamConfig, rng: np.random.Generator):
    """The surveyed objects' poses: the dataset's object poses plus an N(0, survey sigma) error (a simulated
    survey; a real survey's poses are given to :meth:`SlamSession.add_surveyed_landmarks` directly)."""
    byname = {o.name: o for o in dataset.objects}
    missing = [n for n in cfg.initialisation.surveyed_objects if n not in byname]
    if missing:
        raise SlamError(f"The 'surveyed_objects' of SlamConfig must name objects of the mission "
                        f"({sorted(byname)}). Got {missing} instead.")
    labels, poses = [], []
    for name in cfg.initialisation.surveyed_objects:
        o = byname[name]
        R = kern.so3_exp(rng.normal(0.0, cfg.initialisation.survey_rotation_sigma_rad, 3)) @ o.T_world_object.rotation
        p = o.T_world_object.translation_m + rng.normal(0.0, cfg.initialisation.survey_position_sigma_m, 3)
        labels.append(o.label)
        poses.append(RigidTransform.from_rotation_translation(R, p))
    return list(cfg.initialisation.surveyed_objects), labels, poses
