"""``--backend`` of ``semslam slam`` and ``semslam montecarlo``, and ``run_montecarlo(backend=...)`` (issue 17)."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("gtsam", reason="the graph backends need GTSAM (pip install gtsam)")

from semslam.cli.main import main  # noqa: E402
from semslam.errors import SlamError  # noqa: E402
from semslam.experiments.montecarlo import run_montecarlo  # noqa: E402


def test_slam_cli_backend_writes_a_run_with_the_graph_metrics(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["slam", "synthetic:2", "--mode", "pose", "--backend", "isam2", "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    m = payload["metrics"]["pose"]
    assert m["backend"] == "isam2" and m["graph"]["n_keyframes"] > 100 and m["n_landmarks"] >= 3
    assert m["smoother"]["status"] == "graph (isam2)"  # the whole-dive estimate, evaluated like the RTS smoother's
    assert 0 < m["smoother"]["ate_rmse_m"] < 1.2 * m["ate_rmse_m"]
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["graph"]["backend"] == "isam2"


def test_montecarlo_cli_backend_on_two_tiny_runs(tmp_path, capsys):
    args = ["montecarlo", "--runs", "2", "--mode", "pose", "--source", "synthetic", "--loops", "1", "--json"]
    assert main(args + ["--backend", "batch", "--out", str(tmp_path / "b")]) == 0
    b = json.loads(capsys.readouterr().out)["summary"]["pose"]
    assert main(args + ["--out", str(tmp_path / "e")]) == 0
    e = json.loads(capsys.readouterr().out)["summary"]["pose"]
    # same missions and detections: batch's online trajectory is the front-end filter's, its smoothed one the graph's
    assert b["ate_rmse_mean_m"] == pytest.approx(e["ate_rmse_mean_m"], rel=1e-9)
    assert b["smoothed"]["ate_rmse_mean_m"] == pytest.approx(e["smoothed"]["ate_rmse_mean_m"], rel=0.2)
    assert b["smoothed"]["ate_rmse_mean_m"] < 1.2 * b["ate_rmse_mean_m"]


def test_run_montecarlo_rejects_an_unknown_backend():
    with pytest.raises(SlamError, match=r"'backend' argument of run_montecarlo.*'isam2'.*Got 'gtsam'"):
        run_montecarlo(1, modes=("pose",), source="synthetic", loops=1, backend="gtsam")
