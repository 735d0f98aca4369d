"""Objects attached to structure (``PipelineConfig(attached=AttachedConfig())``, semslam.pipeline.attached): the
object and the pipe it is mounted on are one cluster, too big for any class; the pipe is removed and the object
recognised. Synthetic scenes with an exact oracle (which points are the pipe's is known analytically), and a
cropped real RealSense frame of the shared ball valve (tests/data/real_frames/)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.errors import ConfigError, InputError
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.attached import AttachedConfig, remove_structure
from semslam.segmentation.primitives import fit_primitive
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT, KinectConfig, kinect_view
from semslam.simulation.objects import _box, _cyl, _solid, make_object
from semslam.symmetry import Symmetry

PIPE_R = 0.03
SEG = {"max_planes": 0}
BASE = {"segmentation": SEG, "border": "keep"}


@pytest.fixture(scope="module")
def world():
    """An L-shaped handle (10 cm) and a tube in one database; the handle mounted on a vertical pipe (r 3 cm, 40 cm
    long) that touches its short leg, in the handle's own frame and resting pose."""
    from semslam.recognition import build_database
    from semslam.simulation.objects import _centre

    handle = _centre(_solid([_box((0.10, 0.03, 0.02), (0.0, 0.0, 0.0)), _box((0.03, 0.03, 0.05), (0.035, 0.0, 0.015))]))
    handle_obj = make_object("handle", handle, Symmetry("none"))
    tube = make_object("tube", _solid([_cyl(0.045, (-0.1, 0, 0), (0.1, 0, 0))], [_cyl(0.04, (-0.11, 0, 0), (0.11, 0, 0))]),
                       Symmetry("none"))
    models = {"handle": handle_obj, "tube": tube}
    views, classes = models_view_clouds(models, seed=0, config=SURVEY_KINECT, n_views=8)
    model_views, _ = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT)
    db = build_database(views, classes, seed=0, model_views=model_views)
    T = handle_obj.resting_poses[0]
    up = T[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the floor's vertical in the handle's frame
    lo, hi = handle.bounds
    # the pipe's axis beside the handle's end that is farthest along its long axis (x), touching it
    x_end = lo[0] - PIPE_R + 0.004
    centre = np.array([x_end, 0.0, 0.0])
    p0, p1 = centre - 0.30 * up, centre + 0.10 * up
    pipe = _cyl(PIPE_R, p0, p1)
    mounted = make_object("mounted", _solid([handle, pipe]), Symmetry("none"), centre=False)
    mounted = dataclasses.replace(mounted, resting_poses=[T], resting_probabilities=np.array([1.0]))
    return handle_obj, mounted, db, (p0, p1)


def _scene(mounted, azimuth: float) -> PointCloud:
    return kinect_view(mounted, azimuth, config=KinectConfig(distance_m=1.0, elevation_rad=float(np.radians(45))),
                       seed=1)


def _on_pipe(points: np.ndarray, axis_points) -> np.ndarray:
    """The oracle: points on the pipe's mantle or caps (analytic; depth noise < 2 mm at 1 m)."""
    p0, p1 = axis_points
    a = (p1 - p0) / np.linalg.norm(p1 - p0)
    d = points - p0
    t = d @ a
    r = np.linalg.norm(d - np.outer(t, a), axis=1)
    mantle = np.abs(r - PIPE_R) < 0.004
    caps = (r < PIPE_R + 0.004) & ((np.abs(t) < 0.004) | (np.abs(t - np.linalg.norm(p1 - p0)) < 0.004))
    return mantle | caps


AZIMUTHS = (0.4, 1.2)


@pytest.mark.parametrize("azimuth", AZIMUTHS)
def test_object_on_a_pipe_is_found_only_with_the_flag(world, azimuth):
    handle, mounted, db, axis = world
    scan = _scene(mounted, azimuth)
    pipe = _on_pipe(scan.points_xyz_m, axis)
    assert 0.3 < pipe.mean() < 0.9  # both seen
    off = ScanRecognizer(db, PipelineConfig.from_dict(BASE)).recognize(scan, seed=0)
    assert not off.detections
    big = [c for c in off.clusters if "too big for any class" in c.reason]
    assert len(big) == 1 and big[0].n_points > 0.9 * sum(c.n_points for c in off.clusters)
    on = ScanRecognizer(db, PipelineConfig.from_dict({**BASE, "attached": {}})).recognize(scan, seed=0)
    assert [d.label for d in on.detections] == ["handle"]
    det = on.detections[0]
    att = det.extras["attached"]
    assert att["cluster"] == big[0].cluster_index and att["structures"][0]["kind"] == "cylinder"
    assert abs(att["structures"][0]["radius_m"] - PIPE_R) < 0.006
    # the piece is the handle: its centroid within 1.5 cm of the handle's seen points' (the whole cluster's: 10 cm)
    handle_c = scan.points_xyz_m[~pipe].mean(axis=0)
    assert np.linalg.norm(np.asarray(att["piece_centroid_m"]) - handle_c) < 0.015
    assert np.linalg.norm(scan.points_xyz_m.mean(axis=0) - handle_c) > 0.05
    # the pose: the scan is in the handle's frame, so the true pose is the identity (measured: < 1 mm, < 1 degree)
    assert np.linalg.norm(det.T_sensor_object.translation_m) < 0.005
    cos = (np.trace(det.T_sensor_object.matrix[:3, :3]) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 3.0
    assert on.clusters[big[0].cluster_index].detection is det
    assert "after removing its attachment" in on.clusters[big[0].cluster_index].reason
    assert "attached" in on.timings_ms and "attached" not in off.timings_ms


def test_a_pipe_with_a_short_stub_gives_no_detection_with_the_flag(world):
    """Precision: the same pipe without the handle but with an 8 cm branch (a tee, too big for any class): once the
    pipe is removed, the stub (4.9 cm seen, under 0.6 of the handle's 10 cm) is a fragment, not an object.
    (A 12 cm branch of radius 2 cm is taken for the handle, by the stage as by the plain pipeline when the branch is
    its own cluster: the synthetic database's handle views and a pipe stub are that close.)"""
    handle, _, db, (p0, p1) = world
    side = np.cross(p1 - p0, [1.0, 0.0, 0.0])
    side = 0.08 * side / np.linalg.norm(side)
    mid = p0 + 0.5 * (p1 - p0)
    tee = make_object("tee", _solid([_cyl(PIPE_R, p0, p1), _cyl(0.015, mid, mid + side)]), Symmetry("none"),
                      centre=False)
    tee = dataclasses.replace(tee, resting_poses=[handle.resting_poses[0]], resting_probabilities=np.array([1.0]))
    for azimuth in AZIMUTHS:
        scan = _scene(tee, azimuth)
        on = ScanRecognizer(db, PipelineConfig.from_dict({**BASE, "attached": {}})).recognize(scan, seed=0)
        assert not on.detections, [c.reason for c in on.clusters]
        assert any("too big for any class" in c.reason for c in on.clusters)


def test_structure_removal_takes_the_pipe_and_leaves_the_handle(world):
    from semslam.descriptors import estimate_normals
    from semslam.segmentation import voxel_downsample

    _, mounted, _, axis = world
    scan = _scene(mounted, AZIMUTHS[0])
    pts = voxel_downsample(scan.points_xyz_m, 0.005)
    pipe = _on_pipe(pts, axis)
    normals = estimate_normals(pts, radius_m=0.015, viewpoint_xyz_m=scan.viewpoint_xyz_m).normals_xyz
    steps = remove_structure(pts, normals, tolerance_m=0.02, config=AttachedConfig(max_structures=1), seed=0)
    assert len(steps) == 1
    (prim,), pieces, n_left = steps[0]
    assert n_left >= sum(len(p) for p in pieces)
    a = (axis[1] - axis[0]) / np.linalg.norm(axis[1] - axis[0])
    assert np.degrees(np.arccos(min(1.0, abs(prim.direction @ a)))) < 3.0  # the pipe's axis (measured 0.8 deg)
    biggest = pieces[0]
    assert pipe[biggest].mean() < 0.1  # the piece is the handle
    assert (~pipe[biggest]).sum() > 0.7 * (~pipe).sum()  # and most of it
    removed = np.setdiff1d(np.arange(len(pts)), np.concatenate(pieces))
    assert pipe[removed].mean() > 0.9 and pipe[removed].sum() > 0.95 * pipe.sum()


def test_fit_primitive_recovers_a_cylinder_and_a_plane():
    rng = np.random.default_rng(4)
    axis = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    e1 = np.cross(axis, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    th = rng.uniform(-1.2, 1.2, 1500)  # a 140-degree arc, as a camera sees a pipe
    t = rng.uniform(-0.1, 0.1, 1500)
    centre = np.array([0.1, -0.05, 0.5])
    radial = np.outer(np.cos(th), e1) + np.outer(np.sin(th), e2)
    cyl = centre + 0.035 * radial + np.outer(t, axis) + rng.normal(scale=0.0005, size=(1500, 3))
    outliers = rng.uniform(-0.1, 0.1, (300, 3)) + centre
    pts = np.vstack([cyl, outliers])
    normals = np.vstack([radial, rng.normal(size=(300, 3))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    c = fit_primitive(pts, normals, "cylinder", distance_m=0.003, seed=0)
    assert abs(c.radius_m - 0.035) < 0.002 and abs(abs(c.direction @ axis) - 1) < 1e-3
    assert np.all(c.inliers[:1400] < 1500) and len(c.inliers) >= 1450 and (c.inliers >= 1500).sum() < 30
    plane = np.column_stack([rng.uniform(-0.1, 0.1, (1000, 2)), rng.normal(scale=0.0005, size=1000)])
    pn = np.tile([0.0, 0.0, 1.0], (1000, 1))
    p = fit_primitive(np.vstack([plane, outliers]), np.vstack([pn, normals[1500:]]), "plane", distance_m=0.003, seed=0)
    assert abs(abs(p.direction[2]) - 1) < 1e-3 and len(p.inliers) >= 990
    assert fit_primitive(pts[:2], normals[:2], "cylinder", distance_m=0.003) is None
    # the same seed, the same surface
    c2 = fit_primitive(pts, normals, "cylinder", distance_m=0.003, seed=0)
    assert np.array_equal(c.inliers, c2.inliers)


def test_bad_settings_name_the_argument():
    with pytest.raises(InputError, match="min_area_share"):
        AttachedConfig(min_area_share=0)
    with pytest.raises(InputError, match="kinds"):
        AttachedConfig(kinds=("sphere",))
    with pytest.raises(InputError, match="radius_range_m"):
        AttachedConfig(radius_range_m=(0.1, 0.05))
    with pytest.raises(InputError, match="attached"):
        PipelineConfig(attached={"max_structures": 2})
    with pytest.raises(ConfigError, match="attached"):
        PipelineConfig.from_dict({"attached": {"bogus": 1}})
    with pytest.raises(InputError, match="tolerance_m"):
        remove_structure(np.zeros((5, 3)), np.zeros((5, 3)), tolerance_m=0)
    with pytest.raises(InputError, match="normals_xyz"):
        remove_structure(np.zeros((5, 3)), np.zeros((4, 3)), tolerance_m=0.01)
    with pytest.raises(InputError, match="distance_m"):
        fit_primitive(np.zeros((5, 3)), np.zeros((5, 3)), "plane", distance_m=-1)
    cfg = PipelineConfig.from_dict({"attached": {"kinds": ["cylinder", "plane"], "radius_range_m": [0.01, 0.1]}})
    assert cfg.attached.kinds == ("cylinder", "plane")
    assert PipelineConfig.from_dict(cfg.to_dict()).attached == cfg.attached
    assert PipelineConfig().to_dict()["attached"] is None


REAL = Path(__file__).parents[1] / "data" / "real_valves"
FRAME = Path(__file__).parents[1] / "data" / "real_frames" / "ball_valve_yaw000_1_crop.pcd"
FRAME_SEG = {"drop_origin": True, "max_range_m": 0.5, "voxel_leaf_m": "auto", "cluster_tolerance_m": "auto",
             "max_planes": 0}


@pytest.fixture(scope="module")
def real_ball_frame():
    """The committed crop of a real RealSense frame of the ball valve (yaw 0, frame 1), the database of the
    committed thinned valve views of the OTHER settings (yaw -30 and +30, both classes; held out as in
    ``benchmarks/real_valves_frames.py --db loso``), and the authors' valve centroid in that frame."""
    from semslam.io import read_point_cloud
    from semslam.recognition import build_database

    views, bounds = [], {}
    for f in sorted(REAL.glob("*_valve/*.pcd")):
        if "_yaw000_" in f.name:
            continue
        p = read_point_cloud(f).points_xyz_m
        c = p.mean(axis=0)
        views.append((f.parent.name, f.stem, PointCloud(p - c, viewpoint_xyz_m=-c)))
        lo, hi = bounds.get(f.parent.name, (np.full(3, np.inf), np.full(3, -np.inf)))
        bounds[f.parent.name] = (np.minimum(lo, (p - c).min(axis=0)), np.maximum(hi, (p - c).max(axis=0)))
    assert len(views) == 8
    classes = {c: {"symmetry": Symmetry(), "size_xyz_m": hi - lo} for c, (lo, hi) in bounds.items()}
    db = build_database(views, classes, normal_radius_m="auto", voxel_leaf_m="auto", seed=0)
    scan = read_point_cloud(FRAME)
    truth = read_point_cloud(REAL / "ball_valve" / "pitch000_yaw000_30cm_1.pcd").points_xyz_m.mean(axis=0)
    return db, scan, truth


def test_real_ball_valve_on_its_pipe_is_found_only_with_the_flag(real_ball_frame):
    db, scan, truth = real_ball_frame
    off = ScanRecognizer(db, PipelineConfig.from_dict({"segmentation": FRAME_SEG})).recognize(scan, seed=0)
    assert not off.detections
    (valve,) = [c for c in off.clusters if c.n_points > 2000]  # the lever, the body and the rig's pipe
    assert "too big for any class" in valve.reason
    cluster_c = off.segmentation.clusters[valve.cluster_index].points_xyz_m.mean(axis=0)
    assert np.linalg.norm(cluster_c - truth) > 0.04  # measured 64 mm: the pipe pulls the centroid down
    on = ScanRecognizer(db, PipelineConfig.from_dict({"segmentation": FRAME_SEG, "attached": {}})).recognize(
        scan, seed=0)
    assert [d.label for d in on.detections] == ["ball_valve"]
    det = on.detections[0]
    att = det.extras["attached"]
    assert att["cluster"] == valve.cluster_index and att["structures"][0]["kind"] == "cylinder"
    # measured: the piece's centroid 19 mm and the pose's position 15 mm from the authors' valve centroid
    assert np.linalg.norm(np.asarray(att["piece_centroid_m"]) - truth) < 0.025
    assert np.linalg.norm(det.T_sensor_object.translation_m - truth) < 0.02
    assert att["piece_points"] < 0.4 * valve.n_points


def test_recognize_cli_attached_flag(real_ball_frame, tmp_path, capsys):
    import json

    from semslam.cli.main import main
    from semslam.recognition import save_database

    db, _, truth = real_ball_frame
    save_database(db, tmp_path / "valves.npz")
    frame = FRAME
    opts = ["--max-range", "0.5", "--voxel", "auto", "--cluster-tolerance", "auto", "--max-planes", "0", "--json"]
    capsys.readouterr()
    assert main(["recognize", str(frame), "--db", str(tmp_path / "valves.npz"), *opts]) == 0
    assert json.loads(capsys.readouterr().out)["detections"] == []
    assert main(["recognize", str(frame), "--db", str(tmp_path / "valves.npz"), *opts, "--attached"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert [d["label"] for d in payload["detections"]] == ["ball_valve"]
    assert np.linalg.norm(np.asarray(payload["detections"][0]["T_sensor_object"]["xyz_m"]) - truth) < 0.02
    assert any("after removing its attachment" in c["reason"] for c in payload["clusters"])
