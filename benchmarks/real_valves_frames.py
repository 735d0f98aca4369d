"""Recognition and pose of the valves in the full RealSense frames (issue #16, item 4).

Runs the pipeline of ``semslam recognize FRAME --db DB --max-range 0.5 --voxel auto --cluster-tolerance auto
--max-planes 0`` on every ``valves/CLASS/SETTING/N/Captured_Frame.pcd`` of the shared real data and compares
with the authors' segmentation of the valve in that frame (``RANSAC.pcd`` without its last 405 points, which
are drawn axis and normal lines, not geometry).

Per frame: the cluster holding the valve (the one containing most of the RANSAC points, each within 5 mm of
a cluster point), its label (right class or not), chi-square distance, centroid error against the RANSAC
centroid (mm), the share of RANSAC points it covers, the pose (xyz mm, roll pitch yaw deg), reliable flag,
the other detections in the frame (clutter accepted), the time of the frame. "found" = the valve's cluster
is detected with the right class and its centroid is within 20 mm of the RANSAC centroid. Per setting: the
rotation angle (deg) and the translation difference (mm) between the poses of its two frames.

    .venv/bin/python benchmarks/real_valves_frames.py --db /tmp/v16/clean_real.npz
    .venv/bin/python benchmarks/real_valves_frames.py --db loso --border flag --pose-model view

``--db loso`` (leave one setting out): for every yaw setting, a database is built from the authors' valve
segmentations of the OTHER settings (both classes, both frames; each view centred on its centroid, so that a
pose's translation is where the valve's face is) and run on the frames of the held-out setting.
    .venv/bin/python benchmarks/real_valves_frames.py --db DB --border flag --pose-model view --json out.json

``--attached`` turns on ``PipelineConfig.attached`` (objects attached to structure: the ball valve's lever is one
cluster with the rig's pipe); the valve's centroid error is then that of the piece found inside the cluster, and
the label column says "(inside the cluster)". ``--attached-far`` also searches the clusters rejected by their
descriptor distance.
    .venv/bin/python benchmarks/real_valves_frames.py --db loso-fused --up 0,-1,0 --reject-margin 1 --attached

Other settings of the rig (camera pitch 30/45, other yaw steps and distances; the original dataset's
``CLASS/pitchPPP/pitchPPPyawYYY/DDcm/N/`` layout is read too): ``--up auto`` gives each setting the rig's vertical
as its pitched camera sees it (``real_valves.up_camera``, sign measured from the backboard), for the fused
database (each view about its own up) and for the pose search of its frames.
    .venv/bin/python benchmarks/real_valves_frames.py --db loso-fused --up auto --reject-margin 1 --attached
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: The last points of every RANSAC.pcd are drawn lines (axes, normal), not geometry.
DRAWN_TAIL = 405
FOUND_CENTROID_MM = 20.0
COVER_RADIUS_M = 0.005


def frame_key(data: Path, path: Path) -> tuple[str, str, str]:
    """``(class, setting, frame)`` of a file ``data/CLASS/<setting path>/N/NAME``: the shared layout
    (``pitch000_yaw030_30cm``) or the original dataset's (``pitch030/pitch030yaw-015/30cm``)."""
    parts = path.relative_to(data).parts
    return parts[0], "/".join(parts[1:-2]), parts[-2]


def setting_ups(data: Path) -> dict:
    """``{setting: up in the camera frame}`` for ``--up auto``: the rig's vertical as a camera pitched by the
    setting's pitch sees it (:func:`real_valves.up_camera`, its sign measured by :func:`real_valves.pitch_signs`,
    the majority over the classes)."""
    sys.path.insert(0, str(Path(__file__).parent))
    import real_valves as rv

    views = []
    for path in sorted(data.glob("*/**/RANSAC.pcd")):
        cls, setting, frame = frame_key(data, path)
        pitch, yaw, _ = rv.parse_setting(setting)
        views.append({"cls": cls, "setting": setting, "pitch": pitch, "yaw": yaw, "path": path})
    signs = rv.pitch_signs(views)
    out = {}
    for v in views:
        votes = [s for (c, p), (s, _) in signs.items() if p == v["pitch"]]
        out[v["setting"]] = tuple(rv.up_camera(v["pitch"], 1 if sum(votes) >= 0 else -1))
    return out


def shared_valves() -> Path:
    shared = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared"))
    return shared / "data" / "real" / "valves"


