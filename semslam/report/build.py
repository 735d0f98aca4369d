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

This module orchestrates; the sections are built in :mod:`.recognition_sections` and :mod:`.slam_sections`,
the run's files read through :mod:`.inputs`.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import ReportError
from .html import Section, write_report
from .plots import pyplot_agg as _plt
from .inputs import MODE_ORDER, _load_json, load_trajectory_csv
from .recognition_sections import (_section_consensus, _section_detections, _section_fig3, _section_recognition,
                                   _section_tables)
from .slam_sections import _sections_slam
from .summary import summary_section

__all__ = ["build_report", "load_trajectory_csv"]


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


