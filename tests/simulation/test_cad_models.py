"""``semslam db build --models DIR``: users' CAD models (STL, OBJ, PLY + models.toml) into a view database.

The fixture ``tests/data/models`` holds three fittings of the procedural catalogue exported in millimetres
(``tests/data/models/make_models.py``); the database built from it must describe them as the built-in
objects and recognise them in simulated scans."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh

from semslam.cli.main import main
from semslam.errors import DatabaseError
from semslam.recognition import load_database
from semslam.simulation.cad_models import NonWatertightMeshWarning, models_view_clouds, parse_symmetry, read_models
from semslam.simulation.config import KinectConfig

LABELS = ("ball_valve", "elbow", "reducing_tee")


@pytest.fixture(scope="module")
def db_path(tmp_path_factory, test_data):
    out = tmp_path_factory.mktemp("db") / "models.npz"
    assert main(["db", "build", "--models", str(test_data / "models"), "--out", str(out)]) == 0
    return out


def test_cli_builds_the_three_classes_with_the_builtin_sizes(db_path, test_data, tmp_path, capsys):
    from semslam.simulation import builtin_objects

    db = load_database(db_path)
    assert set(db.classes) == set(LABELS)
    builtin = builtin_objects()
    summary = db.summary()
    for label in LABELS:
        info = db.class_info(label)
        np.testing.assert_allclose(info.size_xyz_m, builtin[label].size_xyz_m, atol=1e-6)  # mm -> m
        assert summary["classes"][label]["n_views"] == 8 and summary["classes"][label]["n_model_views"] == 8
    assert db.class_info("reducing_tee").symmetry.kind == "discrete"
    np.testing.assert_allclose(db.class_info("reducing_tee").symmetry.axis_object, [0, 1, 0])
    assert db.class_info("elbow").symmetry.kind == "none"
    # the acquisition geometry comes from the options; --json reports the source and no warning
    out = tmp_path / "small.npz"
    assert main(["db", "build", "--models", str(test_data / "models"), "--out", str(out), "--n-views", "3",
                 "--kinect-elevation", "60", "--kinect-distance", "1.0", "--model-views", "0", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["source"] == str(test_data / "models") and payload["warnings"] == []
    assert payload["n_views"] == 9 and payload["n_model_views"] == 0


def test_the_database_recognises_the_parts_in_simulated_scans(db_path):
    from semslam.experiments.recognition_scoring import score_scan
    from semslam.pipeline import ScanRecognizer
    from semslam.pipeline.dataset_detection import detect_dataset
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    db = load_database(db_path)
    mission = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4)
    rows: list[dict] = []
    found = detect_dataset(mission, ScanRecognizer(db), seed=0,
                           on_scan=lambda rec, cloud, result: rows.extend(score_scan(mission, rec, cloud, result, db)))
    labels = [d.label for dets in found.detections_by_scan.values() for d in dets]
    assert labels and set(labels) <= set(LABELS)
    detected = [r for r in rows if r["detected"]]
    correct = [r for r in detected if r["label"] == r["truth_label"]]
    assert len(correct) / len(detected) >= 0.9  # measured 19 / 19; the reducing socket (not in the db) is rejected
    for label in LABELS:  # measured 6-7 each
        assert sum(r["label"] == label for r in correct) >= 3, label
    rot = [r["rotation_error_deg"] for r in correct]
    assert np.median(rot) < 10 and max(rot) < 30  # measured <= 8 degrees: the frames are the built-in ones


# -- bad input -------------------------------------------------------------------------------------------
def _box_dir(tmp_path, toml: str, mesh: trimesh.Trimesh | None = None, name: str = "box.stl"):
    """A models folder with one 50 mm box (or ``mesh``) in ``name`` and ``toml`` as models.toml."""
    d = tmp_path / "models"
    d.mkdir(exist_ok=True)
    (mesh if mesh is not None else trimesh.creation.box(extents=(50.0, 30.0, 20.0))).export(d / name)
    (d / "models.toml").write_text(toml, encoding="utf-8")
    return d


GOOD = '[box]\nfile = "box.stl"\nunit = "mm"\n'

BAD_TOML = [
    ('[box]\nfile = "box.stl"\nunit = \n', ("models file", "not valid TOML")),
    (GOOD + 'colour = "red"\n', ("class 'box'", "unknown key 'colour'", "Expected keys")),
    ('[box]\nunit = "mm"\n', ("class 'box'", "missing the key 'file'")),
    ('[box]\nfile = "box.stl"\n', ("class 'box'", "missing the key 'unit'")),
    ('[box]\nfile = "missing.stl"\nunit = "mm"\n', ("class 'box'", "missing.stl", "does not exist")),
    ('[box]\nfile = "box.stl"\nunit = "feet"\n', ("class 'box'", "'unit'", "m, mm, cm, inch", "'feet'")),
    (GOOD + 'symmetry = "discrete:1:z"\n', ("class 'box'", "'symmetry'", "'discrete:1:z'")),
    (GOOD + 'symmetry = "continuous:w"\n', ("'symmetry'", "AXIS one of x, y, z", "'continuous:w'")),
    (GOOD + 'symmetry = "continuous:x:flop"\n', ("'symmetry'", "'continuous:AXIS:flip'", "'continuous:x:flop'")),
    (GOOD + 'symmetry = "discrete:2:x:flip"\n', ("'symmetry'", "'discrete:2:x:flip'")),
    (GOOD + "T_mesh_object = [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
     ("class 'box'", "'T_mesh_object'", "rotation", "det = 2")),
    (GOOD + "T_mesh_object = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n", ("'T_mesh_object'", "4x4", "shape (3, 3)")),
    ('[box]\nfile = "box.stl"\nunit = "m"\n', ("class 'box'", "box.stl", "bounding-box", "'m'", "check 'unit'")),
    ("", ("models file", "at least one class")),
    ('file = "box.stl"\n', ("class 'file'", "must be a table")),
    ('[unknown]\nfile = "box.stl"\nunit = "mm"\n', ("'unknown'",)),
]


@pytest.mark.parametrize("toml, words", BAD_TOML, ids=[w[-1] for _, w in BAD_TOML])
def test_bad_models_file_raises_naming_the_problem(tmp_path, toml, words):
    d = _box_dir(tmp_path, toml)
    with pytest.raises(DatabaseError) as exc:
        read_models(d)
    message = str(exc.value)
    assert "\n" not in message
    for w in words:
        assert w in message, (w, message)


def test_bad_meshes_raise(tmp_path):
    with pytest.raises(DatabaseError, match=r"models file .*models\.toml.* does not exist"):
        read_models(tmp_path)  # no models.toml
    with pytest.raises(DatabaseError, match="models folder .* does not exist"):
        read_models(tmp_path / "nowhere")
    d = tmp_path / "m"
    d.mkdir()
    (d / "models.toml").write_text('[part]\nfile = "part.obj"\nunit = "mm"\n')
    (d / "part.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")  # vertices, no face
    with pytest.raises(DatabaseError, match=r"class 'part'.*part\.obj.*must hold triangles.*empty mesh"):
        read_models(d)
    (d / "part.obj").write_text("v nan 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n")
    with pytest.raises(DatabaseError, match=r"part\.obj.*finite vertex coordinates.*1 vertices with NaN"):
        read_models(d)
    (d / "part.obj").write_text("this is not a mesh\n")
    with pytest.raises(DatabaseError, match=r"class 'part'.*part\.obj"):
        read_models(d)
    (d / "models.toml").write_text('[part]\nfile = "part.3ds"\nunit = "mm"\n')
    (d / "part.3ds").write_text("3DS\n")
    with pytest.raises(DatabaseError, match=r"format semslam does not read.*STL, OBJ, PLY, COLLADA.*'\.3ds'"):
        read_models(d)
    tiny = _box_dir(tmp_path, GOOD, trimesh.creation.box(extents=(2.0, 2.0, 2.0)))  # 2 mm cube in mm
    with pytest.raises(DatabaseError, match=r"3\.464 mm across .*expected 5 mm to 20 m: check 'unit'"):
        read_models(tiny)
    with pytest.raises(DatabaseError, match="The symmetry must be a string.*Got 2 instead"):
        parse_symmetry(2)


def test_a_plain_cylinder_symmetry_is_declared_with_flip():
    s = parse_symmetry("Continuous:Y:Flip")
    assert s.kind == "continuous" and s.flip and s.axis_object.tolist() == [0.0, 1.0, 0.0]
    assert not parse_symmetry("continuous:y").flip


def test_cli_error_is_one_line(tmp_path, capsys):
    d = _box_dir(tmp_path, '[box]\nfile = "box.stl"\nunit = "inch"\n')  # a 50 mm box read in inches: 1.6 m, fine
    assert main(["db", "build", "--models", str(d), "--out", str(tmp_path / "ok.npz"), "--n-views", "2",
                 "--model-views", "0", "--kinect-distance", "3"]) == 0
    capsys.readouterr()
    (d / "models.toml").write_text('[box]\nfile = "box.stl"\nunit = "m"\n')
    assert main(["db", "build", "--models", str(d), "--out", str(tmp_path / "x.npz")]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error: The class 'box'") and "check 'unit'" in lines[0]
    assert not (tmp_path / "x.npz").exists()


def test_non_watertight_mesh_warns_and_still_renders(tmp_path, capsys):
    box = trimesh.creation.box(extents=(50.0, 30.0, 20.0))
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)  # one side open
    d = _box_dir(tmp_path, GOOD, open_box)
    with pytest.warns(NonWatertightMeshWarning, match=r"class 'box'.*not watertight"):
        models = read_models(d)
    views, classes = models_view_clouds(models, seed=0, n_views=2, config=KinectConfig(distance_m=0.5))
    assert len(views) == 2 and all(c.n_points > 100 for _, _, c in views)
    np.testing.assert_allclose(classes["box"]["size_xyz_m"], [0.05, 0.03, 0.02], atol=1e-9)
    # the CLI prints it as one warning line and builds the database
    assert main(["db", "build", "--models", str(d), "--out", str(tmp_path / "db.npz"), "--n-views", "2",
                 "--model-views", "2", "--kinect-distance", "0.5", "--json"]) == 0
    captured = capsys.readouterr()
    assert [line for line in captured.err.splitlines() if line.startswith("semslam: warning:")] != []
    assert "not watertight" in json.loads(captured.out)["warnings"][0]


# -- units and frames --------------------------------------------------------------------------------------
def test_the_same_model_in_m_and_in_mm_gives_the_same_views(tmp_path, test_data):
    mm = trimesh.load(test_data / "models" / "elbow.stl", force="mesh")
    d = tmp_path / "m"
    d.mkdir()
    trimesh.Trimesh(mm.vertices, mm.faces).export(d / "elbow_mm.ply")
    trimesh.Trimesh(mm.vertices * 0.001, mm.faces).export(d / "elbow_m.ply")  # float32 in the file: ~1e-9 m apart
    (d / "models.toml").write_text('[elbow]\nfile = "elbow_mm.ply"\nunit = "mm"\n\n[elbow_m]\nfile = "elbow_m.ply"\nunit = "m"\n')
    models = read_models(d)
    np.testing.assert_allclose(models["elbow"].size_xyz_m, models["elbow_m"].size_xyz_m, atol=1e-8)
    cfg = KinectConfig(distance_m=0.7)
    a, _ = models_view_clouds({"elbow": models["elbow"]}, seed=3, n_views=3, config=cfg)
    b, _ = models_view_clouds({"elbow": models["elbow_m"]}, seed=3, n_views=3, config=cfg)
    for (_, ida, ca), (_, idb, cb) in zip(a, b):
        assert ida == idb and ca.n_points == cb.n_points > 500
        np.testing.assert_allclose(ca.points_xyz_m, cb.points_xyz_m, atol=1e-6)
        np.testing.assert_allclose(ca.viewpoint_xyz_m, cb.viewpoint_xyz_m, atol=1e-8)
    # inch and cm scale the same way
    (d / "models.toml").write_text('[elbow]\nfile = "elbow_mm.ply"\nunit = "cm"\n')
    np.testing.assert_allclose(read_models(d)["elbow"].size_xyz_m, 10 * models["elbow"].size_xyz_m, rtol=1e-9)


def test_T_mesh_object_sets_the_canonical_frame(tmp_path):
    box = trimesh.creation.box(extents=(50.0, 30.0, 20.0))
    box.apply_translation((100.0, 0.0, 0.0))  # mm, far from the origin
    # object x = mesh y, object y = -mesh x, origin at the mesh point (100, 0, 0) mm
    T = "[[0, -1, 0, 100], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]"
    d = _box_dir(tmp_path, GOOD + f'symmetry = "discrete:2:z"\nT_mesh_object = {T}\n', box)
    model = read_models(d)["box"]
    np.testing.assert_allclose(model.size_xyz_m, [0.03, 0.05, 0.02], atol=1e-9)
    np.testing.assert_allclose(model.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)
    assert model.symmetry.order == 2 and model.symmetry.axis_object.tolist() == [0.0, 0.0, 1.0]
    # the default frame: the mesh axes, origin at the bounding-box centre
    d = _box_dir(tmp_path, GOOD, box)
    model = read_models(d)["box"]
    np.testing.assert_allclose(model.size_xyz_m, [0.05, 0.03, 0.02], atol=1e-9)
    np.testing.assert_allclose(model.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)


@pytest.mark.parametrize("how", ["absolute", "parent", "symlink"])
def test_a_model_file_outside_the_models_folder_is_refused(tmp_path, how):
    """models.toml names a file outside its folder (an absolute path, ``../``, a symbolic link leading out): refused
    with one line naming the key, never read."""
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    trimesh.creation.box((0.1, 0.1, 0.1)).export(outside / "box.stl")
    folder = tmp_path / "models"
    folder.mkdir()
    name = {"absolute": str(outside / "box.stl"), "parent": "../elsewhere/box.stl", "symlink": "link.stl"}[how]
    if how == "symlink":
        (folder / "link.stl").symlink_to(outside / "box.stl")
    (folder / "models.toml").write_text(f'[box]\nfile = "{name}"\nunit = "m"\n')
    with pytest.raises(DatabaseError, match=r"'file'.*(inside|leads out of) the models folder"):
        read_models(folder)


def test_a_mesh_beyond_the_size_limits_is_refused_before_it_costs_memory(tmp_path, monkeypatch, capsys):
    """Building a database costs ~1.5 GB per million triangles: a file larger than MAX_MESH_FILE_BYTES is refused
    before it is read, a mesh of more than MAX_MESH_FACES triangles once read, each in one line that says to
    decimate it (the limits lowered here so that a small box crosses them)."""
    import semslam.simulation.mesh_files as mesh_files

    d = _box_dir(tmp_path, '[box]\nfile = "box.stl"\nunit = "mm"\n')  # 12 triangles, 684 bytes
    monkeypatch.setattr(mesh_files, "MAX_MESH_FACES", 11)
    with pytest.raises(DatabaseError, match=r"class 'box'.*box\.stl.*at most 11 triangles\. Got 12 instead: decimate"):
        read_models(d)
    monkeypatch.setattr(mesh_files, "MAX_MESH_FILE_BYTES", 100)
    assert main(["db", "build", "--models", str(d), "--out", str(tmp_path / "db.npz"), "--n-views", "2"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and re.search(r"box\.stl.*must be at most 0 MiB .* Got 0 MiB instead: decimate", err[0])
    assert not (tmp_path / "db.npz").exists()
    monkeypatch.setattr(mesh_files, "MAX_MESH_FACES", 12)
    monkeypatch.setattr(mesh_files, "MAX_MESH_FILE_BYTES", 684)
    assert read_models(d)["box"].mesh.faces.shape == (12, 3)


def test_a_part_too_large_for_the_image_is_seen_whole_from_farther(tmp_path):
    """A 1.4 m part (a UXO-sized body) at the pose-model views' 0.7 m: the camera would sit inside its bounding
    sphere. Its views are taken from farther, far enough that each sees the part from end to end."""
    from semslam.simulation.model_views import whole_part_config

    d = _box_dir(tmp_path, '[box]\nfile = "box.stl"\nunit = "m"\n', trimesh.creation.box(extents=(1.4, 0.3, 0.3)))
    models = read_models(d)
    cfg = KinectConfig(distance_m=0.7, elevation_rad=np.radians(60.0))
    views, _ = models_view_clouds(models, seed=0, n_views=4, config=cfg)
    radius = float(np.linalg.norm([0.7, 0.15, 0.15]))
    half_fov = np.arctan(239.5 / cfg.focal_px)
    for _, view_id, cloud in views:  # the camera aims at the box's centre, the origin of its canonical frame
        assert np.linalg.norm(cloud.viewpoint_xyz_m) == pytest.approx(radius / np.sin(half_fov), rel=1e-6)  # float32 STL
    broadside = [c for _, vid, c in views if vid.endswith("az090")][0]
    assert np.ptp(broadside.points_xyz_m[:, 0]) > 1.38  # end to end (at 0.7 m it would be cut at about +-0.5 m)
    small = KinectConfig(distance_m=0.7)
    assert whole_part_config(small, 0.2) is small  # a part that fits keeps its views