def frame_config(args: argparse.Namespace, up=None):
    from semslam.pipeline import PipelineConfig

    seg = {"drop_origin": True, "max_range_m": args.max_range, "voxel_leaf_m": "auto",
           "cluster_tolerance_m": "auto", "max_planes": args.max_planes}
    table = {"segmentation": seg, "border": args.border, "pose_model": args.pose_model}
    if getattr(args, "reject_margin", None) is not None:
        table["reject_margin"] = args.reject_margin
    if getattr(args, "descriptor", None):
        table["descriptor"] = args.descriptor
    if up is not None:
        table["up_scanner"] = [float(v) for v in up]
    if getattr(args, "attached", False):
        table["attached"] = {"include_far": bool(getattr(args, "attached_far", False))}
    return PipelineConfig.from_dict(table)


def valve_cluster(result, ransac_xyz_m: np.ndarray):
    """(outcome, cluster points, coverage) of the cluster holding most RANSAC points, or (None, None, 0)."""
    from scipy.spatial import cKDTree

    best = (None, None, 0.0)
    for o in result.clusters:
        pts = result.segmentation.clusters[o.cluster_index].points_xyz_m
        cover = float((cKDTree(pts).query(ransac_xyz_m)[0] < COVER_RADIUS_M).mean())
        if cover > best[2]:
            best = (o, pts, cover)
    return best


def run_frame(recognizer, path: Path, seed: int, data: Path) -> dict:
    from semslam.io import read_point_cloud

    truth_class, setting, frame = frame_key(data, path)
    scan = read_point_cloud(path)
    ransac = read_point_cloud(path.with_name("RANSAC.pcd")).points_xyz_m[:-DRAWN_TAIL]
    centre = ransac.mean(axis=0)
    t0 = time.perf_counter()
    result = recognizer.recognize(scan, seed=seed)
    dt_ms = (time.perf_counter() - t0) * 1e3
    outcome, pts, cover = valve_cluster(result, ransac)
    row = {"class": truth_class, "setting": setting, "frame": frame, "n_points": scan.n_points,
           "time_ms": dt_ms, "spacing_mm": 1e3 * (result.segmentation.resolved.get("spacing_m") or float("nan")),
           "cover": cover, "label": "-", "detected": False, "right_class": False, "distance": float("nan"),
           "centroid_err_mm": float("nan"), "reason": "no cluster holds the valve", "pose": None,
           "reliable": False, "fitness": float("nan"), "pose_t_err_mm": float("nan")}
    if outcome is not None:
        det = outcome.detection
        att = (det.extras.get("attached") if det is not None else None) or {}
        c_found = np.asarray(att["piece_centroid_m"]) if att else pts.mean(0)  # the object found inside the cluster
        row.update(label=outcome.label, detected=det is not None, right_class=outcome.label == truth_class,
                   distance=float(outcome.distance), centroid_err_mm=1e3 * float(np.linalg.norm(c_found - centre)),
                   attached=bool(att), piece_points=att.get("piece_points"),
                   reason=outcome.reason, touches_border=outcome.touches_border, cluster_points=outcome.n_points)
        if det is not None:
            T = det.T_sensor_object
            row.update(pose=T.matrix.tolist(), reliable=bool(det.reliable),
                       fitness=float("nan") if det.fitness is None else float(det.fitness),
                       pose_t_err_mm=1e3 * float(np.linalg.norm(T.translation_m - centre)))
    others = [d for d in result.detections if outcome is None or d is not outcome.detection]
    row["other_detections"] = len(others)
    row["found"] = bool(row["detected"] and row["right_class"] and row["centroid_err_mm"] <= FOUND_CENTROID_MM)
    return row


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def consistency(rows: list[dict]) -> list[dict]:
    """Per (class, setting): rotation angle and translation difference between the poses of its frames."""
    out = []
    keys = sorted({(r["class"], r["setting"]) for r in rows})
    for cls, setting in keys:
        poses = [np.asarray(r["pose"]) for r in rows if (r["class"], r["setting"]) == (cls, setting)
                 and r["pose"] is not None and r["right_class"]]
        rec = {"class": cls, "setting": setting, "frames_with_pose": len(poses), "rot_deg": float("nan"),
               "dt_mm": float("nan")}
        if len(poses) >= 2:
            rec["rot_deg"] = rotation_angle_deg(poses[0][:3, :3], poses[1][:3, :3])
            rec["dt_mm"] = 1e3 * float(np.linalg.norm(poses[0][:3, 3] - poses[1][:3, 3]))
        out.append(rec)
    return out


