"""The 13-class catalogue benchmark: recognition in simulated laser scans of cluttered tank scenes.

The database holds every part of :mod:`semslam.simulation.catalogue` (Kinect-like views, survey geometry, as
the built-in database). The route of one mission sees four corner objects well, so the catalogue is split into
subsets of 4-5 parts; each subset is one cluttered mission (rocks and pipe offcuts not in the database), and
every scan is recognised against the full database. Reported: per class precision/recall, the confusion matrix
(true class or background vs predicted class or unknown), the background (tank + clutter) false-accept rate, split
into floor, rocks and pipe offcuts; then sweeps over range noise, scanner density, occlusion and
descriptor/classifier.

Pipeline settings (``--config``): ``defaults`` is ``PipelineConfig()`` as the built-in demo uses it;
``catalogue`` (the default here) adds the options measured better on this benchmark (seed 0; checked on seed 1):
hypothesis verification (``verify_min_fitness=0.95``, ``verify_max_visibility=0.15``: the estimated pose must put
the class's surface on the cluster and nowhere the scan sees through) and clusters cut by the scan border
recognised too (``border="flag"``: their pose is flagged unreliable, so SLAM does not use it), and the size test
measured against the class's principal extent (``size_reference="principal"``: the whole butterfly valve is longer
along its principal axis than its bounding box's longest side);
``catalogue_tol3`` adds a 3 cm cluster tolerance (joins the ball valve's lever to its body: better at the default
noise and at low density, but at 5 mm noise the floor's remains join the objects); ``catalogue_parts`` adds the
part-based hypotheses (``PipelineConfig(parts=PartsConfig())``, :mod:`semslam.pipeline.parts`: unknown clusters
near each other tried as one object, e.g. a gate valve's body and handwheel); ``catalogue_scene`` also checks
the visibility cost against the whole scan about the cluster (``verify_visibility_image="scene"``: a model point
behind another object is hidden, one outside the scan's footprint unknown); ``catalogue_border`` does so only
for the clusters cut by the scan border, and ``catalogue_border_unionscene`` also for every part-based union
(``PartsConfig(scene_visibility=True)``: a union may miss a part of its object that went to another cluster).
The other settings' headline numbers are printed too, on the same missions.

Database (``--db-sensor``): ``kinect`` (default) = Kinect-like survey views at 1.5 m, 12 azimuths x elevations
45/60/75/85 deg; ``laser`` = views rendered by the missions' own laser scanner from route-like viewpoints
(:mod:`semslam.simulation.laser_views`: altitude 1.4-1.6 m, cross-track offset up to 0.45 m, anywhere along the
sweep, vehicle motion during the scan; ``--laser-views`` whole views per class, ``--laser-cut-views`` extra views
the swath's border may cut): the database ``semslam db build --models DIR --vehicle V.toml`` builds with the
missions' scanner (:func:`~semslam.simulation.model_database.sensor_database`, its defaults: 48 + 16 views, 16
pose-model views, the scanner's camera recorded for verification); ``kinect+laser`` both. The pose-model views are
Kinect ones (0.7 m, 60 deg) in every case. ``--reject-margin`` overrides the settings' rejection margin (6, set
for the Kinect-to-laser gap).

Recall is counted per cluster (every cluster of a database object, including those cut by the scan border);
also printed: recall over the clusters not cut by the border, and per object (found in at least one scan).

    .venv/bin/python benchmarks/catalogue.py [--quick] [--plot FILE] [--sweep noise,density,occlusion,combo,margin]
                                             [--config catalogue|defaults|...] [--seed N] [--compare all|A,B|'']
                                             [--db-sensor kinect|laser|kinect+laser] [--reject-margin M]
                                             [--descriptor esf|vfh|esf+vfh] [--records FILE.jsonl]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections import Counter

import numpy as np

from semslam.experiments.recognition_scoring import score_scan
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.dataset_detection import detect_dataset
from semslam.pipeline.parts import PartsConfig
from semslam.recognition import build_database
from semslam.run.config import load_run_config
from semslam.simulation import ScannerConfig, SimulatorConfig, TrajectoryConfig, WorldConfig, simulate_dataset
from semslam.simulation.cad_models import models_view_clouds, with_resting_up
from semslam.simulation.catalogue import catalogue_objects
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT
from semslam.simulation.laser_views import LaserViewConfig
from semslam.simulation.model_database import LASER_CUT_VIEWS, LASER_VIEWS, sensor_database, sensor_view_clouds
from semslam.simulation.occlusion import occlude_objects
from semslam.segmentation import SegmentationConfig

BG, UNK = "background", "unknown"

_SEABED = load_run_config(preset="seabed").pipeline_config()

#: The pipeline settings compared (keyword arguments of PipelineConfig); see the module docstring.
CONFIGS = {
    "defaults": {},
    "catalogue": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                  "size_reference": "principal"},
    "catalogue_tol3": {"segmentation": SegmentationConfig(cluster_tolerance_m=0.03), "verify_min_fitness": 0.95,
                       "verify_max_visibility": 0.15, "border": "flag", "size_reference": "principal"},
    "catalogue_parts": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                        "size_reference": "principal", "parts": PartsConfig()},
    "catalogue_scene": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                        "size_reference": "principal", "parts": PartsConfig(), "verify_visibility_image": "scene"},
    "catalogue_border": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                         "size_reference": "principal", "parts": PartsConfig(), "verify_visibility_image": "border"},
    "catalogue_border_floor": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                               "size_reference": "principal", "parts": PartsConfig(), "verify_visibility_image": "border",
                               "verify_max_plane_penetration_m": 0.01},
    # + part gaps learnt from the database views: the `cluttered` preset since 2026-12-05; four-part unions with
    # recognised clusters among the parts since 2026-12-06 (session 22)
    "catalogue_border_floor_gaps": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                                    "size_reference": "principal",
                                    "parts": PartsConfig(view_gaps=True, max_parts=4, detected_parts=True),
                                    "verify_visibility_image": "border", "verify_max_plane_penetration_m": 0.01},
    "catalogue_border_floor_next": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                                    "size_reference": "principal", "parts": PartsConfig(),
                                    "verify_visibility_image": "border", "verify_max_plane_penetration_m": 0.01,
                                    "verify_next_classes": 1},
    # the seabed preset's pipeline section as it is (semslam.run.config.PRESETS); its up_from_attitude is --upright
    "seabed": {f.name: getattr(_SEABED, f.name) for f in dataclasses.fields(_SEABED)
               if f.name not in ("descriptor", "classifier")},
    # seabed trying the two next nearest classes after a failed verification (session 32; not adopted: seed 0 and the
    # real models' seeds 0 and 3 unchanged)
    "seabed_next2": {**{f.name: getattr(_SEABED, f.name) for f in dataclasses.fields(_SEABED)
                        if f.name not in ("descriptor", "classifier")}, "verify_next_classes": 2},
    # seabed with a border-cut cluster's pose search against the whole scan (session 27; not adopted: seed 2's
    # precision 95.3 -> 93.6 %)
    "seabed_border_scene": {**{f.name: getattr(_SEABED, f.name) for f in dataclasses.fields(_SEABED)
                               if f.name not in ("descriptor", "classifier")}, "pose_border_scene": True},
    # seabed with two translation steps per distance in the pose search (session 28; not adopted: seed 2's precision
    # 95.3 -> 94.4 %)
    "seabed_translation_steps": {**{f.name: getattr(_SEABED, f.name) for f in dataclasses.fields(_SEABED)
                                    if f.name not in ("descriptor", "classifier")},
                                 "pose": dataclasses.replace(_SEABED.pose, translation_steps_m=(
                                     0.03, 0.03, 0.015, 0.015, 0.008, 0.008, 0.006))},
    # seabed before session 30: no border-cut cluster tracked from the scan before (semslam.pipeline.tracking)
    "seabed_untracked": {**{f.name: getattr(_SEABED, f.name) for f in dataclasses.fields(_SEABED)
                            if f.name not in ("descriptor", "classifier")}, "track_border_cut_m": None},
    "catalogue_border_unionscene": {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "flag",
                                    "size_reference": "principal", "parts": PartsConfig(scene_visibility=True),
                                    "verify_visibility_image": "border"},
}


def subsets(labels: list[str], size: int = 4) -> list[list[str]]:
    """Consecutive groups of ``size`` (the last one absorbs a remainder of 1: 13 -> 4, 4, 5)."""
    groups = [labels[i:i + size] for i in range(0, len(labels), size)]
    if len(groups) > 1 and len(groups[-1]) == 1:
        last = groups.pop()
        groups[-1] = groups[-1] + last
    return groups


def build_db(models: dict, seed: int, elevations_deg=(75.0,), n_views: int = 8, *, sensor: str = "kinect",
             laser_views: int = LASER_VIEWS, laser_cut_views: int = LASER_CUT_VIEWS,
             laser_config: LaserViewConfig | None = None):
    """The recognition views + the pose-model views (Kinect, 0.7 m / 60 deg, as always).

    ``sensor``: ``"kinect"`` survey views at each elevation (1.5 m, ``n_views`` azimuths each); ``"laser"`` views
    rendered by the missions' laser scanner from route-like viewpoints (:mod:`semslam.simulation.laser_views`:
    ``laser_views`` whole views per class, headings every 360 / laser_views degrees, plus ``laser_cut_views``
    views that the swath's border may cut), the database ``semslam db build --models DIR --vehicle V.toml`` makes
    (:func:`~semslam.simulation.model_database.sensor_database`: 16 pose-model views, the scanner's camera
    recorded); ``"kinect+laser"`` both, the survey elevations of this benchmark beside the same laser views (8
    pose-model views, no camera: not a database ``db build`` makes)."""
    if sensor not in ("kinect", "laser", "kinect+laser"):
        raise ValueError(f"sensor must be kinect, laser or kinect+laser, got {sensor!r}")
    views, classes = [], None
    if "kinect" in sensor:
        for i, el in enumerate(elevations_deg):
            cfg = dataclasses.replace(SURVEY_KINECT, elevation_rad=float(np.radians(el)))
            v, classes = models_view_clouds(models, seed=seed + i, config=cfg, n_views=n_views)
            views += [(lab, f"{vid}_el{el:g}", cloud) for lab, vid, cloud in v]
    if sensor == "laser":  # the database `semslam db build --models DIR --vehicle V.toml` builds, on the user's path
        return sensor_database(models, sensor="laser", seed=seed, laser=laser_config, laser_views=laser_views,
                               laser_cut_views=laser_cut_views)
    if "laser" in sensor:  # kinect+laser: the laser views as sensor_database renders them
        v, classes = sensor_view_clouds(models, sensor="laser", seed=seed, laser=laser_config, laser_views=laser_views,
                                        laser_cut_views=laser_cut_views)
        views += v
    model_views, _ = models_view_clouds(models, seed=seed, config=POSE_MODEL_KINECT, tied_rests=True)
    return with_resting_up(build_database(views, classes, seed=seed, model_views=model_views), models)


def occluded(mission, fraction: float, seed: int):
    """The mission with every object in every scan occluded by ``fraction`` (:func:`occlude_objects`)."""
    if fraction == 0:
        return mission
    clouds = {r.scan_id: occlude_objects(mission.load_scan(r.scan_id), fraction,
                                         seed=np.random.default_rng([seed, r.scan_id])) for r in mission.scans}
    return dataclasses.replace(mission, scan_clouds=clouds)


def background_kind(mission, object_index: int) -> str:
    """floor (tank, outliers), rock or offcut: ``build_world`` places clutter k as a rock for even k, else an offcut."""
    if object_index < 0:
        return "floor"
    return "rock" if int(mission.objects[object_index].name.rsplit("_", 1)[1]) % 2 == 0 else "offcut"


def run_case(db, models: dict, *, seed: int, scanner: ScannerConfig, descriptor: str = "esf+vfh",
             classifier: str = "chi2", loops: int = 1, missions: list | None = None, occlusion: float = 0.0,
             scan_ms: list | None = None, upright: bool = False, **pipeline) -> tuple[list[dict], list]:
    """Simulate (or reuse) one cluttered mission per subset and score every cluster of every scan (``scan_ms``:
    appended the recognition time of every scan, ``RecognitionResult.timings_ms["total"]``)."""
    records, sims = [], []
    recognizer = ScanRecognizer(db, PipelineConfig(descriptor=descriptor, classifier=classifier, **pipeline), seed=seed)
    recognizer.warm_up()
    for k, group in enumerate(subsets(list(models))):
        if missions is not None:
            mission = missions[k]
        else:
            cfg = SimulatorConfig().replace(world=WorldConfig(clutter=True), trajectory=TrajectoryConfig(loops=loops),
                                            scanner=scanner)
            mission = simulate_dataset(cfg, seed=seed + 1000 * k, objects={lab: models[lab] for lab in group})
        sims.append(mission)

        def score(rec, cloud, res, m=mission, k=k):
            if scan_ms is not None:
                scan_ms.append(res.timings_ms["total"])
            for row in score_scan(m, rec, cloud, res, db):
                row["mission"] = k
                if row["truth_label"] == BG:
                    row["background_kind"] = background_kind(m, row["truth_object"])
                records.append(row)

        detect_dataset(occluded(mission, occlusion, seed), recognizer, seed=seed, on_scan=score,
                       up_from_attitude=upright)
    return records, sims


def summarise(records: list[dict], labels: list[str]) -> dict:
    pred = [r["label"] if r["detected"] else UNK for r in records]
    truth = [r["truth_label"] for r in records]
    conf = Counter(zip(truth, pred))
    per = {}
    for lab in labels:
        tp = conf[(lab, lab)]
        n_pred = sum(v for (t, p), v in conf.items() if p == lab)
        n_true = sum(v for (t, p), v in conf.items() if t == lab)
        per[lab] = {"tp": tp, "pred": n_pred, "true": n_true,
                    "precision": tp / n_pred if n_pred else math.nan, "recall": tp / n_true if n_true else math.nan}
    dets = sum(p != UNK for p in pred)
    tp_all = sum(t == p for t, p in zip(truth, pred) if p != UNK)
    n_obj = sum(t != BG for t in truth)
    n_bg = sum(t == BG for t in truth)
    fa = sum(t == BG and p != UNK for t, p in zip(truth, pred))
    reasons = Counter(r["reason"].split(" 0")[0].split(" 1")[0] for r in records if r["truth_label"] != BG and not r["detected"])
    inner = [r for r in records if r["truth_label"] != BG and not r["touches_border"]]
    nearest_ok = sum(r["nearest_label"] == r["truth_label"] for r in inner)
    nearest_by_class = {lab: (sum(r["nearest_label"] == lab for r in inner if r["truth_label"] == lab),
                              sum(r["truth_label"] == lab for r in inner)) for lab in labels}
    obj_dets = sum(t != BG and p != UNK for t, p in zip(truth, pred))
    whole = [(t, p) for r, t, p in zip(records, truth, pred) if t != BG and not r["touches_border"]]
    objects, found = set(), set()  # per object: found when one of its clusters is recognised as its class
    for r, t, p in zip(records, truth, pred):
        if t != BG:
            objects.add((r["mission"], r["truth_object"]))
            if p == t:
                found.add((r["mission"], r["truth_object"]))
    fa_kind = Counter(r["background_kind"] for r, p in zip(records, pred) if r["truth_label"] == BG and p != UNK)
    n_kind = Counter(r["background_kind"] for r in records if r["truth_label"] == BG)
    return {"recall_whole": sum(t == p for t, p in whole) / len(whole) if whole else math.nan, "n_whole": len(whole),
            "objects": len(objects), "objects_found": len(found), "fa_by_kind": {k: (fa_kind[k], n_kind[k]) for k in n_kind},
            "object_precision": tp_all / obj_dets if obj_dets else math.nan, "miss_reasons": dict(reasons), "nearest_acc": nearest_ok / len(inner) if inner else math.nan,
            "nearest_by_class": nearest_by_class,
            "n_inner": len(inner), "precision": tp_all / dets if dets else math.nan, "recall": tp_all / n_obj if n_obj else math.nan,
            "bg_clusters": n_bg, "bg_false_accepts": fa, "bg_fa_rate": fa / n_bg if n_bg else math.nan,
            "n_obj_clusters": n_obj, "n_detections": dets, "per_class": per, "confusion": conf}


def pct(x: float) -> str:
    return "  n/a" if not np.isfinite(x) else f"{100 * x:5.1f}"


def print_main(s: dict, labels: list[str]) -> None:
    print(f"\nprecision {pct(s['precision'])} %  recall {pct(s['recall'])} %  ({s['n_detections']} detections, "
          f"{s['n_obj_clusters']} object clusters)  background false accepts {s['bg_false_accepts']}/{s['bg_clusters']}"
          f" = {pct(s['bg_fa_rate'])} %; precision on object clusters only {pct(s['object_precision'])} %")
    print(f"object clusters not touching the scan border: {s['n_inner']}, nearest view of the right class: "
          f"{pct(s['nearest_acc'])} %; missed object clusters by reason: {s['miss_reasons']}")
    print("nearest view of the right class, per class (uncut clusters): "
          + ", ".join(f"{lab} {a}/{n}" for lab, (a, n) in s["nearest_by_class"].items()))
    print(f"recall over object clusters not cut by the scan border {pct(s['recall_whole'])} % ({s['n_whole']}); objects "
          f"found in at least one scan {s['objects_found']}/{s['objects']}; background false accepts by kind "
          + ", ".join(f"{k} {a}/{n}" for k, (a, n) in sorted(s["fa_by_kind"].items())))
    print("\n| class | object clusters | detections | correct | precision % | recall % |\n|---|---|---|---|---|---|")
    for lab in labels:
        p = s["per_class"][lab]
        print(f"| {lab} | {p['true']} | {p['pred']} | {p['tp']} | {pct(p['precision'])} | {pct(p['recall'])} |")
    cols = labels + [UNK]
    short = {"flange": "fl", "blind_flange": "bfl", "elbow_45": "e45", "elbow_90": "e90", "equal_tee": "tee",
             "cross": "x", "reducing_tee": "rtee", "reducing_socket": "rsock", "gate_valve": "gate",
             "ball_valve": "ball", "butterfly_valve": "bfly", UNK: "unk"}
    abbrev = {c: short.get(c, c[:6]) for c in cols}
    print("\nConfusion (rows: truth, columns: predicted)\n")
    print("| truth \\ pred | " + " | ".join(abbrev[c] for c in cols) + " |\n|---" * 1 + "|---" * len(cols) + "|")
    for t in labels + [BG]:
        print(f"| {t} | " + " | ".join(str(s["confusion"].get((t, c), 0) or ".") for c in cols) + " |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one-elevation database (75 deg, 8 views) and fewer sweep points")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plot", default=None, help="save the sweep plot (PNG)")
    ap.add_argument("--elevations", default="45,60,75,85", help="database survey elevations (deg), comma list")
    ap.add_argument("--n-views", type=int, default=12, help="database views per class and elevation")
    ap.add_argument("--objects", default="catalogue", choices=("catalogue", "builtin"))
    ap.add_argument("--db-sensor", default="kinect", choices=("kinect", "laser", "kinect+laser"),
                    help="recognition views of the database: Kinect-like survey views (default), views rendered by "
                         "the missions' laser scanner from route-like viewpoints, or both")
    ap.add_argument("--laser-views", type=int, default=LASER_VIEWS,
                    help="with --db-sensor *laser: whole views per class")
    ap.add_argument("--laser-cut-views", type=int, default=LASER_CUT_VIEWS,
                    help="with --db-sensor *laser: extra views per class that the swath's border may cut")
    ap.add_argument("--descriptor", default="esf+vfh", choices=("esf", "vfh", "esf+vfh"),
                    help="descriptor of the main tables and headlines (default esf+vfh, the pipeline's)")
    ap.add_argument("--rejection", default=None, choices=("global", "per_class"),
                    help="override the settings' rejection mode (PipelineConfig default global)")
    ap.add_argument("--reject-margin", type=float, default=None,
                    help="override the setting's reject_margin (PipelineConfig default 6)")
    ap.add_argument("--sweep", default="noise,density,occlusion,combo",
                    help="comma list of: noise, density, occlusion, combo, margin ('' = none)")
    ap.add_argument("--config", default="catalogue", choices=tuple(CONFIGS),
                    help="pipeline setting of the tables and sweeps (the others' headlines are printed too)")
    ap.add_argument("--compare", default="all",
                    help="comma list of the other settings whose headlines are printed on the same missions "
                         "('all', default; '' = none)")
    ap.add_argument("--upright", action="store_true",
                    help="pose the classes upright about each scan's up from the vehicle's attitude (the database "
                         "records each class's up from its resting pose; detect_dataset(up_from_attitude=True))")
    ap.add_argument("--records", default=None, metavar="FILE.jsonl",
                    help="write every scored cluster of the main setting (one JSON object per line)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.objects == "builtin":
        from semslam.simulation import builtin_objects

        models = builtin_objects()
    else:
        models = catalogue_objects()
    labels = list(models)
    if args.quick:
        args.elevations, args.n_views = "75", 8
    elevations = tuple(float(e) for e in args.elevations.split(","))
    db = build_db(models, args.seed, elevations, args.n_views, sensor=args.db_sensor, laser_views=args.laser_views,
                  laser_cut_views=args.laser_cut_views)
    laser_text = (f" + laser {args.laser_views} whole + {args.laser_cut_views} cut views per class"
                  if "laser" in args.db_sensor else "")
    kinect_text = (f"{args.n_views} Kinect views x elevations {elevations} deg" if "kinect" in args.db_sensor
                   else "no Kinect views")
    print(f"database ({args.db_sensor}): {len(labels)} classes x {kinect_text}{laser_text} = {db.n_views} views, "
          f"built in {time.perf_counter() - t0:.0f} s; missions: " + " / ".join(",".join(g) for g in subsets(labels)))
    base = ScannerConfig()
    kw = dict(CONFIGS[args.config])
    override = {k: v for k, v in (("reject_margin", args.reject_margin), ("rejection", args.rejection),
                                  ("upright", args.upright or None)) if v is not None}
    kw.update(override)
    if override:
        print(f"overrides (all settings): {override}")
    t1 = time.perf_counter()
    main_ms: list = []
    records, missions = run_case(db, models, seed=args.seed, scanner=base, scan_ms=main_ms,
                                 descriptor=args.descriptor, **kw)
    s = summarise(records, labels)
    n_scans = sum(len(m.scans) for m in missions)
    print(f"default scanner ({base.n_lines} x {base.points_per_line}, noise {base.noise_floor_m * 1e3:.1f} mm + "
          f"{base.noise_range2_per_m * 1e3:.1f} mm/m^2 r^2), {args.descriptor} chi2, pipeline setting {args.config!r}: "
          f"{n_scans} scans in {time.perf_counter() - t1:.0f} s")
    compare = set(CONFIGS) if args.compare == "all" else {c for c in args.compare.split(",") if c}
    unknown = compare - set(CONFIGS)
    if unknown:
        ap.error(f"--compare: unknown setting(s) {sorted(unknown)}; choose from {sorted(CONFIGS)}")
    if args.records:
        import json

        with open(args.records, "w") as fh:
            for r in records:
                fh.write(json.dumps({k: v for k, v in r.items() if isinstance(v, (str, int, float, bool, type(None)))})
                         + "\n")
    for name, other in CONFIGS.items():  # headline of the other settings, same missions
        if name != args.config and name in compare:
            other_ms: list = []
            other = {**other, **override}
            o = summarise(run_case(db, models, seed=args.seed, scanner=base, missions=missions, scan_ms=other_ms,
                                   descriptor=args.descriptor, **other)[0], labels)
            print(f"setting {name!r}: precision {pct(o['precision'])} %  recall {pct(o['recall'])} % "
                  f"(not cut by the border {pct(o['recall_whole'])} %; objects {o['objects_found']}/{o['objects']})  "
                  f"background false accepts {o['bg_false_accepts']}/{o['bg_clusters']} = {pct(o['bg_fa_rate'])} %; "
                  f"recognition {np.mean(other_ms):.0f} ms per scan (median {np.median(other_ms):.0f}); per class "
                  + ", ".join(f"{lab} {o['per_class'][lab]['tp']}/{o['per_class'][lab]['true']}"
                              for lab in ("gate_valve", "ball_valve", "butterfly_valve") if lab in o["per_class"]))
    print(f"setting {args.config!r}: recognition {np.mean(main_ms):.0f} ms per scan (median {np.median(main_ms):.0f}); "
          "per class " + ", ".join(f"{lab} {s['per_class'][lab]['tp']}/{s['per_class'][lab]['true']}"
                                   for lab in ("gate_valve", "ball_valve", "butterfly_valve") if lab in s["per_class"]))
    print(f"setting {args.config!r} (tables below):")
    print_main(s, labels)
    sweeps = {k for k in args.sweep.split(",") if k}
    rows = []
    if "combo" in sweeps:
        print("\n| descriptor | classifier | precision % | recall % | background FA % |\n|---|---|---|---|---|")
        for d in ("esf", "vfh", "esf+vfh"):
            for c in ("chi2", "svm"):
                if (d, c) == ("esf+vfh", "chi2"):
                    r = s
                else:
                    try:
                        r = summarise(run_case(db, models, seed=args.seed, scanner=base, descriptor=d, classifier=c,
                                               missions=missions, **kw)[0], labels)
                    except Exception as exc:  # a combination the pipeline refuses: say so
                        print(f"| {d} | {c} | failed: {exc} | | |")
                        continue
                print(f"| {d} | {c} | {pct(r['precision'])} | {pct(r['recall'])} | {pct(r['bg_fa_rate'])} |", flush=True)
        r = summarise(run_case(db, models, seed=args.seed, scanner=base, missions=missions,
                               **{**kw, "rejection": "per_class"})[0], labels)
        print(f"| esf+vfh | chi2, per-class rejection | {pct(r['precision'])} | {pct(r['recall'])} | {pct(r['bg_fa_rate'])} |")
    if "margin" in sweeps:  # a tighter rejection threshold, and counting only detections with a reliable pose
        print("\n| reject_margin | detections counted | precision % | recall % | background FA % |\n|---|---|---|---|---|")
        for margin in (6.0, 4.0, 3.0):
            recs = records if margin == kw.get("reject_margin", 6.0) else run_case(
                db, models, seed=args.seed, scanner=base, missions=missions, **{**kw, "reject_margin": margin})[0]
            rel = [dict(r, detected=bool(r["detected"] and r.get("reliable"))) for r in recs]
            rel = [r if r["detected"] else dict(r, label=UNK) for r in rel]
            for name, rr in (("all", summarise(recs, labels)), ("reliable pose only", summarise(rel, labels))):
                print(f"| {margin:g} | {name} | {pct(rr['precision'])} | {pct(rr['recall'])} | {pct(rr['bg_fa_rate'])} |",
                      flush=True)
    if "noise" in sweeps:
        rows.append(("noise", "default", s))
        for mm in ((1, 5) if args.quick else (1, 3, 5)):
            sc = ScannerConfig(**{**base.__dict__, "noise_floor_m": mm * 1e-3, "noise_range2_per_m": 0.0})
            rows.append(("noise", f"{mm} mm", summarise(run_case(db, models, seed=args.seed, scanner=sc, **kw)[0], labels)))
    if "density" in sweeps:
        rows.append(("density", f"{base.n_lines} x {base.points_per_line} (default)", s))
        for n in ((80,) if args.quick else (240, 160, 80)):
            sc = ScannerConfig(**{**base.__dict__, "n_lines": n, "points_per_line": n})
            rows.append(("density", f"{n} x {n}", summarise(run_case(db, models, seed=args.seed, scanner=sc, **kw)[0],
                                                            labels)))
    if "occlusion" in sweeps:  # the same missions, a share of every object's points hidden from one side
        rows.append(("occlusion", "0 %", s))
        for frac in ((0.4,) if args.quick else (0.2, 0.4, 0.6)):
            r = summarise(run_case(db, models, seed=args.seed, scanner=base, missions=missions, occlusion=frac, **kw)[0],
                          labels)
            rows.append(("occlusion", f"{100 * frac:.0f} %", r))
    if rows:
        print("\n| sweep | setting | precision % | recall % | recall, not cut by border % | objects found | "
              "background FA % | detections | object clusters |\n|---|---|---|---|---|---|---|---|---|")
        for kind, setting, r in rows:
            print(f"| {kind} | {setting} | {pct(r['precision'])} | {pct(r['recall'])} | {pct(r['recall_whole'])} | "
                  f"{r['objects_found']}/{r['objects']} | {pct(r['bg_fa_rate'])} | {r['n_detections']} | "
                  f"{r['n_obj_clusters']} |")
    if args.plot and rows:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        kinds = sorted({k for k, _, _ in rows})
        fig, axes = plt.subplots(1, len(kinds), figsize=(5 * len(kinds), 3.6), squeeze=False)
        for ax, kind in zip(axes[0], kinds):
            sel = [(st, r) for k, st, r in rows if k == kind]
            x = np.arange(len(sel))
            for key, name in (("precision", "precision"), ("recall", "recall"), ("bg_fa_rate", "background FA")):
                ax.plot(x, [100 * r[key] for _, r in sel], "o-", label=name)
            ax.set_xticks(x, [st for st, _ in sel])
            ax.set_xlabel({"noise": "range noise sigma (default: 0.5 mm + 1 mm/m^2 r^2)",
                           "occlusion": "share of every object's points hidden from one side"}.get(
                kind, "scanner lines x points per line"))
            ax.set_ylabel("%")
            ax.set_ylim(0, 100)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(f"{len(labels)}-class catalogue, cluttered scans (esf+vfh chi2, setting {args.config!r})")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"\nplot: {args.plot}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
