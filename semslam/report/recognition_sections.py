"""The report's recognition sections: the papers' Tables 1-2 (leave-one-out confusion matrices), Fig. 3 (a scan
with its recognised objects), recognition against ground truth, the detections, and the consensus
initialisation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import ReportError
from .html import Figure, Section, figure_to_png
from .summary import human_label
from .inputs import _load_csv_dicts, _load_json


def _section_tables(run_dir: Path, plt) -> Section | None:
    from .plots import plot_confusion_matrix

    ev_dir = run_dir / "evaluation"
    files = sorted(ev_dir.glob("loo_*.json")) if ev_dir.is_dir() else []
    if not files:
        return None
    sec = Section("Tables 1 and 2: leave-one-out recognition of the database views",
                  "Each view of the database is classified by a classifier trained on all the other views "
                  "(rows: actual class, columns: predicted). The papers report 93.75% (ESF) and 78.1% (VFH) with an "
                  "RBF SVM on their tank database.")
    cfg = _load_json(run_dir / "config.json") or {}
    if cfg.get("demo", {}).get("quick"):
        sec.text += ("\n\nQuick run: the SVM's (C, gamma) come from one grid search on all the views, then the "
                     "leave-one-out runs at that setting (not nested, so slightly optimistic); a full run nests the "
                     "grid search inside every fold.")
    order = {"esf_svm": 0, "vfh_svm": 1, "esf_chi2": 2, "vfh_chi2": 3}
    files.sort(key=lambda p: order.get(p.stem[4:], 9))
    rows = []
    for path in files:
        ev = _load_json(path)
        key = path.stem[4:]
        desc, clf = ev.get("descriptor", key), ev.get("classifier", "")
        labels = ev["labels"]
        conf = np.asarray(ev["confusion"])
        rows.append([desc.upper(), clf, f"{100 * ev['accuracy']:.2f}%",
                     ", ".join(f"{human_label(k)}: {100 * v:.0f}%" for k, v in ev["recall"].items())])
        if clf == "svm" or key.endswith("svm"):
            fig, ax = plt.subplots(figsize=(5.2, 4.4))
            plot_confusion_matrix(ax, conf, [human_label(x) for x in labels],
                                  title=f"{desc.upper()} + {clf.upper()}: {100 * ev['accuracy']:.2f}% correct")
            sec.figures.append(
                Figure(
                    f"table_{key}.png",
                    figure_to_png(fig),
                    f"Confusion matrix, {desc.upper()} features, {clf.upper()} classifier, leave-one-out.",
                )
            )
    sec.tables.append(("Leave-one-out accuracy", ["descriptor", "classifier", "accuracy", "per-class recall"], rows))
    return sec



def _section_fig3(run_dir: Path, plt) -> Section | None:
    path = run_dir / "fig3_scan.npz"
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        pts, cluster, labels, poses, scan_id = (
            z["points_xyz_m"],
            z["cluster"],
            z["labels"],
            z["T_scanner_object"],
            int(z["scan_id"]),
        )
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    bg = cluster < 0
    step = max(1, int(bg.sum() // 40000))
    ax.scatter(pts[bg][::step, 1], pts[bg][::step, 0], s=0.3, c="0.75", label="scene (plane and unclustered)")
    colours = plt.get_cmap("tab10")
    for k, lab in enumerate(labels):
        sel = cluster == k
        colour = "0.35" if lab == "unknown" else colours(k % 10)
        ax.scatter(pts[sel, 1], pts[sel, 0], s=1.5, color=colour, label=f"cluster {k}: {lab}")
        T = poses[k]
        if np.isfinite(T).all():
            o = T[:3, 3]
            for axis, c in zip(range(3), ("r", "g", "b")):
                tip = o + 0.06 * T[:3, axis]
                ax.plot([o[1], tip[1]], [o[0], tip[0]], color=c, lw=2)
            ax.annotate(lab, (o[1], o[0]), textcoords="offset points", xytext=(8, 8), fontsize=8,
                        bbox={"boxstyle": "round", "fc": "white", "alpha": 0.8})
    ax.set_xlabel("scanner y [m]")
    ax.set_ylabel("scanner x [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=7, markerscale=6, loc="upper right")
    detected = [k for k in range(len(labels)) if np.isfinite(poses[k]).all()]
    if detected:  # the objects are small in a metre-wide scan: a zoom on the first one
        k = detected[0]
        o = poses[k][:3, 3]
        sel = cluster == k
        inset = ax.inset_axes([0.02, 0.02, 0.36, 0.36])
        near = (np.abs(pts[:, 0] - o[0]) < 0.12) & (np.abs(pts[:, 1] - o[1]) < 0.12)
        inset.scatter(pts[near & ~sel, 1], pts[near & ~sel, 0], s=0.5, c="0.75")
        inset.scatter(pts[sel, 1], pts[sel, 0], s=2, color=colours(k % 10))
        for axis, c in zip(range(3), ("r", "g", "b")):
            tip = o + 0.06 * poses[k][:3, axis]
            inset.plot([o[1], tip[1]], [o[0], tip[0]], color=c, lw=2)
        inset.set_xlim(o[1] - 0.1, o[1] + 0.1)
        inset.set_ylim(o[0] - 0.1, o[0] + 0.1)
        inset.set_aspect("equal")
        inset.set_xticks([])
        inset.set_yticks([])
        inset.set_title(f"zoom: {labels[k]} (20 cm)", fontsize=7)
    ax.set_title(f"Fig. 3: scan {scan_id}, recognised objects and their poses (x red, y green, z blue; 6 cm axes)")
    return Section("Fig. 3: recognition in a laser scan",
                   "The scan of the mission with the most detections, seen along the scanner's optical axis. "
                   "Grey: the removed floor and unclustered points; colours: clusters with their recognised class; "
                   "axes: the estimated object frames (T_scanner_object).",
                   figures=[Figure("fig3_scan.png", figure_to_png(fig), f"Recognition in scan {scan_id}.")])



def _section_recognition(run_dir: Path, plt) -> Section | None:
    from .plots import plot_histogram

    rec = _load_json(run_dir / "recognition.json")
    if rec is None:
        return None
    s = rec["summary"]
    rows = [
        ["scans", s["n_scans"]],
        ["clusters", s["n_clusters"]],
        ["detections", s["n_detections"]],
        ["precision (detections with the right class)", _pct(s["precision"])],
        ["recall (object clusters recognised)", _pct(s["recall"])],
        ["background clusters accepted as an object", f"{s['background_false_accepts']} of {s['background_clusters']}"],
        ["detections with a reliable pose", s["n_reliable"]],
        ["median rotation error (deg, modulo symmetry)", s["pose_median_rotation_error_deg"]],
        ["median translation error (m)", s["pose_median_translation_error_m"]],
        ["pose success rate (< 10 deg and < 1 cm)", _pct(s["pose_success_rate"])],
        ["mean pose NEES (6 dof; ideal 6)", s["pose_mean_nees_6dof"]],
        ["median scan-to-detections latency (ms)", s["scan_latency_ms_median"]],
    ]
    sec = Section("Recognition and pose estimation against the ground truth (beyond the papers)",
                  "Every cluster of every scan compared with the simulator's ground truth: the object most of its "
                  "points lie on, and that object's true pose at the cluster's acquisition time.",
                  tables=[("Recognition over the mission", ["metric", "value"], rows)])
    per_class = s.get("per_class", {})
    if per_class:
        sec.tables.append(("Per class", ["class", "object clusters", "recognised"],
                           [[human_label(k), v["clusters"], v["recognised"]] for k, v in per_class.items()]))
    correct = [c for c in rec["clusters"] if c.get("detected") and c.get("label") == c.get("truth_label")]
    rot = [c["rotation_error_deg"] for c in correct if "rotation_error_deg" in c]
    trans = [1000 * c["translation_error_m"] for c in correct if "translation_error_m" in c]
    if rot:
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        plot_histogram(axes[0], np.asarray(rot), xlabel="rotation error [deg] (modulo symmetry)",
                       title="Pose rotation errors")
        plot_histogram(axes[1], np.asarray(trans), xlabel="translation error [mm]", title="Pose translation errors")
        sec.figures.append(Figure("pose_errors.png", figure_to_png(fig),
                                  "Distribution of the pose errors of correctly recognised objects."))
    return sec



def _section_detections(run_dir: Path) -> Section | None:
    """A table of the detections of ``*.jsonl`` files in the run (``semslam recognize --out RUN/x.jsonl``, or the
    demo's detections.jsonl), up to 200 rows."""
    from ..detection import Detection

    rows = []
    files = sorted(run_dir.glob("*.jsonl"))
    for path in files:
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ReportError(f"cannot read {path}: {exc}") from None
        for line in text.splitlines():
            if not line.strip():
                continue
            try:
                d = Detection.from_dict(json.loads(line))
            except (ValueError, TypeError) as exc:
                raise ReportError(f"{path} has a malformed detection line: {exc}") from None
            x, y, z, r, p, yw = d.T_sensor_object.as_xyz_rpy()
            sd = np.sqrt(np.clip(np.diag(d.covariance_6x6), 0, None))
            rows.append([path.name, d.scan_id, human_label(d.label), d.score, f"{x:.3f} {y:.3f} {z:.3f}",
                         f"{np.degrees(r):.1f} {np.degrees(p):.1f} {np.degrees(yw):.1f}",
                         f"{1000 * sd[:3].max():.1f}", d.fitness, 1000 * d.rmse_m if np.isfinite(d.rmse_m) else "",
                         "yes" if d.reliable else "no"])
    if not files:
        return None
    n = len(rows)
    return Section("Detections", f"{n} detection(s); poses T_sensor_object in the scanner frame (m, degrees)"
                   + ("; the first 200 are listed." if n > 200 else "."),
                   tables=[("Detections", ["file", "scan", "label", "distance", "x y z (m)", "roll pitch yaw (deg)",
                                           "max position sigma (mm)", "fitness", "RMSE (mm)", "reliable"], rows[:200])])



def _section_consensus(run_dir: Path, plt) -> Section | None:
    c = _load_json(run_dir / "consensus.json")
    if c is None:
        return None
    P = np.asarray(c["observations_xyz_m"], dtype=float)
    yaw = np.asarray(c["observation_yaw_rad"], dtype=float)
    inside = np.asarray(c["in_consensus"], dtype=bool)
    p0 = np.asarray(c["initial_xyz_m"], dtype=float)
    fig, ax = plt.subplots(figsize=(6.5, 6))
    L = 0.05
    for sel, colour, name in ((inside, "tab:green", "consensus set"), (~inside, "tab:red", "outliers / other")):
        ax.scatter(P[sel, 1], P[sel, 0], color=colour, s=25, label=f"{name} ({int(sel.sum())})")
        ax.quiver(P[sel, 1], P[sel, 0], L * np.sin(yaw[sel]), L * np.cos(yaw[sel]), color=colour, angles="xy",
                  scale_units="xy", scale=1, width=0.004)
    ax.scatter([p0[1]], [p0[0]], marker="*", s=250, color="gold", edgecolor="black", zorder=5,
               label="initial landmark pose")
    ax.quiver([p0[1]], [p0[0]], [1.5 * L * np.sin(c["initial_yaw_rad"])], [1.5 * L * np.cos(c["initial_yaw_rad"])],
              color="black", angles="xy", scale_units="xy", scale=1, width=0.006)
    ax.add_patch(plt.Circle((p0[1], p0[0]), c["position_threshold_m"], fill=False, ls="--", color="0.4"))
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"Consensus initialisation of the first landmark ({human_label(c['label'])}); arrows: object heading")
    return Section(
        "Landmark initialisation by consensus (second paper)",
        f"Unassociated observations of class {human_label(c['label'])} in the world frame. Two observations agree when "
        f"their positions are closer than {c['position_threshold_m']} m and their attitude distance "
        f"1 - <q1, q2>^2 is below {c['attitude_threshold']}; the observation with the most agreement and "
        f"its consensus set (at least {c['min_observations']} observations) give the initial pose "
        "(mean position, eigenvector quaternion mean).",
        figures=[Figure("consensus.png", figure_to_png(fig), "Consensus initialisation.")],
    )



def _objects_xy(run_dir: Path) -> dict:
    rows = _load_csv_dicts(run_dir / "mission" / "ground_truth" / "objects.csv")
    out = {}
    for r in rows:
        if r.get("in_database", "1") in ("1", "True", "true"):
            try:
                out[r["name"]] = (float(r["x_m"]), float(r["y_m"]))
            except (KeyError, ValueError):
                continue
    return out



def _pct(x) -> str:
    try:
        return f"{100 * float(x):.1f}%"
    except (TypeError, ValueError):
        return "n/a"
