"""The backends report (issue 17): position error over time per backend, from Monte-Carlo outputs, and the
current-time / end-of-dive figure of a graph-backend run's report. The figure's content is checked, not only its
existence: the legend's estimates in the page, the table's numbers, and the drawn colours in the embedded PNG."""

from __future__ import annotations

import base64
import io
import json
import re

import numpy as np
import pytest

from semslam.errors import ReportError
from semslam.report.backends import SERIES, load_curves, write_error_over_time
from semslam.report.build import build_report

SC = {"mode": "pose", "n_runs": 3, "seed": 0}


def _pngs(html: str) -> list[np.ndarray]:
    import matplotlib.image as mpimg

    return [mpimg.imread(io.BytesIO(base64.b64decode(b)), format="png")
            for b in re.findall(r"src='data:image/png;base64,([^']+)'", html)]


def _has_colour(img: np.ndarray, hex_colour: str, tol: float = 0.06) -> bool:
    rgb = np.array([int(hex_colour[i:i + 2], 16) / 255 for i in (1, 3, 5)])
    return bool((np.abs(img[..., :3] - rgb).max(axis=-1) < tol).sum() > 50)


def _three_backends(tmp_path, scenario=SC):
    t = np.arange(40) * 0.5
    ramp = 0.01 + 0.001 * t
    stats = {"ekf_online": {"ate_rmse_mean_m": 0.0270, "fraction_in_band": 0.95},
             "ekf-rts_end": {"ate_rmse_mean_m": 0.0141, "fraction_in_band": 0.99}}
    write_error_over_time(tmp_path / "ekf", "pose", t, {"ekf_online": ramp, "ekf-rts_end": 0.5 * ramp},
                          scenario=scenario, stats=stats)
    write_error_over_time(tmp_path / "isam2", "pose", t, {"isam2_online": ramp, "isam2_end": 0.5 * ramp},
                          scenario=scenario, stats={"isam2_online": {"ate_rmse_mean_m": 0.0270},
                                                    "isam2_end": {"ate_rmse_mean_m": 0.0135}})
    write_error_over_time(tmp_path / "batch", "pose", t, {"batch_online": ramp, "batch_end": 0.5 * ramp + 1e-4},
                          scenario=scenario, stats={"batch_end": {"ate_rmse_mean_m": 0.0135}})
    return t, ramp


def test_report_compares_the_backends_in_one_figure(tmp_path):
    t, ramp = _three_backends(tmp_path)
    html = build_report(tmp_path).read_text()
    assert html.count("<h2>Position error over time per backend") == 1  # one scenario: one section
    for s in ("ekf_online", "ekf-rts_end", "isam2_online", "isam2_end", "batch_end"):
        assert f"<td>{SERIES[s][0]}</td>" in html
    assert SERIES["batch_online"][0] not in html  # batch's front end repeats the EKF's online estimate
    assert "<td>0.0135</td><td>0.50x</td>" in html  # iSAM2 held at the end against the EKF online: 0.0135 / 0.0270
    assert "<td>95 %</td>" in html and "<td>99 %</td>" in html
    rms_end = float(np.sqrt(np.mean((0.5 * ramp) ** 2)))
    assert f"<td>{rms_end:.4g}</td>" in html  # the table's curve figures are the curves'
    (img,) = _pngs(html)
    assert img.shape[0] > 200 and img.shape[1] > 500
    for colour in ("#1f77b4", "#d62728", "#2ca02c"):  # EKF blue, iSAM2 red, batch green lines
        assert _has_colour(img, colour), colour
    assert not (tmp_path / "figures").exists()  # embedded only


def test_different_scenarios_are_not_mixed_and_duplicates_are_named(tmp_path):
    _three_backends(tmp_path)
    t = np.arange(10) * 0.5
    write_error_over_time(tmp_path / "heading", "pose", t, {"isam2_online": t * 0 + 0.02},
                          scenario=dict(SC, yaw_bias_deg=2.0))
    write_error_over_time(tmp_path / "ekf_again", "pose", t, {"ekf_online": t * 0 + 0.05}, scenario=SC)
    groups = load_curves(tmp_path)
    assert sorted(len(g["series"]) for g in groups) == [1, 6]
    html = build_report(tmp_path).read_text()
    assert html.count("<h2>Position error over time per backend") == 2
    assert "yaw bias deg 2.0" in html
    assert "found twice" in html and "ekf_again" in html


def test_bad_curve_files_are_report_errors(tmp_path):
    with pytest.raises(ReportError, match="online"):
        write_error_over_time(tmp_path, "pose", [0.0], {"isam2_now": [0.1]}, scenario={})
    with pytest.raises(ReportError, match="name"):
        write_error_over_time(tmp_path, "../x", [0.0], {"isam2_online": [0.1]}, scenario={})
    (tmp_path / "error_over_time_pose.csv").write_text("t_s,isam2_online_m\n0.0,abc\n")
    with pytest.raises(ReportError, match="error-over-time CSV"):
        build_report(tmp_path)


def test_montecarlo_outputs_of_two_backends_make_one_report(tmp_path):
    pytest.importorskip("gtsam", reason="the graph backends need GTSAM")
    from semslam.cli.main import main
    from semslam.experiments.montecarlo import run_montecarlo, write_montecarlo

    res = {}
    for b in ("ekf", "isam2"):
        res[b] = run_montecarlo(2, modes=("pose",), seed=0, source="synthetic", loops=1, backend=b)
        write_montecarlo(res[b], tmp_path / b)
        assert "<h2>Position error over time per backend" in (tmp_path / b / "report.html").read_text()
    assert res["isam2"].end_error_runs["pose"].shape == res["isam2"].error_runs["pose"].shape
    assert json.loads((tmp_path / "isam2" / "summary.json").read_text())["backend"] == "isam2"
    assert main(["report", str(tmp_path)]) == 0
    html = (tmp_path / "report.html").read_text()
    for s in ("ekf_online", "ekf-rts_end", "isam2_online", "isam2_end"):
        assert f"<td>{SERIES[s][0]}</td>" in html
    ate = res["isam2"].summary["pose"]["smoothed"]["ate_rmse_mean_m"]
    assert f"<td>{SERIES['isam2_end'][0]}</td><td>{ate:.4g}</td>" in html
    (img,) = _pngs(html)
    assert _has_colour(img, "#d62728") and _has_colour(img, "#1f77b4")


def test_a_graph_run_report_shows_current_time_and_end_of_dive_errors(tmp_path):
    pytest.importorskip("gtsam", reason="the graph backends need GTSAM")
    from semslam.simulation.synthetic import square_dataset
    from semslam.simulation.detections import simulate_detections
    from semslam.simulation.truth_slam import truth_detection_config
    from semslam.run import run_slam
    from semslam.run.rundir import write_run

    m = square_dataset(seed=3, loops=1)
    dets = simulate_detections(m, truth_detection_config(m), seed=3, symmetries={})
    write_run(run_slam(m, dets, mode="pose", backend="isam2", symmetries={}), tmp_path)
    html = build_report(tmp_path).read_text()
    assert "<h2>Position error over time: isam2 backend</h2>" in html
    assert "iSAM2 held at the end of the dive" in html
    assert (tmp_path / "figures" / "fig_backend_errors.png").stat().st_size > 10_000
    assert "Online vs smoothed position error" not in html  # the EKF's RTS wording is not used for a graph run