def fmt_pose(pose) -> str:
    if pose is None:
        return "-"
    from semslam.geometry import RigidTransform

    xyz_rpy = RigidTransform(np.asarray(pose)).as_xyz_rpy()
    x, y, z = (1e3 * v for v in xyz_rpy[:3])
    r, p, w = np.degrees(xyz_rpy[3:])
    return f"[{x:.0f} {y:.0f} {z:.0f}] mm [{r:.0f} {p:.0f} {w:.0f}] deg"


def table(rows: list[dict], cons: list[dict]) -> str:
    lines = ["| class | setting | frame | found | label (valve cluster) | right class | chi2 | centroid err mm | "
             "RANSAC covered | pose-t vs RANSAC c. mm | pose xyz, rpy | reliable | other detections | ms |",
             "|---|---|---|---|---|---|---:|---:|---:|---:|---|---|---:|---:|"]
    for r in rows:
        lab = r["label"] + (" (inside the cluster)" if r.get("attached") else "") + ("" if r["detected"] else f" ({r['reason']})")
        lines.append(f"| {r['class']} | {r['setting']} | {r['frame']} | {'yes' if r['found'] else 'no'} | {lab} | "
                     f"{'yes' if r['right_class'] else 'no'} | {r['distance']:.3f} | {r['centroid_err_mm']:.0f} | "
                     f"{100 * r['cover']:.0f} % | {r['pose_t_err_mm']:.0f} | {fmt_pose(r['pose'])} | "
                     f"{'yes' if r['reliable'] else 'no'} | {r['other_detections']} | {r['time_ms']:.0f} |")
    n = len(rows)
    found = sum(r["found"] for r in rows)
    right = sum(r["detected"] and r["right_class"] for r in rows)
    lines += ["", f"found (right class, centroid within {FOUND_CENTROID_MM:.0f} mm of RANSAC's): {found}/{n}; "
                  f"valve cluster detected with the right class: {right}/{n}; clutter detections: "
                  f"{sum(r['other_detections'] for r in rows)} in {n} frames; median time "
                  f"{np.median([r['time_ms'] for r in rows]):.0f} ms per frame", "",
              "| class | setting | frames with a pose | rotation between the two poses (deg) | translation difference (mm) |",
              "|---|---|---:|---:|---:|"]
    lines += [f"| {c['class']} | {c['setting']} | {c['frames_with_pose']} | {c['rot_deg']:.1f} | {c['dt_mm']:.1f} |"
              for c in cons]
    return "\n".join(lines)


def loso_database(data: Path, held_out: str):
    """A database of the RANSAC views of every setting but ``held_out`` (centred views, "auto" lengths)."""
    from semslam.cloud import PointCloud
    from semslam.io import read_point_cloud
    from semslam.recognition import build_database
    from semslam.symmetry import Symmetry

    views, extent = [], {}
    for path in sorted(data.glob("*/**/RANSAC.pcd")):
        cls, setting, frame = frame_key(data, path)
        if setting == held_out:
            continue
        pts = read_point_cloud(path).points_xyz_m[:-DRAWN_TAIL]
        centre = pts.mean(axis=0)
        views.append((cls, f"{setting}_{frame}", PointCloud(pts - centre, viewpoint_xyz_m=-centre)))
        lo, hi = extent.get(cls, (np.full(3, np.inf), np.full(3, -np.inf)))
        extent[cls] = (np.minimum(lo, (pts - centre).min(0)), np.maximum(hi, (pts - centre).max(0)))
    classes = {c: {"symmetry": Symmetry(), "size_xyz_m": hi - lo} for c, (lo, hi) in extent.items()}
    return build_database(views, classes, normal_radius_m="auto", voxel_leaf_m="auto", seed=0)


