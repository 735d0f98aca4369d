"""Build ``report.html`` from a run directory, using only the files in it.

A demo run has every part; a ``semslam slam`` output (trajectory.csv, landmarks.csv, updates.csv,
metrics.json) or a ``semslam evaluate`` JSON alone can be reported alike: each section is written only when
its inputs exist, and the page says what is missing.

Sections and the papers' items they regenerate:

* Tables 1 and 2: leave-one-out confusion matrices of the database (ESF and VFH, SVM; chi-square too).
* Fig. 3: a scan with the recognised objects coloured and labelled, and their estimated poses.
* Fig. 4: dead-reckoning and SLAM trajectories against ground truth, 3-sigma ellipses, landmarks.
* The consensus initialisation figure of the second paper.
* Fig. 6: x, y, z errors with +-3-sigma bounds over time, landmark detections marked.
* Beyond the papers: recognition precision / recall against ground truth, pose error distributions, NEES over
  time with its chi-square band, the heading-bias mode.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from ..errors import ReportError
from .html import Figure, Section, figure_to_png, write_report
from .summary import human_label, summary_section

MODE_ORDER = ("dr", "position", "pose", "pose+heading")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _load_json(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ReportError(f"cannot read {path}: {exc}") from None


def load_trajectory_csv(path: Path) -> dict:
    """Read a ``trajectory.csv`` written by :func:`semslam.slam.runner.write_run`."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ReportError(f"cannot read {path}: {exc}") from None
    if len(rows) < 2:
        raise ReportError(f"{path} has no data rows")
    head = rows[0]
    try:
        data = np.array(rows[1:], dtype=float)
    except ValueError as exc:
        raise ReportError(f"{path} is malformed: {exc}") from None
    if data.ndim != 2 or data.shape[1] != len(rows[0]):
        raise ReportError(f"{path} is malformed: rows of {data.shape[-1] if data.ndim == 2 else '?'} values under a "
                          f"header of {len(rows[0])} columns")
    col = {name: i for i, name in enumerate(head)}
    need = ["stamp_s", "x_m", "y_m", "z_m"] + [f"cov_p_{a}{b}" for a, b in ("xx", "xy", "xz", "yy", "yz", "zz")]
    missing = [n for n in need if n not in col]
    if missing:
        raise ReportError(f"{path} lacks the columns {missing}")
    cov = np.zeros((len(data), 3, 3))
    for a, i in zip("xyz", range(3)):
        for b, j in zip("xyz", range(3)):
            key = f"cov_p_{a}{b}" if i <= j else f"cov_p_{b}{a}"
            cov[:, i, j] = data[:, col[key]]
    out = {"stamp_s": data[:, col["stamp_s"]], "position_ned_m": data[:, [col["x_m"], col["y_m"], col["z_m"]]],
           "position_cov": cov}
    truth_cols = [c for c in ("truth_x_m", "truth_y_m", "truth_z_m") if c in col]
    if truth_cols and len(truth_cols) != 3:
        raise ReportError(f"{path} lacks the columns {sorted({'truth_x_m', 'truth_y_m', 'truth_z_m'} - set(truth_cols))}")
    if truth_cols:
        out["truth_position_ned_m"] = data[:, [col["truth_x_m"], col["truth_y_m"], col["truth_z_m"]]]
    if "yaw_bias_rad" in col:
        out["yaw_bias_rad"] = data[:, col["yaw_bias_rad"]]
    return out


