"""The report's SLAM sections: Figs. 4 and 6 (trajectories, errors with their 3-sigma bounds), NEES over time,
the heading-bias mode, and runs without ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .html import Figure, Section, figure_to_png
from .inputs import _load_csv_dicts, _load_json, load_trajectory_csv
from .recognition_sections import _objects_xy
from .summary import human_label
from ..modes import GRAPH_BACKENDS


def _sections_slam(run_dir: Path, runs: dict[str, Path], plt) -> list[Section]:
    trajs = {mode: load_trajectory_csv(d / "trajectory.csv") for mode, d in runs.items()}
    metrics = {mode: _load_json(d / "metrics.json") or {} for mode, d in runs.items()}
    first = next(iter(trajs.values()))
    truth = None
    if "truth_position_ned_m" in first:
        truth = {"stamp_s": first["stamp_s"], "position_ned_m": first["truth_position_ned_m"]}
    objects_xy = _objects_xy(run_dir)
    landmarks = _mapped_landmarks(runs)
    sections = [_section_fig4(trajs, metrics, truth, landmarks, objects_xy, plt)]
    if truth is not None:
        sections.append(_section_fig6(runs, trajs, truth, plt))
        sections += _sections_smoothed(runs, trajs, metrics, truth, plt)
        sections.append(_section_nees(trajs, plt))
        if "pose+heading" in trajs and "yaw_bias_rad" in trajs["pose+heading"]:
            sections.append(_section_heading_bias(trajs["pose+heading"], plt))
    else:  # a recorded dive: no truth, so what the filter says of itself
        sections += _sections_without_truth(trajs, landmarks, plt)
    return sections


def _mapped_landmarks(runs: dict[str, Path]) -> dict:
    """Per mode (DR aside), the landmarks of its ``landmarks.csv`` with their position covariance."""
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
    return landmarks


def _section_fig4(trajs: dict, metrics: dict, truth, landmarks: dict, objects_xy, plt) -> Section:
    from .plots import plot_trajectories

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
    sec = Section(
        "Fig. 4: dead reckoning and SLAM trajectories",
        "All modes run on the same navigation data and the same detections. Ellipses: 3-sigma position "
        "uncertainty in the horizontal plane; stars: true object positions; crosses: mapped landmarks.",
        tables=[
            (
                "Trajectory metrics per mode (smoothed: RTS over the whole mission, offline"
                + (
                    "; with a graph backend, the graph's estimate at the end of the dive)"
                    if any(m.get("backend") in GRAPH_BACKENDS for m in metrics.values())
                    else ")"
                ),
                [
                    "mode",
                    "ATE RMSE (m)",
                    "smoothed ATE RMSE (m)",
                    "final error (m)",
                    "max error (m)",
                    "mean position NEES (dof 3)",
                    "landmarks",
                ],
                rows,
            )
        ],
        figures=[Figure("fig4_trajectories.png", figure_to_png(fig), "Trajectories, 3-sigma ellipses, landmarks.")],
    )
    return sec


def _section_fig6(runs: dict[str, Path], trajs: dict, truth: dict, plt) -> Section:
    from .plots import plot_error_bounds

    det_stamps = []
    pose_dir = runs.get("pose") or next(iter(runs.values()))
    for row in _load_csv_dicts(pose_dir / "updates.csv"):
        if row.get("kind") == "landmark" and row.get("accepted") in ("True", "true", "1"):
            det_stamps.append(float(row["stamp_s"]))
    fig6 = {m: trajs[m] for m in ("dr", "position", "pose") if m in trajs} or trajs
    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), sharex=True)
    plot_error_bounds(
        axes,
        fig6,
        truth,
        detection_stamps_s=det_stamps,
        title="Fig. 6: position error (solid) and +-3-sigma bounds (dashed); green lines: landmark updates",
    )
    return Section("Fig. 6: position error and +-3-sigma bounds over time",
                   "Dead reckoning's bounds grow without limit; SLAM's shrink at every landmark update.",
                   figures=[Figure("fig6_error_bounds.png", figure_to_png(fig), "Errors and 3-sigma bounds.")])


def _sections_smoothed(runs: dict[str, Path], trajs: dict, metrics: dict, truth: dict, plt) -> list[Section]:
    from .plots import plot_smoothed_errors

    sections = []
    smoothed = {mode: load_trajectory_csv(d / "trajectory_smoothed.csv") for mode, d in runs.items()
                if (d / "trajectory_smoothed.csv").is_file()}
    graph = sorted({m.get("backend") for m in metrics.values()} & set(GRAPH_BACKENDS))
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
    return sections


def _section_nees(trajs: dict, plt) -> Section:
    from ..slam.consistency import chi2_band

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
    return Section("Consistency: NEES over time (beyond the papers)",
                   "Normalised estimation error squared of the vehicle position against the ground truth. "
                   "Monte-Carlo averages (semslam montecarlo) narrow the band.",
                   figures=[Figure("nees.png", figure_to_png(fig), "Position NEES with its 95% band.")])


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
            rows.append(
                [mode, k, human_label(lm["label"]), *[float(v) for v in lm["position_ned_m"]], *[float(v) for v in sig]]
            )
    if rows:
        out.append(Section("Landmark maps", "Each mode's map at the end of the dive (world NED).",
                           tables=[("Landmarks", ["mode", "#", "class", "x (m)", "y (m)", "z (m)", "sigma x (m)",
                                                   "sigma y (m)", "sigma z (m)"], rows)]))
    return out
