"""The whole job of ``semslam run`` as one library call: a dive from any source through the runner, and the run
directory written from it (evo's library/CLI split: the command only parses and calls :func:`run_dive`).

::

    RUN/
      run.json              the source, the topic map and vehicle file used, the start, counts, the verdicts
      detections.jsonl      the detections kept for SLAM (+ detections.jsonl.config.json: the pipeline's settings)
      slam/<mode>/          per mode: trajectory.csv, landmarks.csv, metrics.json (with its health verdict), ...
                            + trajectory.tum/.kitti, map.json/.csv/.ply, run.mcap
      report.html           (written by the caller: the report sits above this layer)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .._atomic import atomic_write_text
from .._jsonable import to_jsonable
from ..slam import MODES, SlamConfig
from ..io.detections import write_detections_jsonl
from .rundir import write_run
from .rundir import DETECTIONS, mode_dir
from .health import health_verdict
from .runner import LOOKAHEAD, RunOutcome, run_stream
from .sources import open_dive

RUN_JSON = "run.json"


def run_dive(source: Any, out_dir: str | Path, *, db, modes=MODES, topics=None, vehicle=None, msg_dirs=(),
             config: SlamConfig | None = None, pipeline_config=None, backend: str = "ekf", seed: int = 0,
             survey=None, up_from_attitude: bool = False, keep_unreliable: bool = False, export: bool = True) -> dict:
    """Recognise every scan of the dive ``source`` (bag, dataset directory, Dataset) with the view database
    ``db``, run SLAM in every mode of ``modes`` in one pass, and write the run directory ``out_dir`` (which the
    caller creates, e.g. with :func:`semslam._outdir.staged_output_dir`). Returns the payload the CLI prints: per
    mode the metrics and the health verdict, the detection summary, the start."""
    from ..pipeline import ScanRecognizer

    out = Path(out_dir)
    cfg = SlamConfig() if config is None else config
    dive = open_dive(source, topics=topics, vehicle=vehicle, msg_dirs=msg_dirs)
    if survey is not None:
        adopt_survey_frame(dive, survey)
    recognizer = ScanRecognizer(db, pipeline_config, seed=seed)
    recognizer.warm_up()
    outcome = run_stream(dive, modes=tuple(modes), recognizer=recognizer, config=cfg, symmetries=db.symmetries(),
                         backend=backend, survey=survey, seed=seed, keep_unreliable=keep_unreliable,
                         up_from_attitude=up_from_attitude, lookahead=LOOKAHEAD)
    # after the run: a dataset directory's (or a dataset's) ground truth, when it has one, for the metrics only
    from ..evaluation.slam_run import evaluate_results, load_reference

    outcome.results = evaluate_results(outcome.results, load_reference(source), db.symmetries())
    return write_outcome(outcome, out, dive=dive, pipeline_config=recognizer.config, seed=seed, export=export)


def detect_dive(source: Any, *, db, topics=None, vehicle=None, msg_dirs=(), pipeline_config=None, seed: int = 0,
                up_from_attitude: bool = False, keep_unreliable: bool = False, progress: Any = False) -> RunOutcome:
    """Recognise every scan of the dive ``source`` (bag, dataset directory, Dataset) with the view database ``db``:
    the detections :func:`run_dive` would keep for SLAM, through the same runner (only dead reckoning rides along,
    for the scans' timing), nothing written. ``semslam detect`` is this call and a file.

    Raises :class:`~semslam.errors.InputError` when the dive has no scan."""
    from .._progress import progress_steps
    from ..errors import InputError
    from ..pipeline import ScanRecognizer

    dive = open_dive(source, topics=topics, vehicle=vehicle, msg_dirs=msg_dirs)
    recognizer = ScanRecognizer(db, pipeline_config, seed=seed)
    recognizer.warm_up()
    n_scans = len(source.scans) if hasattr(source, "scans") else dive.metadata.get("n_scans")
    with progress_steps(progress, n_scans, "recognise", "scan") as step:
        outcome = run_stream(dive, modes=("dr",), recognizer=recognizer, symmetries=db.symmetries(), seed=seed,
                             keep_unreliable=keep_unreliable, up_from_attitude=up_from_attitude,
                             on_scan=lambda *_: step(), lookahead=LOOKAHEAD)
    if not outcome.scans:
        raise InputError(f"The dive {dive.name!r} has no scans to recognise objects in.")
    return outcome


def slam_dive(source: Any, detections_by_scan: dict, *, modes=MODES, topics=None, vehicle=None, msg_dirs=(),
              config: SlamConfig | None = None, symmetries=None, backend: str = "ekf", survey=None) -> dict:
    """SLAM in every mode of ``modes`` (one pass of the runner) on the dive ``source`` with detections known in
    advance (``{scan_id: [Detection]}``, e.g. read from ``semslam detect``'s file), then evaluated against the
    source's ground truth when it has one: ``{mode: SlamResult}``. ``semslam slam`` is this call and a run
    directory."""
    dive = open_dive(source, topics=topics, vehicle=vehicle, msg_dirs=msg_dirs, scans=False)
    if survey is not None:
        adopt_survey_frame(dive, survey)
    outcome = run_stream(dive, modes=tuple(modes), detections_by_scan=detections_by_scan,
                         config=SlamConfig() if config is None else config, symmetries=symmetries, backend=backend,
                         survey=survey)
    from ..evaluation.slam_run import evaluate_results, load_reference

    return evaluate_results(outcome.results, load_reference(source), symmetries)


def adopt_survey_frame(dive, survey) -> None:
    """A prior map placed about a geodetic origin defines the world frame: a bag dive without an origin of its own
    takes the map's (its fixes are then converted about it); one with another origin is refused."""
    from ..geodesy import GeodeticOrigin
    from ..slam.survey import check_survey_frame

    if survey.geodetic_origin is not None and dive.geodetic_origin is None and dive.kind == "bag":
        dive.geodetic_origin = GeodeticOrigin.from_dict(survey.geodetic_origin)
        dive.metadata["geodetic_origin_from"] = f"the prior map {survey.source}"
    check_survey_frame(survey, dive.geodetic_origin)


def write_outcome(outcome: RunOutcome, out: Path, *, dive, pipeline_config=None, seed: int = 0, export: bool = True,
                  extra: dict | None = None) -> dict:
    """Write a :class:`RunOutcome` as a run directory (see the module docstring) and return the CLI's payload."""
    from .export import export_run

    out = Path(out)
    write_detections_jsonl(out / DETECTIONS, outcome.detections_by_scan)
    if pipeline_config is not None:
        atomic_write_text(out / (DETECTIONS + ".config.json"), json.dumps(to_jsonable(
            {"pipeline": pipeline_config.to_dict(), "seed": seed}), indent=2) + "\n")
    verdicts, metrics = {}, {}
    origin_ns = int(dive.metadata.get("time_origin_ns", 0) or 0)
    for mode, res in outcome.results.items():
        v = health_verdict(res, counts=outcome.counts)
        res.metrics["health"] = v.as_dict()
        if dive.geodetic_origin is not None:
            res.metrics["geodetic_origin"] = dive.geodetic_origin.as_dict()
        where = mode_dir(out, mode)
        write_run(res, where)
        if export:
            export_run(res, where, detections_by_scan=outcome.detections_by_scan or None,
                       T_vehicle_scanner=dive.vehicle.scanner.T_vehicle_scanner if outcome.detections_by_scan
                       else None, time_origin_ns=origin_ns)
        verdicts[mode] = v
        metrics[mode] = res.metrics
    overall = max((v.level for v in verdicts.values()), key=("ok", "warning", "bad").index, default="ok")
    run_doc = {"format": "semslam-run", "format_version": 1, "source": dive.metadata, "vehicle": dive.vehicle.name,
               "geodetic_origin": None if dive.geodetic_origin is None else dive.geodetic_origin.as_dict(),
               "start": None if outcome.start is None else outcome.start.as_dict(), "counts": outcome.counts,
               "verdict": overall, "health": {m: v.as_dict() for m, v in verdicts.items()},
               # counts only: the latencies (wall time) are in the CLI's payload, never in a run's files, so that
               # the same dive gives the same run directory on any machine
               "detection": {k: v for k, v in outcome.detection_summary().items() if "latency" not in k},
               **(extra or {})}
    atomic_write_text(out / RUN_JSON, json.dumps(to_jsonable(run_doc), indent=2) + "\n")
    return {"detection": outcome.detection_summary(), "slam": metrics, "verdict": overall,
            "health": {m: v.as_dict() for m, v in verdicts.items()}, "start": run_doc["start"],
            "counts": outcome.counts}
