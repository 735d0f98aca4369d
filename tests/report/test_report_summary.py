"""The report's summary table (issue 18 item 6): verdicts against the goals from hand-made run files, and honest
axes for the heading-bias state."""

from __future__ import annotations

import json

import numpy as np

from semslam.report.plots import pyplot_agg as _plt
from semslam.report.slam_sections import _section_heading_bias
from semslam.report.html import COLLAPSE_ROWS, _table_html
from semslam.report.summary import human_label, key_results, summary_section


def _run(tmp_path, slam: dict, recognition: dict | None = None):
    runs = {}
    for mode, m in slam.items():
        d = tmp_path / "slam" / mode.replace("+", "_")
        d.mkdir(parents=True)
        (d / "metrics.json").write_text(json.dumps(m))
        runs[mode] = d
    if recognition is not None:
        (tmp_path / "recognition.json").write_text(json.dumps({"summary": recognition}))
    return runs


def test_verdicts_follow_the_goals(tmp_path):
    """Each goal is judged on its own number: a mode worse than DR, a NEES out of band and a final error outside
    3-sigma are each named; recall 0.86 misses the 90 % goal, precision 1.0 meets the 95 % one."""
    runs = _run(tmp_path, {
        "dr": {"ate_rmse_m": 0.2, "nees_position_fraction_in_95": 0.95, "final_position_error_m": 0.1,
               "final_3sigma_m": 0.5},
        "pose": {"ate_rmse_m": 0.05, "nees_position_fraction_in_95": 0.93, "final_position_error_m": 0.02,
                 "final_3sigma_m": 0.06, "n_landmarks": 4, "landmark_position_error_mean_m": 0.02},
        "position": {"ate_rmse_m": 0.3, "nees_position_fraction_in_95": 0.5, "final_position_error_m": 0.4,
                     "final_3sigma_m": 0.1}},
        {"precision": 1.0, "recall": 0.86, "background_false_accepts": 0, "background_clusters": 10,
         "scan_latency_ms_median": 20.0, "scan_latency_ms_p90": 35.0})
    rec, slam = key_results(tmp_path, runs)
    verdict = {r[0]: r[3] for r in rec}
    assert verdict == {"precision": "met", "recall": "NOT met", "background clusters accepted": "met",
                       "scan -> detections latency": "NOT met"}
    by_mode = {r[0]: r for r in slam}
    assert [r[0] for r in slam] == ["dr", "position", "pose"]  # the papers' order
    assert by_mode["pose"][6] == "met" and by_mode["pose"][2] == "4.0x"
    assert by_mode["position"][6] == ("NOT met: not better than DR, NEES out of band, final error outside 3-sigma")
    sec = summary_section(tmp_path, runs)
    assert sec.title == "Summary" and sec.text.startswith("4 of 7 goals met. Not met: recall; scan -> detections "
                                                          "latency; position.")


def test_a_run_without_ground_truth_has_no_verdict(tmp_path):
    runs = _run(tmp_path, {"pose": {"final_3sigma_m": 0.3, "n_landmarks": 2}})
    rec, slam = key_results(tmp_path, runs)
    assert rec == [] and slam[0][6] == "-" and slam[0][1] == "-"


def test_long_tables_collapse_short_ones_do_not():
    short = _table_html("t", ["a"], [[i] for i in range(COLLAPSE_ROWS)])
    long = _table_html("t", ["a"], [[i] for i in range(COLLAPSE_ROWS + 1)])
    assert "<details>" not in short
    assert long.startswith(f"<details><summary>t: {COLLAPSE_ROWS + 1} rows")


def test_a_flat_bias_is_said_in_words_not_plotted():
    """The report showed 1e-13 rad of numerical noise on an axis that suggested a signal."""
    plt = _plt()
    t = np.arange(100.0)
    flat = _section_heading_bias({"stamp_s": t, "yaw_bias_rad": 1e-13 * np.sin(t)}, plt)
    assert not flat.figures and flat.text.startswith("No bias estimated")
    real = _section_heading_bias({"stamp_s": t, "yaw_bias_rad": np.radians(2.0) * (1 - np.exp(-t / 20))}, plt)
    assert len(real.figures) == 1


def test_human_labels():
    assert human_label("reducing_socket") == "reducing socket" and human_label("tee") == "tee"
