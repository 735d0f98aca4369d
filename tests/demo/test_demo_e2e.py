"""End to end: `semslam demo --quick` in a temporary directory writes a complete, readable run."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "run"
    proc = subprocess.run([sys.executable, "-m", "semslam.cli.main", "demo", "--quick", "--out", str(out),
                           "--no-progress", "--seed", "3"], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, proc


def test_prints_summary_and_report_path_last(quick_run):
    out, proc = quick_run
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == f"report: {out / 'report.html'}"
    assert any(line.startswith("dr ") for line in lines) and any(line.startswith("pose ") for line in lines)


def test_every_output_exists(quick_run):
    out, _ = quick_run
    for name in ("config.json", "db.npz", "detections.jsonl", "recognition.json", "metrics.json", "report.html",
                 "mission/mission.json", "evaluation/loo_esf_svm.json", "evaluation/loo_vfh_svm.json",
                 "fig3_scan.npz", "consensus.json"):
        assert (out / name).is_file(), name
    for mode in ("dr", "position", "pose", "pose_heading"):
        for name in ("trajectory.csv", "landmarks.csv", "updates.csv", "metrics.json"):
            assert (out / "slam" / mode / name).is_file(), f"slam/{mode}/{name}"
    lines = (out / "detections.jsonl").read_text().strip().splitlines()
    assert lines and all("scan_id" in json.loads(line) for line in lines)


def test_every_figure_is_embedded(quick_run):
    out, _ = quick_run
    pngs = sorted(p.name for p in (out / "figures").glob("*.png"))
    assert {"table_esf_svm.png", "table_vfh_svm.png", "fig3_scan.png", "fig4_trajectories.png",
            "fig6_error_bounds.png", "fig_smoothed_errors.png", "consensus.png", "nees.png", "pose_errors.png"} <= set(pngs)
    html = (out / "report.html").read_text()
    assert len(re.findall(r"src='data:image/png;base64,", html)) == len(pngs)
    assert "<img" in html and "src='figures/" not in html  # self-contained


def test_metrics_in_expected_ranges(quick_run):
    out, _ = quick_run
    m = json.loads((out / "metrics.json").read_text())
    assert m["leave_one_out"]["esf_svm"]["accuracy"] >= 0.9
    rec = m["recognition"]
    assert rec["n_detections"] >= 3
    assert rec["precision"] >= 0.8
    slam = m["slam"]
    assert slam["pose"]["n_landmarks"] >= 1
    assert slam["pose"]["ate_rmse_m"] < slam["dr"]["ate_rmse_m"]


def test_report_rebuilds_from_the_directory(quick_run, tmp_path):
    import shutil

    from semslam.cli.main import main

    out, _ = quick_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    (copy / "report.html").unlink()
    assert main(["report", str(copy)]) == 0
    assert (copy / "report.html").stat().st_size > 10000


def test_refuses_to_mix_runs(quick_run, capsys):
    from semslam.cli.main import main

    out, _ = quick_run
    assert main(["demo", "--quick", "--out", str(out)]) == 1
    assert "holds an earlier semslam run" in capsys.readouterr().err


def test_slam_runs_are_reported_alike(quick_run, tmp_path):
    """`semslam slam --mode all` on the demo's mission and detections writes a directory `semslam report` reads."""
    from semslam.cli.main import main

    out, _ = quick_run
    slam_out = tmp_path / "slam"
    assert main(["slam", str(out / "mission"), "--mode", "all", "--out", str(slam_out),
                 "--detections", str(out / "detections.jsonl")]) == 0
    assert main(["report", str(slam_out)]) == 0
    names = {p.name for p in (slam_out / "figures").glob("*.png")}
    assert {"fig4_trajectories.png", "fig6_error_bounds.png", "fig_smoothed_errors.png", "nees.png"} <= names


def test_recognize_runs_are_reported_alike(quick_run, tmp_path):
    from semslam.cli.main import main

    out, _ = quick_run
    first = json.loads((out / "detections.jsonl").read_text().splitlines()[0])
    scan = out / "mission" / "scans" / f"scan_{first['scan_id']:05d}.pcd"
    run = tmp_path / "rec"
    run.mkdir()
    assert main(["recognize", str(scan), "--db", str(out / "db.npz"), "--out", str(run / "detections.jsonl")]) == 0
    assert main(["report", str(run)]) == 0
    html = (run / "report.html").read_text()
    assert "<h2>Detections</h2>" in html and f"<td>{first['label']}</td>" in html


