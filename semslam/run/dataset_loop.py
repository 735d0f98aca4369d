"""Run the semantic EKF over a whole dataset in memory: :func:`run_slam` feeds the dataset's logs and the given
detections through the streaming runner of ``semslam run`` (:class:`semslam.run.runner.Runner`), then evaluates
against the dataset's ground truth when it has one. The run's start comes from the dive's own data
(:mod:`semslam.slam.initial`), never from its truth: the same dive with or without truth gives the same estimate.

:func:`merged_messages` and :func:`feed_message` step a session by hand, message by message, in the runner's
processing order (to look at the filter between two messages)."""

from __future__ import annotations

import math
from typing import Any


from .._validation import check_choice
from ..dataset import Dataset
from ..detection import Detection
from ..errors import SlamError
from ..symmetry import Symmetry
from ..slam.config import MODES, SlamConfig
from ..evaluation.slam_run import evaluate_run
from ..modes import BACKENDS
from ..slam.results import SlamResult
from ..slam.survey import Survey



def feed_message(session: Any, stamp_s: float, kind: str, payload: tuple) -> None:
    """Give one message of :func:`merged_messages` to a session (any :class:`SlamSession`: its ``add_*``)."""
    if kind == "attitude":
        session.add_attitude(stamp_s, *payload)
    elif kind == "dvl":
        session.add_dvl(stamp_s, payload[0], valid=payload[1], beam_range_m=payload[2])
    elif kind == "depth":
        session.add_depth(stamp_s, *payload)
    elif kind == "fix":
        session.add_position_fix(stamp_s, *payload)
    elif kind == "detections":
        session.add_detections(stamp_s, *payload)
    else:
        raise SlamError(
            f"The 'kind' argument of feed_message must be attitude, dvl, depth, fix or detections. Got {kind!r} "
            "instead."
        )


def merged_messages(dataset: Dataset, detections_by_scan: dict[int, list[Detection]]):
    """Every message of the dataset and the detections, in processing order ``(stamp, kind, payload)``: by
    stamp, then attitude, DVL, depth, position fix, detections. Detections are grouped by (stamp, scan)."""
    a, d, z, f = dataset.attitude, dataset.dvl, dataset.depth, dataset.fixes
    beams = d.beam_range_m
    msgs = [(float(t), 0, i, "attitude") for i, t in enumerate(a.stamp_s)]
    msgs += [(float(t), 1, i, "dvl") for i, t in enumerate(d.stamp_s)]
    msgs += [(float(t), 2, i, "depth") for i, t in enumerate(z.stamp_s)]
    if f is not None:
        msgs += [(float(t), 3, i, "fix") for i, t in enumerate(f.stamp_s)]
    groups: dict = {}
    for sid, dets in detections_by_scan.items():
        for det in dets:
            st = float(det.stamp_s)
            if not math.isfinite(st):
                raise SlamError(f"Every detection given to run_slam needs a finite 'stamp_s'. Got {det.stamp_s!r} "
                                f"in scan {sid} instead.")
            groups.setdefault((st, sid), []).append(det)
    keys = list(groups)
    msgs += [(k[0], 4, i, "detections") for i, k in enumerate(keys)]
    msgs.sort(key=lambda m: (m[0], m[1], m[2]))
    for t, _, i, kind in msgs:
        if kind == "attitude":
            yield t, kind, (a.rpy_rad[i],)
        elif kind == "dvl":
            yield t, kind, (d.velocity_body_mps[i], bool(d.valid[i]), None if beams is None else beams[i])
        elif kind == "depth":
            yield t, kind, (float(z.depth_m[i]),)
        elif kind == "fix":
            yield t, kind, (f.position_ne_m[i], f.covariance_ne_m2[i])
        else:
            yield t, kind, (groups[keys[i]],)


def run_slam(dataset: Dataset, detections_by_scan: dict[int, list[Detection]] | None = None, *, mode: str = "pose",
             config: SlamConfig | None = None, symmetries: dict[str, Symmetry] | None = None,
             backend: str = "ekf", huber_k: float | None = None, survey: Survey | None = None) -> SlamResult:
    """Run the filter over ``dataset`` in ``mode`` (see :mod:`semslam.slam.session`) and evaluate it against the
    dataset's ground truth when present (after the run: the estimate never reads the truth).

    Parameters
    ----------
    dataset : Dataset
        Vehicle description, navigation logs, position fixes (and ground truth for the metrics).
    detections_by_scan : dict, optional
        ``{scan_id: [Detection]}`` in the scanner frame, each with ``stamp_s`` (from :func:`detect_dataset`, a
        detections file, or the simulator's truth-based source). None or empty: no object measurements.
    mode : {"dr", "position", "pose", "pose+heading"}
    config : SlamConfig, optional
    symmetries : dict, optional
        Symmetry per class label.
    backend : {"ekf", "isam2", "batch"}
        The EKF (:class:`SlamSession`) or a GTSAM factor graph (:class:`semslam.slam.graph.GraphSession`).
    huber_k : float, optional
        Graph backends: Huber threshold of the detection factors (None: Gaussian).
    survey : Survey, optional
        Landmarks known before the run (:func:`semslam.slam.survey.read_survey`: a survey CSV, an earlier map).
    """
    check_choice("mode", mode, MODES, caller="run_slam")
    check_choice("backend", backend, BACKENDS, caller="run_slam")
    if not isinstance(dataset, Dataset):
        raise SlamError(f"The 'dataset' argument of run_slam must be a Dataset. Got {type(dataset).__name__} instead.")
    if len(dataset.attitude) == 0:
        raise SlamError("The dataset has no attitude samples: the filter needs the attitude as input.")
    from .runner import run_stream
    from .sources import open_dive

    # the streaming runner of `semslam run`, fed from the dataset in memory: one loop for every entry point
    outcome = run_stream(open_dive(dataset, scans=False), modes=(mode,), config=config, symmetries=symmetries,
                         backend=backend, huber_k=huber_k, survey=survey,
                         detections_by_scan=(detections_by_scan or {}) if mode != "dr" else {})
    return evaluate_run(outcome.results[mode], dataset, symmetries)
