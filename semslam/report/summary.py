"""The report's first table: the key numbers of a run and whether each met its goal, readable in a minute.

Goals (the project's; the same as in the issues and RESULTS.md):

* recognition precision >= 95 % and recall >= 90 % (clusters of known objects), no background cluster accepted;
* SLAM better than dead reckoning on the same data (DR ATE / mode ATE > 1);
* the filter consistent: >= 90 % of the epochs' position NEES inside the 95 % chi-square band of one run
  (dof 3), and the final error inside the stated 3-sigma;
* scan -> detections latency p90 <= 1.5x the median.

A number the run does not have is left out; a number without a goal is shown with "-".
"""

from __future__ import annotations

import json
from pathlib import Path

from .html import Section
from ..modes import MODES

#: filter modes in the order of the papers
_MODES = MODES


def human_label(label: str) -> str:
    """``"reducing_socket"`` -> ``"reducing socket"`` (a class label as people write it)."""
    return str(label).replace("_", " ").strip()


def _load(path: Path) -> dict | None:
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _num(d: dict, key: str) -> float | None:
    v = d.get(key)
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _recognition_rows(run_dir: Path) -> list[list[str]]:
    rows: list[list[str]] = []

    def add(what, value, goal="-", ok=None):
        rows.append([what, value, goal, "-" if ok is None else ("met" if ok else "NOT met")])

    rec = (_load(run_dir / "recognition.json") or {}).get("summary")
    if not isinstance(rec, dict):
        return rows
    p, r = _num(rec, "precision"), _num(rec, "recall")
    if p is not None:
        add("precision", f"{100 * p:.1f} %", ">= 95 %", p >= 0.95)
    if r is not None:
        add("recall", f"{100 * r:.1f} %", ">= 90 %", r >= 0.90)
    fa = _num(rec, "background_false_accepts")
    if fa is not None:
        add("background clusters accepted", f"{int(fa)} of {int(_num(rec, 'background_clusters') or 0)}", "0", fa == 0)
    med, p90 = _num(rec, "scan_latency_ms_median"), _num(rec, "scan_latency_ms_p90")
    if med and p90:
        add("scan -> detections latency", f"median {med:.1f} ms, p90 {p90:.1f} ms", "p90 <= 1.5x median",
            p90 <= 1.5 * med)
    rot, tr = _num(rec, "pose_median_rotation_error_deg"), _num(rec, "pose_median_translation_error_m")
    if rot is not None and tr is not None:
        add("object pose error (median)", f"{1000 * tr:.1f} mm, {rot:.2f} deg")
    return rows


def _slam_rows(slam_runs: dict[str, Path]) -> list[list[str]]:
    """One row per mode: ATE, ratio to DR, NEES epochs in band, final error vs 3-sigma, map, verdict."""
    metrics = {m: _load(d / "metrics.json") or {} for m, d in slam_runs.items()}
    dr = _num(metrics.get("dr", {}), "ate_rmse_m")
    rows = []
    for mode in [m for m in _MODES if m in metrics] + [m for m in metrics if m not in _MODES]:
        m = metrics[mode]
        ate, inb = _num(m, "ate_rmse_m"), _num(m, "nees_position_fraction_in_95")
        fe, s3 = _num(m, "final_position_error_m"), _num(m, "final_3sigma_m")
        le, nl = _num(m, "landmark_position_error_mean_m"), int(_num(m, "n_landmarks") or 0)
        missed = []
        if ate is not None and dr is not None and mode != "dr" and not ate < dr:
            missed.append("not better than DR")
        if inb is not None and inb < 0.90:
            missed.append("NEES out of band")
        if fe is not None and s3 is not None and fe > s3:
            missed.append("final error outside 3-sigma")
        judged = ate is not None or inb is not None
        rows.append([mode, "-" if ate is None else f"{ate:.3f}",
                     f"{dr / max(ate, 1e-12):.1f}x" if ate is not None and dr is not None and mode != "dr" else "-",
                     "-" if inb is None else f"{100 * inb:.0f} %",
                     "-" if fe is None else f"{fe:.3f} / {s3:.3f}" if s3 is not None else f"{fe:.3f} / -",
                     "-" if mode == "dr" else (f"{nl}" + ("" if le is None else f", {le:.3f} m")),
                     ("NOT met: " + ", ".join(missed)) if missed else ("met" if judged else "-")])
    return rows


def key_results(run_dir: Path, slam_runs: dict[str, Path]) -> tuple[list, list]:
    """The recognition rows ``(what, value, goal, verdict)`` and the SLAM rows (one per mode)."""
    return _recognition_rows(run_dir), _slam_rows(slam_runs)


def _health_rows(slam_runs: dict[str, Path]) -> list[list[str]]:
    """One row per mode: the run's health verdict (:mod:`semslam.run.health`) and its problems."""
    rows = []
    for mode, d in slam_runs.items():
        h = (_load(d / "metrics.json") or {}).get("health")
        if not h:
            continue
        problems = [f"{c['level'].upper()} {c['check']}: {c['message']}" for c in h.get("checks", [])
                    if c.get("level") != "ok"]
        m = _load(d / "metrics.json") or {}
        rows.append([mode, str(h.get("verdict", "?")).upper(), str(int(_num(m, "n_landmarks") or 0)),
                     "; ".join(problems) or "none"])
    return rows


def summary_section(run_dir: Path, slam_runs: dict[str, Path]) -> Section | None:
    """The "Summary" section (None when the run has none of the numbers): the health verdict first, then the goals
    measured against ground truth (a run without truth says so instead of counting zero goals)."""
    rec, slam = key_results(run_dir, slam_runs)
    health = _health_rows(slam_runs)
    if not rec and not slam and not health:
        return None
    verdicts = [r[3] for r in rec] + [r[6] for r in slam]
    met = sum(v == "met" for v in verdicts)
    missed = [r[0] for r in rec if r[3] != "met" and r[3] != "-"] + [r[0] for r in slam if r[6].startswith("NOT")]
    worst = max((r[1] for r in health), key=["OK", "WARNING", "BAD"].index, default=None)
    text = f"Health verdict: {worst}. " if worst else ""
    if met + len(missed):
        text += (f"{met} of {met + len(missed)} goals met." + (" Not met: " + "; ".join(missed) + "." if missed else "")
                 + " Goals: recognition precision >= 95 %, recall >= 90 %, no background accepted, latency p90 <= "
                   "1.5x the median; SLAM better than dead reckoning (DR), >= 90 % of the epochs' position NEES in "
                   "the 95 % band, final error inside the stated 3-sigma.")
    else:
        text += ("This run has no ground truth: no error is measured, and the health verdict (each sensor's "
                 "rejected updates and NIS, the map, the covariance) is the judge of whether it went right.")
        slam = []
    text += " Every number is in metrics.json."
    tables = []
    if health:
        tables.append(("Health", ["mode", "verdict", "landmarks", "problems"], health))
    if rec:
        tables.append(("Recognition", ["what", "value", "goal", "verdict"], rec))
    if slam:
        tables.append(("SLAM (positions against the ground truth where the run has it)",
                       ["mode", "ATE (m)", "DR / mode ATE", "NEES epochs in band", "final error / 3-sigma (m)",
                        "landmarks, mean error", "verdict"], slam))
    return Section("Summary", text, tables=tables)
