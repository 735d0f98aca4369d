"""Real RealSense valve views (issue #16): rejection that generalises and relative pose at known yaw steps.

    .venv/bin/python benchmarks/real_valves.py [--data ../shared/data/real/valves] [--baseline]

Views: ``CLASS/pitchPPP_yawYYY_30cm/N/RANSAC.pcd`` (the authors' segmentation of the valve), cleaned by
:func:`semslam.segmentation.clean.clean_view` (their last 405 points are drawn axes and a normal, not
geometry). Two tables:

1. **Leave one setting out.** For each rig setting, a database is built from the other settings' views
   (fused per class into one object frame with the gravity-aligned registration, camera up = -y) and the
   held-out setting's views of both classes are recognised (ESF and ESF+VFH, chi-square nearest view,
   global rejection). ``plain`` calibrates the rejection threshold by ordinary leave-one-out, ``viewpoint`` leaves
   one viewpoint out (:mod:`semslam.recognition.rejection`). Goal: >= 90 % accepted with the right class.
2. **Relative rotation of view pairs** (every ordered pair of views of one class): ``semslam register --up
   0,-1,0`` (:func:`semslam.registration.align_upright`); the error is the angle between the estimate and
   a rotation of the nominal yaw step about the camera's vertical axis; ``reliable`` is the registration's
   own verdict. Goal: >= 85 % within 10 degrees, no reliable answer off by more than 30 degrees.
   ``--baseline`` adds the 6-DoF feature registration (FPFH + prerejective RANSAC + ICP) for comparison.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from semslam.cloud import PointCloud  # noqa: E402
from semslam.io import read_point_cloud  # noqa: E402
from semslam.pipeline.fuse import fuse_class_views  # noqa: E402
from semslam.recognition import Recognizer  # noqa: E402
from semslam.recognition.database import build_database, folder_classes  # noqa: E402
from semslam.registration import RegisterConfig, align_upright, register  # noqa: E402
from semslam.segmentation.clean import clean_view  # noqa: E402

UP_CAMERA = (0.0, -1.0, 0.0)


def load_views(data: Path) -> list[dict]:
    out = []
    nested = sorted(data.glob("*/*/*/RANSAC.pcd"))  # the shared layout CLASS/SETTING/N/RANSAC.pcd
    for f in nested or sorted(data.glob("*/*.pcd")):  # or a flat CLASS/SETTING_N.pcd (tests/data/real_valves)
        parts = f.relative_to(data).parts
        cls = parts[0]
        setting, frame = (parts[1], parts[2]) if nested else tuple(f.stem.rsplit("_", 1))
        cloud = clean_view(read_point_cloud(f), name=str(f))[0]
        yaw = int(re.search(r"yaw(-?\d+)", setting).group(1))
        out.append({"cls": cls, "setting": setting, "frame": frame, "yaw": yaw, "cloud": cloud})
    return out


def rot_about_camera_vertical(step_deg: float) -> np.ndarray:
    """Rotation of the object seen by a level camera (y down) when the rig turns by ``step_deg``: about +y."""
    a = np.radians(step_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def fused_database(train: list[dict], up=UP_CAMERA):
    fused = []
    for cls in sorted({v["cls"] for v in train}):
        items = [(f'{v["setting"]}_{v["frame"]}', v["cloud"]) for v in train if v["cls"] == cls]
        out, _ = fuse_class_views(cls, items, up_sensor=up)
        fused += [(cls, vid, c) for vid, c in out]
    return build_database(fused, folder_classes(fused, {}, Path("classes.json")), voxel_leaf_m="auto",
                          normal_radius_m="auto", seed=0)


def leave_one_setting_out(views: list[dict]) -> list[dict]:
    rows = []
    for setting in sorted({v["setting"] for v in views}):
        train = [v for v in views if v["setting"] != setting]
        test = [v for v in views if v["setting"] == setting]
        t0 = time.perf_counter()
        db = fused_database(train)
        t_db = time.perf_counter() - t0
        for desc in ("esf", "esf+vfh"):
            for mode, directions in (("plain", False), ("viewpoint", True)):
                rec = Recognizer(db, descriptor=desc)
                if not directions:
                    rec.classifier.fit(db.features(desc), db.labels)
                ok = 0
                t1 = time.perf_counter()
                for v in test:
                    m = rec.match(v["cloud"], seed=0)
                    ok += m.label == v["cls"]
                rows.append({"setting": setting, "desc": desc, "mode": mode, "n": len(test), "accepted_correct": ok,
                             "threshold": rec.thresholds.global_threshold,
                             "ms_per_view": 1e3 * (time.perf_counter() - t1) / len(test), "db_s": t_db})
    return rows


def pairs(views: list[dict], baseline: bool) -> list[dict]:
    rows = []
    for a in views:
        for b in views:
            if a is b or a["cls"] != b["cls"]:
                continue
            step = b["yaw"] - a["yaw"]
            R_true = rot_about_camera_vertical(step)
            t0 = time.perf_counter()
            res = align_upright(a["cloud"], b["cloud"], up_source=UP_CAMERA, up_target=UP_CAMERA)
            dt = time.perf_counter() - t0
            R = np.asarray(res.T_target_source.matrix)[:3, :3]
            row = {"cls": a["cls"], "a": f'{a["yaw"]}/{a["frame"]}', "b": f'{b["yaw"]}/{b["frame"]}', "step": step,
                   "err_deg": angle_deg(R.T @ R_true), "reliable": res.extras["reliable"],
                   "ambiguous": res.extras["ambiguous"], "yaw_sigma_deg": res.extras["yaw_sigma_deg"], "s": dt}
            if baseline:
                base = register(a["cloud"], b["cloud"], RegisterConfig(time_budget_s=10), seed=0)
                row["baseline_err_deg"] = angle_deg(np.asarray(base.T_target_source.matrix)[:3, :3].T @ R_true)
                row["baseline_reliable"] = bool(base.extras.get("reliable", False))
            rows.append(row)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "real" / "valves")
    ap.add_argument("--baseline", action="store_true", help="also run the 6-DoF feature registration")
    args = ap.parse_args()
    views = load_views(args.data)
    print(f"{len(views)} views from {args.data}\n")
    print("## Leave one setting out (fused databases of the other settings)\n")
    print("| held-out setting | descriptor | calibration | views | accepted, right class | threshold | ms/view | db build s |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    loso = leave_one_setting_out(views)
    for r in loso:
        print(f"| {r['setting']} | {r['desc']} | {r['mode']} | {r['n']} | {r['accepted_correct']} | {r['threshold']:.3f} | "
              f"{r['ms_per_view']:.0f} | {r['db_s']:.1f} |")
    print()
    for desc in ("esf", "esf+vfh"):
        for mode in ("plain", "viewpoint"):
            rs = [r for r in loso if r["mode"] == mode and r["desc"] == desc]
            n_ok, n = sum(r["accepted_correct"] for r in rs), sum(r["n"] for r in rs)
            print(f"{desc}, {mode} calibration: {n_ok}/{n} ({100 * n_ok / n:.0f} %) accepted with the right class")
    print("\n## Relative rotation of view pairs (upright registration, up = -y)\n")
    rows = pairs(views, args.baseline)
    groups: dict = {}
    for r in rows:
        ya, yb = int(r["a"].split("/")[0]), int(r["b"].split("/")[0])
        groups.setdefault((r["cls"], min(ya, yb), max(ya, yb)), []).append(r)
    head = "| class | settings | nominal step | pairs | within 10 deg | median error deg | reliable | reliable > 30 deg |"
    head += " feature reg. within 10 deg | feature reg. reliable | reliable > 30 deg |" if args.baseline else ""
    print(head)
    print("|---|---|---:|---:|---:|---:|---:|---:|" + ("---:|---:|---:|" if args.baseline else ""))
    for (cls, ya, yb), rs in sorted(groups.items()):
        e = np.array([r["err_deg"] for r in rs])
        line = (f"| {cls} | yaw {ya} / {yb} | {yb - ya} | {len(rs)} | {int((e <= 10).sum())} | {np.median(e):.1f} | "
                f"{sum(r['reliable'] for r in rs)} | {sum(r['reliable'] and r['err_deg'] > 30 for r in rs)} |")
        if args.baseline:
            line += (f" {sum(r['baseline_err_deg'] <= 10 for r in rs)} | {sum(r['baseline_reliable'] for r in rs)} |"
                     f" {sum(r['baseline_reliable'] and r['baseline_err_deg'] > 30 for r in rs)} |")
        print(line)
    e = np.array([r["err_deg"] for r in rows])
    print(f"\nall pairs: {int((e <= 10).sum())}/{len(e)} within 10 deg ({100 * np.mean(e <= 10):.0f} %), "
          f"{sum(r['reliable'] and r['err_deg'] > 30 for r in rows)} reliable answers off by more than 30 deg, "
          f"{np.mean([r['s'] for r in rows]) * 1e3:.0f} ms per pair")
    if args.baseline:
        b = np.array([r["baseline_err_deg"] for r in rows])
        nb = sum(r["baseline_reliable"] and r["baseline_err_deg"] > 30 for r in rows)
        print(f"feature registration: {int((b <= 10).sum())}/{len(b)} within 10 deg ({100 * np.mean(b <= 10):.0f} %), "
              f"{sum(r['baseline_reliable'] for r in rows)} flagged reliable, {nb} of them off by more than 30 deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