def loso_fused_database(data: Path, held_out: str, up):
    """The views of every setting but ``held_out``, cleaned and fused per class (``db build --fuse --up``;
    ``up``: one direction, None, or ``{setting: direction}`` -- each view about its own setting's up)."""
    from semslam.io import read_point_cloud
    from semslam.recognition.fuse import fuse_class_views
    from semslam.recognition.build import build_database, folder_classes
    from semslam.segmentation.clean import clean_view

    items: dict = {}
    ups: dict = {}
    for path in sorted(data.glob("*/**/RANSAC.pcd")):
        cls, setting, frame = frame_key(data, path)
        if setting != held_out:
            items.setdefault(cls, []).append((f"{setting}_{frame}", clean_view(read_point_cloud(path))[0]))
            ups[f"{setting}_{frame}"] = up.get(setting) if isinstance(up, dict) else up
    fused, fusion = [], {}
    for cls, views in sorted(items.items()):
        per_view = {vid: ups[vid] for vid, _ in views}
        out, rep = fuse_class_views(cls, views, up_sensor=per_view if isinstance(up, dict) else up)
        fused += [(cls, vid, c) for vid, c in out]
        fusion[cls] = {"poses": rep.poses, "doubtful": rep.doubtful, "up_object": rep.up_object}
    db = build_database(fused, folder_classes(fused, {}, Path("classes.json")), normal_radius_m="auto",
                        voxel_leaf_m="auto", seed=0)
    object.__setattr__(db, "params", {**db.params, "fusion": fusion})
    return db


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", required=True, help="view database (.npz) of the two valve classes, 'loso' or "
                                                "'loso-fused' (the other settings' views fused with --up)")
    ap.add_argument("--reject-margin", type=float, default=None,
                    help="PipelineConfig.reject_margin (default: the pipeline's, 6, set for laser clusters against "
                         "Kinect views; a database of the same camera's views needs less)")
    ap.add_argument("--descriptor", choices=("esf", "vfh", "esf+vfh"), default=None)
    ap.add_argument("--up", default=None, help="up in the camera frame, e.g. 0,-1,0: pose kept upright; 'auto': "
                                               "each setting's from its camera pitch (pitchPPP in its name)")
    ap.add_argument("--data", default=None, help="the valves folder (default: ../shared/data/real/valves)")
    ap.add_argument("--max-range", type=float, default=0.5)
    ap.add_argument("--max-planes", type=int, default=0)
    ap.add_argument("--border", choices=("reject", "flag", "keep"), default="reject")
    ap.add_argument("--pose-model", choices=("fused", "view"), default="fused")
    ap.add_argument("--attached", action="store_true",
                    help="PipelineConfig.attached: find objects inside clusters too big for them (semslam recognize "
                         "--attached)")
    ap.add_argument("--attached-far", action="store_true",
                    help="with --attached, also search clusters rejected by their descriptor distance")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="write the rows and the consistency table as JSON")
    args = ap.parse_args(argv)
    from semslam.pipeline import ScanRecognizer
    from semslam.recognition import load_database

    data = Path(args.data) if args.data else shared_valves()
    frames = sorted(data.glob("*/**/Captured_Frame.pcd"))
    if not frames:
        print(f"no valves/CLASS/SETTING/N/Captured_Frame.pcd under {data}", file=sys.stderr)
        return 1
    if args.up == "auto":
        up = setting_ups(data)
        print("up per setting: " + ", ".join(f"{k} {np.round(v, 3).tolist()}" for k, v in sorted(up.items())))
    else:
        up = None if args.up is None else tuple(float(v) for v in args.up.split(","))

    def config_for(setting: str):
        return frame_config(args, up[setting] if isinstance(up, dict) else up)

    settings = sorted({frame_key(data, f)[1] for f in frames})
    rows = []
    if args.db in ("loso", "loso-fused"):
        for setting in settings:
            db = loso_database(data, setting) if args.db == "loso" else loso_fused_database(data, setting, up)
            recognizer = ScanRecognizer(db, config_for(setting))
            recognizer.warm_up()
            rows += [run_frame(recognizer, f, args.seed, data) for f in frames if frame_key(data, f)[1] == setting]
    else:
        db = load_database(args.db)
        for setting in settings:
            recognizer = ScanRecognizer(db, config_for(setting))
            recognizer.warm_up()
            rows += [run_frame(recognizer, f, args.seed, data) for f in frames if frame_key(data, f)[1] == setting]
    rows.sort(key=lambda r: (r["class"], r["setting"], r["frame"]))
    cons = consistency(rows)
    print(f"db {args.db}; max range {args.max_range} m, voxel auto, cluster tolerance auto, max planes "
          f"{args.max_planes}, border {args.border}, pose model {args.pose_model}, up {args.up}, reject margin "
          f"{args.reject_margin}, attached {'far' if args.attached_far else args.attached}")
    print(table(rows, cons))
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "consistency": cons}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