def test_detect_and_slam_commands_reproduce_the_demo(quick_run, tmp_path, capsys):
    """`semslam detect` + `semslam slam --detections` on the demo's mission and database give the demo's
    detections and SLAM run exactly (the one scan loop, the same seeds, the pipeline config read back)."""
    from semslam.cli.main import main

    out, _ = quick_run
    dets = tmp_path / "dets.jsonl"
    assert main(["detect", str(out / "mission"), "--db", str(out / "db.npz"), "--seed", "3", "--out", str(dets),
                 "--config", str(out / "config.json"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["summary"]
    assert dets.read_text() == (out / "detections.jsonl").read_text()
    assert summary["n_kept"] == len(dets.read_text().splitlines()) and summary["n_scans"] > 0
    assert json.loads((tmp_path / "dets.jsonl.config.json").read_text())["seed"] == 3
    run = tmp_path / "run"
    assert main(["slam", str(out / "mission"), "--detections", str(dets), "--mode", "pose", "--seed", "3",
                 "--out", str(run), "--json"]) == 0
    capsys.readouterr()
    assert (run / "trajectory.csv").read_text() == (out / "slam" / "pose" / "trajectory.csv").read_text()
    assert (run / "landmarks.csv").read_text() == (out / "slam" / "pose" / "landmarks.csv").read_text()
    a = json.loads((run / "metrics.json").read_text())
    b = json.loads((out / "slam" / "pose" / "metrics.json").read_text())
    assert a["ate_rmse_m"] == b["ate_rmse_m"] and a["smoother"] == b["smoother"]


def test_detect_up_from_attitude_runs_and_is_recorded(quick_run, tmp_path, capsys):
    """`semslam detect --up-from-attitude`: every scan gets its own up from the AHRS; the demo's database records no
    class up, so the detections are the demo's exactly, and the option is recorded with the run."""
    from semslam.cli.main import main

    out, _ = quick_run
    dets = tmp_path / "dets.jsonl"
    assert main(["detect", str(out / "mission"), "--db", str(out / "db.npz"), "--seed", "3", "--out", str(dets),
                 "--config", str(out / "config.json"), "--up-from-attitude", "--json"]) == 0
    capsys.readouterr()
    assert dets.read_text() == (out / "detections.jsonl").read_text()
    assert json.loads((tmp_path / "dets.jsonl.config.json").read_text())["up_from_attitude"] is True


def test_report_reads_in_a_minute(quick_run):
    """Issue 18 item 6: the summary (key numbers with goal verdicts) comes first, long tables are collapsed, the raw
    metrics are linked (not dumped), class names are written as people write them. Catches a report that dumps
    metrics.json into a <pre>, lists 81 detections open, or puts the summary after the papers' tables."""
    out, _ = quick_run
    html = (out / "report.html").read_text()
    h2 = re.findall(r"<h2>([^<]*)</h2>", html)
    assert h2[0] == "Summary", h2
    summary = html[html.index("<h2>Summary</h2>"):html.index(f"<h2>{h2[1]}</h2>")]
    assert re.search(r"\d+ of \d+ goals met", summary)
    assert summary.count("verdict-") >= 4 and "<details>" not in summary
    assert "<pre>" not in html and "<a href='metrics.json'>metrics.json</a>" in html
    n_det = len((out / "detections.jsonl").read_text().strip().splitlines())
    if n_det > 12:
        assert re.search(rf"<details><summary>Detections: {n_det} rows", html)
    text = re.sub(r"<img[^>]*>", "", html)  # the page's words, not the figures' bytes
    assert not re.search(r"ball_valve|reducing_socket|reducing_tee", text), "class labels with underscores"
    assert "reducing socket" in text


def test_report_checks_pass_in_headless_chromium(quick_run):
    """The same checks as benchmarks/report_chromium.py, in a real browser: summary on the first screen, every image
    decoded, long tables collapsed. Needs Chromium (skipped with this reason where it is not installed)."""
    import importlib.util
    import shutil
    from pathlib import Path

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if not chromium:
        pytest.skip("Chromium is not installed (Debian: apt-get install chromium)")
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "report_chromium.py"
    spec = importlib.util.spec_from_file_location("report_chromium", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out, _ = quick_run
    failed = [(name, value) for name, value, ok in mod.checks(mod.probe(out / "report.html", chromium)) if not ok]
    assert not failed
