"""The whole mission in one call (``semslam demo``): build the built-in view database, evaluate it by
leave-one-out, simulate the tank mission, recognise objects in every scan with the real pipeline, run SLAM in
every mode on the same detections, and write a run directory with a self-contained report.

Run directory layout (every file written atomically)::

    RUN/
      config.json          resolved configuration of every stage, and the seed
      db.npz               the built-in view database (Kinect-like views)
      evaluation/          leave-one-out results (Tables 1 and 2): loo_<descriptor>_<classifier>.json
      mission/             the simulated mission (docs/dataset-format.md)
      detections.jsonl     one JSON line per detection (with scan_id and stamp_s)
      recognition.json     every cluster of every scan against the ground truth, pose errors, timings
      fig3_scan.npz        the scan drawn in Fig. 3 (points, cluster labels)
      consensus.json       the observations behind the first landmark's initialisation
      slam/<mode>/         trajectory.csv, trajectory_smoothed.csv, landmarks.csv, updates.csv, metrics.json,
      config.json per mode
      metrics.json         the headline metrics of every stage
      figures/*.png        every figure of the report
      report.html          one self-contained page (figures embedded)
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ._atomic import atomic_write_text
from ._outdir import staged_output_dir
from ._jsonable import to_jsonable
from .errors import InputError
from .experiments.recognition_scoring import recognition_summary, score_scan
from .slam.config import MODES


def mode_dirname(mode: str) -> str:
    """Directory name of a SLAM mode (``pose+heading`` -> ``pose_heading``)."""
    return mode.replace("+", "_")


@dataclass(frozen=True)
class DemoConfig:
    """What :func:`run_demo` does.

    Attributes
    ----------
    seed : int
        Seeds everything (database acquisition, mission, recognition, SLAM): the same seed, the same run.
    quick : bool
        Two loops instead of three (one revisit, so that SLAM has something to close) and one SVM grid search
        instead of one per fold: a first look in well under a minute.
    loops : int, optional
        Loops of the mission (default 3, or 2 with ``quick``).
    modes : tuple of str
        SLAM modes run on the same detections.
    use_unreliable : bool
        Pass detections whose alignment was flagged unreliable to the filter (default False: skipped).
    descriptor, classifier : str
        The pipeline's matcher (see :class:`semslam.pipeline.PipelineConfig`).
    models_dir : str, optional
        A folder of the user's CAD models (``models.toml`` and meshes, see ``semslam db build --models``): the
        database is built from them and they are the objects of the mission, instead of the built-in fittings.
    db_sensor : {"kinect", "laser", "kinect+laser"}, optional
        The sensor the recognition views of the database are rendered with
        (:func:`semslam.simulation.model_database.sensor_database`). Default: the mission's laser scanner for
        ``models_dir`` (a database matched to the sensor), the papers' Kinect views for the built-in fittings.
    preset : str, optional
        The scan pipeline's named preset (:data:`semslam.run.config.PRESETS`; default: the ``config_file``'s, else
        ``"seabed"`` for ``models_dir`` with a laser database (:data:`MODELS_PRESET`), else ``"default"``); its
        descriptor and classifier are ``descriptor`` and ``classifier``.
    config_file : str, optional
        A run configuration file (``docs/configuration.md``) on top of ``preset``: its ``pipeline`` and ``slam``
        sections, ``run.up_from_attitude``, ``run.keep_unreliable`` and ``run.backend`` are the demo's (its modes are
        ``modes``, its seed ``seed``). Read and checked before anything is written.
    """

    seed: int = 0
    quick: bool = False
    loops: int | None = None
    modes: tuple = MODES
    use_unreliable: bool = False
    descriptor: str = "esf+vfh"
    classifier: str = "chi2"
    extras: dict = field(default_factory=dict)
    models_dir: str | None = None
    db_sensor: str | None = None
    preset: str | None = None
    config_file: str | None = None

    def __post_init__(self) -> None:
        from .run.config import PRESETS
        from .simulation.model_database import DB_SENSORS

        if self.db_sensor is None:
            object.__setattr__(self, "db_sensor", "kinect" if self.models_dir is None else "laser")
        if self.db_sensor not in DB_SENSORS:
            raise InputError(f"The 'db_sensor' argument of DemoConfig must be one of {DB_SENSORS}. "
                             f"Got {self.db_sensor!r} instead.")
        if self.preset is not None and self.preset not in PRESETS:
            raise InputError(f"The 'preset' argument of DemoConfig must be one of {tuple(PRESETS)}. "
                             f"Got {self.preset!r} instead.")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise InputError(
                f"The 'seed' argument of DemoConfig must be a non-negative integer. Got {self.seed!r} instead."
            )
        if self.loops is not None and (
            isinstance(self.loops, bool) or not isinstance(self.loops, int) or self.loops < 1
        ):
            raise InputError(f"The 'loops' argument of DemoConfig must be an integer >= 1. Got {self.loops!r} instead.")
        bad = [m for m in self.modes if m not in MODES]
        if bad or not self.modes:
            raise InputError(
                f"The 'modes' argument of DemoConfig must be a non-empty subset of {MODES}. Got {self.modes!r} instead."
            )

    @property
    def n_loops(self) -> int:
        return self.loops if self.loops is not None else (2 if self.quick else 3)


def _write_json(path: Path, payload: object) -> None:
    atomic_write_text(path, json.dumps(to_jsonable(payload), indent=2) + "\n")


#: the preset of ``semslam demo --models`` when neither ``--preset`` nor the configuration file names one
MODELS_PRESET = "seabed"


def _demo_preset(cfg: DemoConfig) -> str | None:
    """The demo's preset: the one given or the configuration file's; else, for the user's models with a laser
    database, :data:`MODELS_PRESET` (their objects rest on the tank's floor in their most probable pose, often cut by
    the swath's border: on the shared real models' held-out seed 1 with a laser database, precision / recall 83.3 /
    47.0 % and mean pose NEES 24.6 with the defaults, 99.1 / 94.1 % and 7.4 with it, benchmarks/RESULTS.md); else
    the library's defaults (the built-in fittings' published figures)."""
    if cfg.preset is not None or cfg.models_dir is None or cfg.db_sensor == "kinect":
        return cfg.preset
    if cfg.config_file is not None:
        from ._tables import read_table
        from .errors import ConfigError

        raw = read_table(cfg.config_file, "configuration file", ConfigError)
        if isinstance(raw, dict) and "preset" in raw:
            return cfg.preset
    return MODELS_PRESET


class _Stages:
    """Times the stages and reports progress in one line each."""

    def __init__(self, log: Callable[[str], None]):
        self.log = log
        self.timings_s: dict[str, float] = {}

    def run(self, name: str, fn, *args, **kwargs):
        self.log(f"[semslam demo] {name} ...")
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        self.timings_s[name] = time.perf_counter() - t0
        self.log(f"[semslam demo] {name}: {self.timings_s[name]:.1f} s")
        return out


def run_demo(out_dir: str | Path, config: DemoConfig | None = None, *, progress: bool = True,
             log: Callable[[str], None] = print, overwrite: bool = False) -> dict:
    """Run the whole mission and write the run directory ``out_dir``; return the headline metrics.

    Raises :class:`~semslam.errors.InputError` if ``out_dir`` is a file, a non-empty directory semslam did not
    write, or an earlier run (unless ``overwrite``): a run never mixes its files with another's.
    """
    from .dataset import read_dataset, write_dataset
    from .simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    cfg = DemoConfig() if config is None else config
    final = Path(out_dir)
    objects = None
    from .run.config import load_run_config

    chosen = _demo_preset(cfg)
    picked = chosen != cfg.preset  # the demo chose the preset for the user's models
    cfg = dataclasses.replace(cfg, preset=chosen) if picked else cfg
    run_cfg = load_run_config(cfg.config_file, preset=cfg.preset)  # read and checked before anything is written
    if cfg.models_dir is not None:  # read (and checked) before anything is written
        from .simulation.cad_models import read_models

        objects = read_models(cfg.models_dir)
    # built beside the target and swapped in at the end: a killed demo leaves the previous run intact, and only a
    # directory semslam wrote is ever replaced (semslam._outdir)
    with staged_output_dir(final, overwrite=overwrite, kind="demo", inputs=(cfg.models_dir,)) as out:
        stages = _Stages(log)
        t_start = time.perf_counter()
        if picked:
            log(f"[semslam demo] preset {chosen!r}: your objects rest on the tank's floor and the database is "
                f"rendered by the mission's laser, the scene that preset is for (--preset default: the library's "
                f"defaults)")

        # 1. the database (built-in, or from the user's models) and its leave-one-out evaluation (Tables 1 and 2)
        db, evaluations = _database_stage(stages, cfg, objects, out, progress)

        # 2. the mission
        sim_cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=cfg.n_loops))
        mission = stages.run("simulate mission", simulate_dataset, sim_cfg, seed=cfg.seed, progress=progress,
                             objects=objects)
        stages.run("write mission", write_dataset, mission, out / "mission")
        # from here on the demo works on the mission as written (float32 scans), exactly what `semslam detect` and
        # `semslam slam` read from the run directory: the commands reproduce the demo's numbers
        mission = read_dataset(out / "mission")

        # 3-4. every scan recognised and SLAM in every mode, in one pass of the streaming runner (`semslam run`'s)
        rec_out, slam_results = stages.run("recognise every scan, SLAM in every mode", _run_dive, mission, db, cfg,
                                           run_cfg, out, progress, None if objects is None else
                                           {k: m.symmetry for k, m in objects.items()})

        # 5. consensus figure data, metrics, report
        _write_consensus(out, mission, rec_out["detections_by_scan"], slam_results.get("pose"))
        metrics = _headline_metrics(evaluations, rec_out["summary"], slam_results)
        metrics["timings_s"] = dict(stages.timings_s)
        metrics["timings_s"]["total"] = time.perf_counter() - t_start
        _write_json(out / "metrics.json", metrics)
        _write_json(out / "config.json", {
            "demo": asdict(cfg), "simulator": sim_cfg.to_dict(), "pipeline": rec_out["pipeline_config"],
            "slam": {m: r.config.to_dict() for m, r in slam_results.items()}, "database": db.summary(),
        })
        from .report.build import build_report

        stages.run("write report", build_report, out)
    metrics["report"] = str(final / "report.html")
    return metrics


def _database_stage(stages: "_Stages", cfg: DemoConfig, objects, out: Path, progress: bool):
    """The view database (built-in objects, or the user's models), saved in the run, and its leave-one-out
    evaluations (Tables 1 and 2 of the paper): ``(database, {"esf_svm": result, ...})``."""
    from .evaluation.classifier import leave_one_out
    from .recognition import build_database, save_database
    from .simulation import builtin_view_clouds
    from .simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT

    if cfg.db_sensor != "kinect":
        from .simulation import SimulatorConfig
        from .simulation.model_database import sensor_database
        from .simulation.objects import builtin_objects

        db = stages.run(f"render and describe database views ({cfg.db_sensor}, the mission's scanner)",
                        sensor_database, builtin_objects() if objects is None else objects, sensor=cfg.db_sensor,
                        seed=cfg.seed, scanner=SimulatorConfig().scanner, progress=progress)
    elif objects is None:
        views, classes = stages.run("acquire database views (Kinect-like, survey geometry)", builtin_view_clouds,
                                    seed=cfg.seed, config=SURVEY_KINECT)
        model_views, _ = stages.run("acquire pose-model views (Kinect-like, 60 deg, 0.7 m)", builtin_view_clouds,
                                    seed=cfg.seed, config=POSE_MODEL_KINECT)
    else:
        from .simulation.cad_models import models_view_clouds

        views, classes = stages.run("acquire database views of your models (Kinect-like, survey geometry)",
                                    models_view_clouds, objects, seed=cfg.seed, config=SURVEY_KINECT)
        model_views, _ = stages.run("acquire pose-model views of your models (Kinect-like, 60 deg, 0.7 m)",
                                    models_view_clouds, objects, seed=cfg.seed, config=POSE_MODEL_KINECT,
                                    tied_rests=True)
    if cfg.db_sensor == "kinect":
        db = stages.run("describe database views (ESF, VFH)", build_database, views, classes, seed=cfg.seed,
                        model_views=model_views, progress=progress)
    save_database(db, out / "db.npz")
    evaluations = {}
    for descriptor in ("esf", "vfh"):
        for clf_name in ("svm", "chi2"):
            clf = "chi2" if clf_name == "chi2" else _svm_for_loo(db, descriptor, cfg)
            res = stages.run(f"leave-one-out {descriptor.upper()} {clf_name}", leave_one_out, db,
                             descriptor=descriptor, classifier=clf, seed=cfg.seed, n_jobs=-1,
                             progress=progress and clf_name == "svm")
            evaluations[f"{descriptor}_{clf_name}"] = res
            _write_json(out / "evaluation" / f"loo_{descriptor}_{clf_name}.json", res.to_dict())
    return db, evaluations


def _svm_for_loo(db, descriptor: str, cfg: DemoConfig):
    """The SVM evaluated by leave-one-out. Full run: the whole Hsu et al. grid search inside every fold
    (nested, unbiased). Quick run: one grid search on all the views, then leave-one-out at that (C, gamma):
    32x faster and slightly optimistic (said in the report)."""
    import math

    from .recognition import SvmClassifier

    if not cfg.quick:
        return SvmClassifier(seed=cfg.seed)
    best = SvmClassifier(seed=cfg.seed).fit(db.features(descriptor), db.labels)
    c, g = round(math.log2(best.C_)), round(math.log2(best.gamma_))
    return SvmClassifier(c_log2=(c, c, 1), gamma_log2=(g, g, 1), seed=cfg.seed)


def _run_dive(mission, db, cfg: DemoConfig, run_cfg, out: Path, progress: bool, symmetries: dict | None = None):
    """The mission through :func:`semslam.run.run_stream` (the path of ``semslam run``): every scan recognised and
    scored against the simulator's truth as it passes (a separate pass: the estimate never sees it), every mode in
    one pass; detections.jsonl, recognition.json, the Fig. 3 scan and each mode's run directory written."""
    from ._progress import progress_steps
    from .pipeline import ScanRecognizer
    from .run import open_dive, run_stream
    from .run.runner import LOOKAHEAD
    from .simulation.truth_slam import builtin_symmetries
    from .io.detections import write_detections_jsonl
    from .run.rundir import write_run
    from .run.rundir import DETECTIONS, mode_dir

    pipe_cfg = dataclasses.replace(run_cfg.pipeline_config(), descriptor=cfg.descriptor, classifier=cfg.classifier)
    recognizer = ScanRecognizer(db, pipe_cfg, seed=cfg.seed)
    recognizer.warm_up()
    records: list[dict] = []
    best_scan: list = [-1, None]
    with progress_steps(progress, len(mission.scans), "recognise", "scan") as step:
        def score(msg, kept, stats, result) -> None:  # the separate pass against the simulator's ground truth
            rec = mission.scan_record(msg.scan_id)
            records.extend(score_scan(mission, rec, msg.cloud, result, db))
            if len(result.detections) > best_scan[0]:
                best_scan[:] = [len(result.detections), (rec.scan_id, msg.cloud, result)]
            step()

        symmetries = builtin_symmetries() if symmetries is None else symmetries
        keep = cfg.use_unreliable or run_cfg.run.keep_unreliable
        found = run_stream(open_dive(mission), modes=tuple(cfg.modes), recognizer=recognizer, symmetries=symmetries,
                           seed=cfg.seed, keep_unreliable=keep, on_scan=score, lookahead=LOOKAHEAD,
                           up_from_attitude=run_cfg.run.up_from_attitude, config=run_cfg.slam_config(),
                           backend=run_cfg.run.backend)
    write_detections_jsonl(out / DETECTIONS, found.detections_by_scan)
    summary = recognition_summary(records, [s["timings_ms"] for s in found.scans])
    _write_json(out / "recognition.json", {"summary": summary, "clusters": records})
    if best_scan[1] is not None:
        _write_fig3_data(out / "fig3_scan.npz", *best_scan[1])
    from .evaluation.slam_run import evaluate_results

    found.results = evaluate_results(found.results, mission, symmetries)  # against the simulator's truth, after
    for mode, res in found.results.items():
        write_run(res, mode_dir(out, mode))
    rec_out = {"detections_by_scan": found.detections_by_scan, "summary": summary,
               "pipeline_config": pipe_cfg.to_dict()}
    return rec_out, found.results


def _write_fig3_data(path: Path, scan_id: int, cloud, result) -> None:
    from ._atomic import atomic_open

    seg = result.segmentation
    cluster_of_point = np.full(cloud.n_points, -1, dtype=np.int32)
    for k in range(seg.n_clusters):
        cluster_of_point[seg.input_indices(k)] = k
    labels = np.array([c.label for c in result.clusters], dtype=str) if result.clusters else np.zeros(0, str)
    poses = np.array([c.detection.T_sensor_object.matrix if c.detection is not None else np.full((4, 4), np.nan)
                      for c in result.clusters]).reshape(-1, 4, 4)
    with atomic_open(path, "wb") as fh:
        np.savez(fh, scan_id=scan_id, points_xyz_m=cloud.points_xyz_m.astype(np.float32), cluster=cluster_of_point,
                 labels=labels, T_scanner_object=poses)


def _write_consensus(out: Path, mission, detections_by_scan: dict, pose_result) -> None:
    """Replay the consensus initialisation of the first landmark for the report's figure: the observations
    of its class in the world frame (vehicle pose from the pose-mode estimate), which agreed, and the pose."""
    from .geometry import RigidTransform, rotation_from_rpy
    from .slam.consensus import ConsensusInitializer, Observation

    if pose_result is None or not detections_by_scan:
        return
    stamps, pos = pose_result.stamps_s, pose_result.position_ned_m
    ahrs_t, ahrs_rpy = mission.attitude.stamp_s, mission.attitude.rpy_rad
    cons = ConsensusInitializer(**_consensus_params(pose_result))
    pools: dict[str, list] = {}
    for scan_id in sorted(detections_by_scan):
        for det in detections_by_scan[scan_id]:
            t = det.stamp_s
            p = np.array([np.interp(t, stamps, pos[:, i]) for i in range(3)])
            i = int(np.clip(np.searchsorted(ahrs_t, t), 0, len(ahrs_t) - 1))
            T_wv = RigidTransform.from_rotation_translation(rotation_from_rpy(*ahrs_rpy[i]), p)
            T_wo = T_wv @ mission.vehicle.scanner.T_vehicle_scanner @ det.T_sensor_object
            obs = Observation(det.label, t, T_wo.translation_m, T_wo.rotation)
            pools.setdefault(det.label, []).append(obs)
            pool_before = list(cons.pools.get(det.label, [])) + [obs]
            res = cons.add(obs)
            if res is not None:
                members, mean_pos, R_mean = res
                member_ids = {id(m) for m in members}
                _write_json(out / "consensus.json", {
                    "label": det.label, "stamp_s": t,
                    "observations_xyz_m": [o.position_world_m for o in pool_before],
                    "observation_yaw_rad": [float(np.arctan2(o.R_world_object[1, 0], o.R_world_object[0, 0]))
                                            for o in pool_before],
                    "in_consensus": [id(o) in member_ids for o in pool_before],
                    "initial_xyz_m": mean_pos, "initial_yaw_rad": float(np.arctan2(R_mean[1, 0], R_mean[0, 0])),
                    "position_threshold_m": cons.position_threshold_m, "attitude_threshold": cons.attitude_threshold,
                    "min_observations": cons.min_observations,
                })
                return


def _consensus_params(result) -> dict:
    """The consensus rule the run used (its SlamConfig), for the figure's replay."""
    c = result.config.initialisation
    return {"position_threshold_m": c.consensus_position_m, "attitude_threshold": c.consensus_attitude,
            "min_observations": c.consensus_min_observations, "max_age_s": c.consensus_max_age_s}


def _headline_metrics(evaluations: dict, recognition: dict, slam_results: dict) -> dict:
    slam = {}
    for mode, res in slam_results.items():
        m = res.metrics
        slam[mode] = {k: m[k] for k in m if not isinstance(m[k], (list, dict)) or k in ("landmarks",)}
        sm = m.get("smoother") or {}
        slam[mode]["smoothed_ate_rmse_m"] = sm.get("ate_rmse_m")
    return {
        "leave_one_out": {k: {"accuracy": v.accuracy, "recall": v.recall} for k, v in evaluations.items()},
        "recognition": recognition,
        "slam": slam,
    }
