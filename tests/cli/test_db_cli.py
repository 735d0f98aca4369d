"""``semslam db build|info`` and ``semslam evaluate``, run in-process."""

from __future__ import annotations

import json

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.io import write_point_cloud
from semslam.recognition import load_database
from semslam.simulation.synthetic_views import synthetic_shape_views


@pytest.fixture
def views_dir(tmp_path):
    views, _ = synthetic_shape_views(4, n_points=200, seed=4)
    for label, view_id, cloud in views:
        write_point_cloud(tmp_path / "views" / label / f"{view_id}.pcd", cloud)
    return tmp_path / "views"


def test_db_build_info_evaluate(views_dir, tmp_path, capsys):
    out = tmp_path / "db.npz"
    assert main(["db", "build", str(views_dir), "--out", str(out), "--seed", "1", "--normal-radius", "0.02",
                 "--esf-samples", "5000", "--json"]) == 0
    built = json.loads(capsys.readouterr().out)
    assert built["n_views"] == 12 and built["path"] == str(out)
    db = load_database(out)
    assert db.classes == ("box", "cylinder", "sphere")

    assert main(["db", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "version 3, 12 views" in text and "| box | 4 | (views) | none |" in text
    assert main(["--json", "db", "info", str(out)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["classes"]["cylinder"]["symmetry"]["kind"] == "none"  # no classes.json: symmetry none
    assert info["classes"]["sphere"]["n_views"] == 4 and info["version"] == 3
    assert info["n_model_views"] == 0 and info["classes"]["sphere"]["n_model_views"] == 0

    assert main(["evaluate", str(out), "--descriptor", "esf", "--classifier", "chi2", "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["n_views"] == 12 and ev["confusion"] == [[4, 0, 0], [0, 4, 0], [0, 0, 4]]  # separable shapes
    assert ev["accuracy"] == 1.0 and ev["recall"] == {"box": 1.0, "cylinder": 1.0, "sphere": 1.0}
    assert [v["view_id"] for v in ev["views"][:2]] == ["view_00", "view_01"]
    # a views folder is evaluated on the fly, with the same table
    assert main(["evaluate", str(views_dir), "--descriptor", "vfh"]) == 0
    text = capsys.readouterr().out
    assert "| actual \\ predicted | box | cylinder | sphere | recall |" in text and "accuracy:" in text
    assert "descriptor vfh, classifier chi2" in text


def test_db_cli_errors(tmp_path, capsys):
    """A corrupt and a missing database: exit 1 and exactly one stderr line naming the file; no source for
    ``db build``: usage error 2.

    Catches: a traceback or a multi-line message (only the start of stderr was checked), a message that does
    not name the file (the missing-file check did not look for the name)."""
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not really")
    assert main(["db", "info", str(bad)]) == 1
    line = _one_line_error(capsys)
    assert line.startswith("semslam: error: The database file") and "bad.npz" in line
    assert main(["evaluate", str(tmp_path / "missing.npz")]) == 1
    line = _one_line_error(capsys)
    assert "missing.npz" in line and "does not exist" in line
    with pytest.raises(SystemExit) as exc:
        main(["db", "build", "--out", str(tmp_path / "x.npz")])  # neither VIEWS_DIR nor --builtin
    assert exc.value.code == 2


def _one_line_error(capsys) -> str:
    """The CLI's error contract: stderr is exactly one line, ``semslam: error: ...`` (no traceback)."""
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error:"), lines
    return lines[0]


def test_db_build_builtin(tmp_path, capsys):
    out = tmp_path / "builtin.npz"
    assert main(["db", "build", "--builtin", "--n-views", "2", "--model-views", "3", "--esf-samples", "5000",
                 "--normal-radius", "0.006", "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["source"] == "builtin" and payload["n_views"] == 8
    db = load_database(out)
    assert db.classes == ("ball_valve", "elbow", "reducing_socket", "reducing_tee")
    assert db.class_info("reducing_socket").symmetry.kind == "continuous"
    assert db.class_info("reducing_tee").symmetry.order == 2
    assert np.isfinite(db.vfh).all() and (db.vfh[:, 180:].sum(axis=1) > 99).all()
    # views are stored in the object frame: the points lie within the object's bounding box, up to the
    # depth noise of the survey-geometry Kinect (sigma ~3.4 mm at 1.5 m)
    assert db.params["voxel_leaf_m"] == 0.005
    for i in range(db.n_views):
        half = db.class_info(db.labels[i]).size_xyz_m / 2
        excess = np.max(np.abs(db.view_points(i)) - half, axis=1)
        assert np.quantile(excess, 0.99) <= 0.01 and excess.max() <= 0.025
        # seen from 75 degrees of elevation, 1.5 m away (the survey geometry)
        vp = db.viewpoints_xyz_m[i]
        assert 1.4 < np.linalg.norm(vp) < 1.6
    # pose-model views: 3 per class at 60 degrees, 0.7 m, object frame
    assert payload["n_model_views"] == 12 and payload["classes"]["elbow"]["n_model_views"] == 3
    for label in db.classes:
        models = db.pose_views(label)
        assert len(models) == 3
        for m in models:
            assert 0.6 < np.linalg.norm(m.viewpoint_xyz_m) < 0.8
            half = db.class_info(label).size_xyz_m / 2
            assert np.quantile(np.max(np.abs(m.points_xyz_m) - half, axis=1), 0.99) <= 0.005
    # catches a negative count accepted, or its error spread over several lines / not naming the value
    assert main(["db", "build", "--builtin", "--n-views", "1", "--model-views", "-1", "--out", str(out),
                 "--overwrite"]) == 1
    line = _one_line_error(capsys)
    assert "'--model-views' option must be >= 0" in line and "-1" in line