def _load_csv_dicts(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _find_slam_runs(run_dir: Path) -> dict[str, Path]:
    """``{mode: directory}`` of the SLAM outputs in a run: ``slam/<mode>/``, ``<mode>/`` or the run itself."""
    runs = {}
    for base in (run_dir / "slam", run_dir):  # a demo run, or `semslam slam --mode all --out RUN`
        for mode in MODE_ORDER:
            d = base / mode.replace("+", "_")
            if mode not in runs and (d / "trajectory.csv").is_file():
                runs[mode] = d
    if not runs and (run_dir / "trajectory.csv").is_file():  # `semslam slam --mode M --out RUN`
        cfg = _load_json(run_dir / "metrics.json") or {}
        runs[str(cfg.get("mode", "run"))] = run_dir
    return runs


def build_report(run_dir: str | Path) -> Path:
    """Write ``figures/*.png`` and ``report.html`` into ``run_dir`` from the files there; return the report path."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ReportError(f"the run directory {str(run_dir)!r} does not exist")
    plt = _plt()
    sections: list[Section] = []
    metrics = _load_json(run_dir / "metrics.json")
    missing: list[str] = []

    sec = _guarded(_section_tables, run_dir, plt, what="evaluation/*.json")
    sections.append(sec) if sec else missing.append("leave-one-out evaluation (evaluation/*.json)")
    sec = _guarded(_section_fig3, run_dir, plt, what="fig3_scan.npz")
    sections.append(sec) if sec else missing.append("Fig. 3 scan (fig3_scan.npz)")
    sec = _guarded(_section_recognition, run_dir, plt, what="recognition.json")
    sections.append(sec) if sec else missing.append("recognition against ground truth (recognition.json)")
    sec = _section_detections(run_dir)
    if sec:
        sections.append(sec)
    slam_runs = _find_slam_runs(run_dir)
    if slam_runs:
        sections.extend(_sections_slam(run_dir, slam_runs, plt))
    else:
        missing.append("SLAM outputs (slam/<mode>/trajectory.csv)")
    sec = _guarded(_section_consensus, run_dir, plt, what="consensus.json")
    sections.append(sec) if sec else missing.append("consensus initialisation (consensus.json)")
    if not sections:
        from .backends import build_backends_report, find_curve_files

        if find_curve_files(run_dir):  # Monte-Carlo outputs (one backend, or one sub-directory per backend)
            return build_backends_report(run_dir)
        raise ReportError(f"nothing to report in {run_dir}: none of the expected outputs is there")
    sec = summary_section(run_dir, slam_runs)
    if sec:
        sections.insert(0, sec)
    summary = ("Regenerated from this run: the papers' Tables 1-2 and Figs. 3, 4 and 6, the consensus "
               "initialisation, and metrics beyond the papers. Units: metres, seconds, degrees where stated; "
               "positions in the world NED frame.")
    if missing:
        summary += " Not in this run: " + "; ".join(missing) + "."
    return write_report(run_dir, "semslam run report", sections, metrics=metrics, summary=summary)


def _guarded(section, run_dir: Path, plt, *, what: str):
    """``section(run_dir, plt)``; a file of the run that lacks what the section reads (a truncated or foreign
    JSON) becomes a one-line :class:`ReportError` naming it instead of a traceback."""
    try:
        return section(run_dir, plt)
    except (KeyError, TypeError, IndexError, AttributeError) as exc:
        files = ", ".join(str(f) for f in sorted(run_dir.glob(what))) or str(run_dir / what)
        raise ReportError(f"{files} is malformed: missing or wrong {exc}") from None


# -- sections -----------------------------------------------------------------------------------

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
            sec.figures.append(Figure(f"table_{key}.png", figure_to_png(fig),
                                      f"Confusion matrix, {desc.upper()} features, {clf.upper()} classifier, leave-one-out."))
    sec.tables.append(("Leave-one-out accuracy", ["descriptor", "classifier", "accuracy", "per-class recall"], rows))
    return sec


def _section_fig3(run_dir: Path, plt) -> Section | None:
    path = run_dir / "fig3_scan.npz"
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        pts, cluster, labels, poses, scan_id = z["points_xyz_m"], z["cluster"], z["labels"], z["T_scanner_object"], int(z["scan_id"])
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
    rows = [["scans", s["n_scans"]], ["clusters", s["n_clusters"]], ["detections", s["n_detections"]],
            ["precision (detections with the right class)", _pct(s["precision"])],
            ["recall (object clusters recognised)", _pct(s["recall"])],
            ["background clusters accepted as an object", f"{s['background_false_accepts']} of {s['background_clusters']}"],
            ["detections with a reliable pose", s["n_reliable"]],
            ["median rotation error (deg, modulo symmetry)", s["pose_median_rotation_error_deg"]],
            ["median translation error (m)", s["pose_median_translation_error_m"]],
            ["pose success rate (< 10 deg and < 1 cm)", _pct(s["pose_success_rate"])],
            ["mean pose NEES (6 dof; ideal 6)", s["pose_mean_nees_6dof"]],
            ["median scan-to-detections latency (ms)", s["scan_latency_ms_median"]]]
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


def _sections_slam(run_dir: Path, runs: dict[str, Path], plt) -> list[Section]:
    from ..slam.metrics import chi2_band
    from .plots import plot_error_bounds, plot_smoothed_errors, plot_trajectories

    trajs = {mode: load_trajectory_csv(d / "trajectory.csv") for mode, d in runs.items()}
    metrics = {mode: _load_json(d / "metrics.json") or {} for mode, d in runs.items()}
    first = next(iter(trajs.values()))
    truth = None
    if "truth_position_ned_m" in first:
        truth = {"stamp_s": first["stamp_s"], "position_ned_m": first["truth_position_ned_m"]}
    objects_xy = _objects_xy(run_dir)
    landmarks = {}
    for mode, d in runs.items():
        lms = []
        for row in _load_csv_dicts(d / "landmarks.csv"):
            try:
                pos = np.array([float(row["x_m"]), float(row["y_m"]), float(row["z_m"])])
                cov = np.array([[float(row.get(f"cov_{a}_{b}", row.get(f"cov_{b}_{a}", "nan")) or "nan")
                                 for b in ("x", "y", "z")] for a in ("x", "y", "z")])
            except (KeyError, ValueError):
                continue
            lms.append({"label": row.get("label", ""), "position_ned_m": pos, "cov": cov})
        if lms and mode != "dr":
            landmarks[mode] = lms
    sections = []
    rows = []
    for mode, m in metrics.items():
        sm = m.get("smoother") or {}
        rows.append([mode, m.get("ate_rmse_m"), sm.get("ate_rmse_m", sm.get("status", "-")),
                     m.get("final_position_error_m"), m.get("max_position_error_m"),
                     m.get("nees_position_mean"), m.get("n_landmarks", "")])
    fig, ax = plt.subplots(figsize=(8.5, 7))
    runs_plot = dict(trajs)
    if truth is not None:
        runs_plot = {"truth": truth, **trajs}
    plot_trajectories(ax, runs_plot, landmarks=landmarks, objects_xy=objects_xy,
                      title="Fig. 4: trajectories with 3-sigma ellipses (every 30 s) and mapped landmarks")
    sec = Section("Fig. 4: dead reckoning and SLAM trajectories",
                  "All modes run on the same navigation data and the same detections. Ellipses: 3-sigma position "
                  "uncertainty in the horizontal plane; stars: true object positions; crosses: mapped landmarks.",
                  tables=[("Trajectory metrics per mode (smoothed: RTS over the whole mission, offline"
                           + ("; with a graph backend, the graph's estimate at the end of the dive)"
                              if any(m.get("backend") in ("isam2", "batch") for m in metrics.values()) else ")"),
                           ["mode", "ATE RMSE (m)", "smoothed ATE RMSE (m)", "final error (m)", "max error (m)",
                            "mean position NEES (dof 3)", "landmarks"], rows)],
                  figures=[Figure("fig4_trajectories.png", figure_to_png(fig), "Trajectories, 3-sigma ellipses, landmarks.")])
    sections.append(sec)
    if truth is not None:
        det_stamps = []
        pose_dir = runs.get("pose") or next(iter(runs.values()))
        for row in _load_csv_dicts(pose_dir / "updates.csv"):
            if row.get("kind") == "landmark" and row.get("accepted") in ("True", "true", "1"):
                det_stamps.append(float(row["stamp_s"]))
        fig6 = {m: trajs[m] for m in ("dr", "position", "pose") if m in trajs} or trajs
        fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), sharex=True)
        plot_error_bounds(axes, fig6, truth, detection_stamps_s=det_stamps,
                          title="Fig. 6: position error (solid) and +-3-sigma bounds (dashed); green lines: landmark updates")
        sections.append(Section("Fig. 6: position error and +-3-sigma bounds over time",
                                "Dead reckoning's bounds grow without limit; SLAM's shrink at every landmark update.",
                                figures=[Figure("fig6_error_bounds.png", figure_to_png(fig), "Errors and 3-sigma bounds.")]))
        smoothed = {mode: load_trajectory_csv(d / "trajectory_smoothed.csv") for mode, d in runs.items()
                    if (d / "trajectory_smoothed.csv").is_file()}
        graph = sorted({m.get("backend") for m in metrics.values()} & {"isam2", "batch"})
        if smoothed and graph:
            from .backends import section_graph_run

            sections.append(section_graph_run(graph[0], trajs, smoothed, truth, plt))
        elif smoothed:
            fig, ax = plt.subplots(figsize=(10, 3.8))
            plot_smoothed_errors(ax, trajs, smoothed, truth,
                                 title="Position error: online filter (solid) and RTS-smoothed trajectory (dotted)")
            sections.append(Section(
                "Online and smoothed trajectories",
                "The online filter's estimate at each time uses the measurements up to that time: in the first loop it "
                "drifts like dead reckoning until the vehicle sees its first landmark again. The RTS smoother "
                "(semslam.slam.smoother) conditions every epoch on the whole mission and carries that loop closure "
                "back (offline; the online estimate is unchanged).",
                figures=[Figure("fig_smoothed_errors.png", figure_to_png(fig), "Online vs smoothed position error.")]))
        fig, ax = plt.subplots(figsize=(10, 3.8))
        for mode, tr in trajs.items():
            e = tr["position_ned_m"] - tr["truth_position_ned_m"]
            try:
                nees = np.einsum("ki,ki->k", e, np.linalg.solve(tr["position_cov"], e[..., None])[..., 0])
            except np.linalg.LinAlgError:
                continue
            ax.plot(tr["stamp_s"], nees, lw=0.7, label=mode)
        band = chi2_band(3, 1)
        ax.axhspan(*band, color="green", alpha=0.12, label="95% chi-square band, dof 3, one run")
        ax.set_yscale("log")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("position NEES [-]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
        ax.set_title("Position NEES over time (single run)")
        sections.append(Section("Consistency: NEES over time (beyond the papers)",
                                "Normalised estimation error squared of the vehicle position against the ground truth. "
                                "Monte-Carlo averages (semslam montecarlo) narrow the band.",
                                figures=[Figure("nees.png", figure_to_png(fig), "Position NEES with its 95% band.")]))
        if "pose+heading" in trajs and "yaw_bias_rad" in trajs["pose+heading"]:
            sections.append(_section_heading_bias(trajs["pose+heading"], plt))
    else:  # a recorded dive: no truth, so what the filter says of itself
        sections += _sections_without_truth(trajs, landmarks, plt)
    return sections


#: a yaw-bias estimate that never leaves this band (deg) is "no bias estimated", not a signal
_BIAS_FLAT_DEG = 1e-3


def _section_heading_bias(tr: dict, plt) -> Section:
    """The AHRS yaw-bias estimate over time; a flat one is said in words (no 1e-13 noise on a signal's axis)."""
    b = np.degrees(tr["yaw_bias_rad"])
    title = "Heading-bias mode (beyond the papers)"
    if not len(b) or np.nanmax(np.abs(b)) < _BIAS_FLAT_DEG:
        return Section(title, "No bias estimated: the yaw-bias state stayed at 0 (below 0.001 deg) throughout the "
                              "run. Without a surveyed landmark a constant AHRS bias is unobservable, and the "
                              "observability-constrained filter does not invent one.")
    fig, ax = plt.subplots(figsize=(10, 3.2))
    ax.plot(tr["stamp_s"], b, label="estimated AHRS yaw bias")
    lo, hi = float(np.nanmin(b)), float(np.nanmax(b))
    if hi - lo < 0.1:  # a honest axis: at least 0.1 deg tall, so that a flat estimate looks flat
        mid = 0.5 * (hi + lo)
        ax.set_ylim(mid - 0.05, mid + 0.05)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("yaw bias [deg]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Heading-bias state (pose+heading mode)")
    return Section(title, "With an AHRS yaw-bias state, object orientations make the heading observable.",
                   figures=[Figure("heading_bias.png", figure_to_png(fig), "Estimated yaw bias.")])


def _sections_without_truth(trajs: dict, landmarks: dict, plt) -> list[Section]:
    """Without ground truth: the 3-sigma position bounds over time per mode, and the maps as tables."""
    fig, ax = plt.subplots(figsize=(10, 3.8))
    for mode, tr in trajs.items():
        P = tr["position_cov"]
        ax.plot(tr["stamp_s"], 3.0 * np.sqrt(np.clip(P[:, 0, 0] + P[:, 1, 1], 0, None)), lw=0.9, label=mode)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("horizontal 3-sigma [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Horizontal position uncertainty (3-sigma) per mode")
    out = [Section("Position uncertainty over time (no ground truth)",
                   "The dataset has no ground truth: errors and consistency against it are not shown. Dead "
                   "reckoning's bound grows; SLAM's shrinks at every landmark update.",
                   figures=[Figure("fig6_bounds.png", figure_to_png(fig), "3-sigma position bounds.")])]
    rows = []
    for mode, lms in landmarks.items():
        for k, lm in enumerate(lms):
            sig = np.sqrt(np.clip(np.diag(lm["cov"]), 0, None))
            rows.append([mode, k, human_label(lm["label"]), *[float(v) for v in lm["position_ned_m"]], *[float(v) for v in sig]])
    if rows:
        out.append(Section("Landmark maps", "Each mode's map at the end of the dive (world NED).",
                           tables=[("Landmarks", ["mode", "#", "class", "x (m)", "y (m)", "z (m)", "sigma x (m)",
                                                   "sigma y (m)", "sigma z (m)"], rows)]))
    return out


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
    return Section("Landmark initialisation by consensus (second paper)",
                   f"Unassociated observations of class {human_label(c['label'])} in the world frame. Two observations agree when "
                   f"their positions are closer than {c['position_threshold_m']} m and their attitude distance "
                   f"1 - <q1, q2>^2 is below {c['attitude_threshold']}; the observation with the most agreement and "
                   f"its consensus set (at least {c['min_observations']} observations) give the initial pose "
                   "(mean position, eigenvector quaternion mean).",
                   figures=[Figure("consensus.png", figure_to_png(fig), "Consensus initialisation.")])


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
