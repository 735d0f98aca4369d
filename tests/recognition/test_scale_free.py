"""Descriptors that do not depend on the unit or the sensor (issue 15 item 3): the measured point spacing,
scale invariance of ESF and VFH, and databases built with ``normal_radius_m="auto", voxel_leaf_m="auto"``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.descriptors import compute_esf, compute_vfh, estimate_normals, point_spacing_m
from semslam.errors import DatabaseError, DescriptorError, InputError
from semslam.simulation.synthetic_views import partial_view, synthetic_shape_views
from semslam.recognition import Recognizer, build_database, compute_view_descriptors, load_database, save_database
from semslam.evaluation.classifier import leave_one_out
from semslam.recognition.database import (
    AUTO_RULE,
    DEFAULT_NORMAL_RADIUS_M,
    DEFAULT_VOXEL_LEAF_M,
    resolve_descriptor_lengths,
)
from semslam.simulation.kinect import SURVEY_KINECT, builtin_view_clouds

AUTO = {"normal_radius_m": "auto", "voxel_leaf_m": "auto"}
DESCRIPTORS = ("esf", "vfh", "esf+vfh")


def transformed(views, scale=1.0, step=1):
    """The views with points and viewpoints multiplied by ``scale``, keeping every ``step``-th point."""
    return [(label, vid, PointCloud(c.points_xyz_m[::step] * scale, viewpoint_xyz_m=c.viewpoint_xyz_m * scale,
                                    frame_id=c.frame_id)) for label, vid, c in views]


def loo_predictions(db):
    return {d: leave_one_out(db, descriptor=d, classifier="chi2") for d in DESCRIPTORS}


@pytest.fixture(scope="module")
def kinect_views():
    return builtin_view_clouds(seed=0, config=SURVEY_KINECT)


# -- point_spacing_m --------------------------------------------------------------------------------

@pytest.mark.parametrize("s", [1e-6, 0.003, 1.0, 250.0])
def test_spacing_of_regular_grids_is_the_grid_step(s):
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))  # any rotation and offset
    i, j = np.meshgrid(np.arange(40), np.arange(30), indexing="ij")
    square = s * np.c_[i.ravel(), j.ravel(), np.zeros(i.size)] @ q.T + rng.normal(size=3) * s
    for k in (1, 2, 3, 4):  # the 4 edge neighbours lie at s
        assert point_spacing_m(square, k=k) == pytest.approx(s, rel=1e-9)
    assert point_spacing_m(square, k=8) == pytest.approx(s * np.sqrt(2), rel=1e-9)  # then the diagonals
    cube = s * np.stack(np.meshgrid(*[np.arange(12)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    for k in (1, 4, 6):  # the 6 face neighbours lie at s
        assert point_spacing_m(cube, k=k, sample=None) == pytest.approx(s, rel=1e-9)
    line = s * np.c_[np.arange(50), np.zeros(50), np.zeros(50)]
    assert point_spacing_m(line, k=2) == pytest.approx(s, rel=1e-9)  # along a line: 2 neighbours at s,
    assert point_spacing_m(line, k=4) == pytest.approx(2 * s, rel=1e-9)  # then 2 at 2 s


def test_spacing_is_seeded_scales_with_the_unit_and_follows_the_density():
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(0, 1, size=(20000, 2)), np.zeros(20000)]  # density 20000 per unit area
    a = point_spacing_m(pts, seed=3)
    assert a == point_spacing_m(pts, seed=3)  # seeded subsample
    assert point_spacing_m(pts * 1000, seed=3) == pytest.approx(1000 * a, rel=1e-12)
    assert a == pytest.approx(point_spacing_m(pts, sample=None), rel=0.03)  # the subsample is representative
    # Poisson points: the k-th neighbour distance has median ~ sqrt(k / (pi rho)) (to ~10 %)
    assert a == pytest.approx(np.sqrt(4 / (np.pi * 20000)), rel=0.1)
    assert point_spacing_m(pts[::10], seed=3) == pytest.approx(np.sqrt(10) * a, rel=0.1)  # decimation x10


def test_spacing_errors():
    grid = np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)]
    with pytest.raises(DescriptorError, match=r"at least k \+ 1 = 5 points.*Got 4"):
        point_spacing_m(grid[:4])
    with pytest.raises(DescriptorError, match=r"at least k \+ 1 = 2 points.*Got 1"):
        point_spacing_m(grid[:1], k=1)
    assert point_spacing_m(grid[:2], k=1) == 1.0
    bad = grid.copy()
    bad[2, 1] = np.nan
    with pytest.raises(DescriptorError, match="must be finite"):
        point_spacing_m(bad)
    bad[2, 1] = np.inf
    with pytest.raises(DescriptorError, match="must be finite"):
        point_spacing_m(bad)
    with pytest.raises(DescriptorError, match="shape"):
        point_spacing_m(np.zeros((10, 2)))
    with pytest.raises(DescriptorError, match="no measurable spacing"):
        point_spacing_m(np.ones((10, 3)))
    with pytest.raises(InputError, match="'k'"):
        point_spacing_m(grid, k=0)
    with pytest.raises(InputError, match="'sample'"):
        point_spacing_m(grid, sample=0)


# -- which descriptor parts depend on the unit ----------------------------------------------------------

def test_esf_is_scale_invariant_and_vfh_only_by_its_viewpoint_part():
    """ESF scales the cloud into its 64^3 grid (D2 / D3 bins are fractions of the cloud's extent): the same
    samples give the same histogram at any scale. VFH's angle features (f1-f3) are scale-free and its size
    block is off, but PCL's viewpoint part normalises (vp - c, -1) as a 4-vector: it depends on the unit
    (variants pcl-1.13 and pcl-1.8), the paper's 3-D direction (rusu2010) does not."""
    c = partial_view("box", (0.1, 0.06, 0.03), (0.3, 0.2, 0.3), n_points=800, seed=0)
    esf = compute_esf(c.points_xyz_m, n_samples=5000, seed=1)
    for s in (1024.0, 1 / 1024):  # exact in binary: bit-identical
        np.testing.assert_array_equal(compute_esf(c.points_xyz_m * s, n_samples=5000, seed=1), esf)
    for s in (1e3, 1e-3, 7.3):
        np.testing.assert_allclose(compute_esf(c.points_xyz_m * s, n_samples=5000, seed=1), esf, atol=1e-4)
    nrm = estimate_normals(c.points_xyz_m, radius_m=0.015, viewpoint_xyz_m=c.viewpoint_xyz_m).normals_xyz
    ok = np.isfinite(nrm).all(axis=1)
    pts, n = c.points_xyz_m[ok], nrm[ok]
    for variant in ("pcl-1.13", "pcl-1.8", "rusu2010"):
        v = compute_vfh(pts, n, viewpoint_xyz_m=c.viewpoint_xyz_m, variant=variant)
        vs = compute_vfh(pts * 1e-3, n, viewpoint_xyz_m=c.viewpoint_xyz_m * 1e-3, variant=variant)
        np.testing.assert_array_equal(vs[:180], v[:180])
        assert (np.abs(vs[180:] - v[180:]).sum() > 100) == (variant != "rusu2010")


# -- "auto" lengths --------------------------------------------------------------------------------

def test_auto_lengths_on_the_builtin_views_are_close_to_the_fixed_ones(kinect_views, tmp_path):
    views, classes = kinect_views
    lengths = resolve_descriptor_lengths([c for _, _, c in views], **AUTO)
    assert lengths["spacing_m"] == pytest.approx(0.0056, rel=0.02)
    assert lengths["voxel_leaf_m"] == pytest.approx(DEFAULT_VOXEL_LEAF_M, rel=0.02)
    assert lengths["normal_radius_m"] == pytest.approx(DEFAULT_NORMAL_RADIUS_M, rel=0.02)
    assert lengths["vfh_scale"] == pytest.approx(1.0, rel=0.02)
    db = build_database(views[::4], {k: classes[k] for k in classes}, esf_n_samples=2000, **AUTO)
    p = db.params
    assert {k: p[k] for k in ("normal_radius_m", "voxel_leaf_m", "spacing_m")} == pytest.approx(
        {k: lengths[k] for k in ("normal_radius_m", "voxel_leaf_m", "spacing_m")}, rel=0.05)  # 8 of the 32 views
    assert all(type(p[k]) is float for k in ("normal_radius_m", "voxel_leaf_m", "spacing_m", "vfh_scale"))
    assert p["auto"] == ["normal_radius_m", "voxel_leaf_m"] and p["auto_rule"] == AUTO_RULE
    assert p["voxel_leaf_m"] == pytest.approx(0.9 * p["spacing_m"]) and p["normal_radius_m"] == pytest.approx(
        3 * p["voxel_leaf_m"])
    loaded = load_database(save_database(db, tmp_path / "auto.npz"))
    assert loaded.params == p
    assert json.loads(json.dumps(loaded.summary()))["params"]["spacing_m"] == p["spacing_m"]
    # queries are described with the database's resolved lengths, not re-measured on the query
    q = views[1][2]
    d = loaded.describe(q, seed=5)
    e = compute_view_descriptors(q, normal_radius_m=p["normal_radius_m"], voxel_leaf_m=p["voxel_leaf_m"],
                                 vfh_scale=p["vfh_scale"], esf_n_samples=2000, seed=5)
    np.testing.assert_array_equal(d.esf, e.esf)
    np.testing.assert_array_equal(d.vfh, e.vfh)
    # only one length auto: the other is kept, and the normal radius follows a larger fixed grid
    one = resolve_descriptor_lengths([c for _, _, c in views], normal_radius_m="auto", voxel_leaf_m=0.01)
    assert one["voxel_leaf_m"] == 0.01 and one["normal_radius_m"] == pytest.approx(0.03)
    raw = resolve_descriptor_lengths([c for _, _, c in views], normal_radius_m=0.02, voxel_leaf_m="auto")
    assert raw["normal_radius_m"] == 0.02 and raw["vfh_scale"] == 1.0 and raw["voxel_leaf_m"] > 0
    none = resolve_descriptor_lengths([c for _, _, c in views], normal_radius_m="auto", voxel_leaf_m=None)
    assert none["voxel_leaf_m"] is None and none["normal_radius_m"] == pytest.approx(lengths["normal_radius_m"])


def test_same_leave_one_out_classification_at_any_scale_and_density():
    """Synthetic shapes (2000 points a view) rescaled x0.001 and x1000, decimated x10 (every 10th point) and
    both: with auto lengths every view gets the same predicted label as the original, on every descriptor.
    (Measured on seeds 0-4 with 5000 and 20000 ESF samples: 24 of 24 and identical predictions every time.)"""
    views, classes = synthetic_shape_views(8, n_points=2000, seed=0)
    ref = loo_predictions(build_database(views, classes, esf_n_samples=5000, seed=0, **AUTO))
    assert all(r.accuracy == 1.0 for r in ref.values())
    for scale, step in ((1e-3, 1), (1e3, 1), (1.0, 10), (1e3, 10)):
        db = build_database(transformed(views, scale, step), classes, esf_n_samples=5000, seed=0, **AUTO)
        assert db.params["spacing_m"] / scale == pytest.approx(
            (3.2 if step == 10 else 1.0) * 0.00234, rel=0.05)  # decimation x10: ~sqrt(10) x the spacing
        got = loo_predictions(db)
        for d in DESCRIPTORS:
            np.testing.assert_array_equal(got[d].predicted, ref[d].predicted, err_msg=f"{d} x{scale} /{step}")


def test_kinect_views_classify_the_same_in_millimetres_and_kilometres(kinect_views):
    """The built-in Kinect views at x0.001 and x1000: the same descriptors (up to float rounding), hence the
    same leave-one-out predictions, as in metres. (Decimating these raster-ordered views keeps 28-95 points of
    one row in ten: a different sensor, not the same one sparser, so it is tested on the synthetic views.)"""
    views, classes = kinect_views
    ref_db = build_database(views, classes, esf_n_samples=4000, seed=0, **AUTO)
    ref = loo_predictions(ref_db)
    assert ref["esf"].accuracy == ref["esf+vfh"].accuracy == 1.0
    for scale in (1e-3, 1e3):
        db = build_database(transformed(views, scale), classes, esf_n_samples=4000, seed=0, **AUTO)
        assert db.params["vfh_scale"] * scale == pytest.approx(ref_db.params["vfh_scale"], rel=1e-9)
        np.testing.assert_allclose(db.esf, ref_db.esf, atol=2e-4)
        got = loo_predictions(db)
        for d in DESCRIPTORS:
            np.testing.assert_array_equal(got[d].predicted, ref[d].predicted, err_msg=f"{d} x{scale}")


def test_a_database_in_millimetres_recognises_queries_in_millimetres(kinect_views):
    views, classes = kinect_views
    queries, _ = builtin_view_clouds(seed=1, n_views=6, config=SURVEY_KINECT)  # other azimuths and noise
    mm = build_database(transformed(views, 1000.0), classes, esf_n_samples=4000, seed=0, **AUTO)
    assert mm.params["voxel_leaf_m"] == pytest.approx(5.0, rel=0.02)  # 5 mm, in millimetres
    metres = build_database(views, classes, esf_n_samples=4000, seed=0, **AUTO)
    for descriptor in ("esf", "esf+vfh"):
        rec_mm = Recognizer(mm, descriptor=descriptor, rejection="none")
        rec_m = Recognizer(metres, descriptor=descriptor, rejection="none")
        labels_mm = [rec_mm.match(c, seed=i).label for i, (_, _, c) in enumerate(transformed(queries, 1000.0))]
        labels_m = [rec_m.match(c, seed=i).label for i, (_, _, c) in enumerate(queries)]
        assert labels_mm == labels_m == [label for label, _, _ in queries]


def test_fixed_metre_lengths_fail_off_scale_with_a_clear_error(kinect_views):
    """The issue: views in millimetres with the fixed metre defaults (a 15 um normal radius) left no normal and
    compute_vfh failed with "must have at least 2 points. Got 0"; the error now says why and what to do."""
    views, classes = kinect_views
    with pytest.raises(DescriptorError, match=r"normal_radius_m=0.015.*too small.*normal_radius_m='auto'"):
        build_database(transformed(views[:1], 1000.0), {views[0][0]: classes[views[0][0]]}, esf_n_samples=500)


def test_fixed_lengths_keep_the_old_descriptors_and_params(kinect_views):
    """The default (fixed) path: no measured spacing, the old params keys, VFH exactly as the plain composition
    of voxel grid, normals and compute_vfh (the goldens of tests/recognition/test_database.py cover the rest)."""
    from semslam.segmentation.voxel import voxel_downsample

    views, classes = kinect_views
    db = build_database(views[::8], {label: classes[label] for label, _, _ in views[::8]}, esf_n_samples=500)
    assert set(db.params) == {"vfh_variant", "normal_radius_m", "esf_n_samples", "voxel_leaf_m", "seed",
                              "preprocessing"}
    assert db.params["normal_radius_m"] == 0.015 and db.params["voxel_leaf_m"] == 0.005
    c = views[8][2]
    pts = voxel_downsample(c.points_xyz_m, 0.005)
    nrm = estimate_normals(pts, radius_m=0.015, viewpoint_xyz_m=c.viewpoint_xyz_m).normals_xyz
    ok = np.isfinite(nrm).all(axis=1)
    np.testing.assert_array_equal(db.vfh[1], compute_vfh(pts[ok], nrm[ok], viewpoint_xyz_m=c.viewpoint_xyz_m))


def test_auto_on_a_single_cloud_and_bad_lengths():
    c = partial_view("cylinder", (0.04, 0.04, 0.12), (0.3, 0.1, 0.3), n_points=1500, seed=2)
    big = PointCloud(c.points_xyz_m * 1000, viewpoint_xyz_m=c.viewpoint_xyz_m * 1000)
    a = compute_view_descriptors(c, esf_n_samples=2000, **AUTO)
    b = compute_view_descriptors(big, esf_n_samples=2000, **AUTO)
    np.testing.assert_allclose(b.esf, a.esf, atol=2e-4)
    assert np.abs(b.vfh - a.vfh).sum() < 2.0  # of 300: a voxel centroid or two rounded differently at most
    views, classes = synthetic_shape_views(1, n_points=50, seed=0)
    for bad in ("Auto", "3 mm", -1.0, 0.0):
        with pytest.raises(InputError, match="normal_radius_m"):
            build_database(views, classes, normal_radius_m=bad)
        with pytest.raises(InputError, match="voxel_leaf_m"):
            compute_view_descriptors(c, voxel_leaf_m=bad)
    tiny = [("sphere", "v", PointCloud(np.ones((4, 3))))]
    with pytest.raises(DatabaseError, match="cannot measure a point spacing"):
        resolve_descriptor_lengths([t[2] for t in tiny], **AUTO)


def test_folder_of_views_in_millimetres(kinect_views, tmp_path):
    """``semslam evaluate FOLDER`` / ``db build FOLDER`` on views recorded in millimetres: the fixed metre
    lengths fail with the clear error, "auto" builds a database that classifies them as in metres."""
    from semslam.io import write_point_cloud
    from semslam.recognition import build_database_from_folder

    views, _ = kinect_views
    for label, vid, cloud in transformed(views, 1000.0):
        (tmp_path / label).mkdir(exist_ok=True)
        write_point_cloud(tmp_path / label / f"{vid}.pcd", cloud)
    with pytest.raises(DescriptorError, match="normal_radius_m='auto'"):
        build_database_from_folder(tmp_path, esf_n_samples=500)
    db = build_database_from_folder(tmp_path, esf_n_samples=4000, **AUTO)
    assert db.params["voxel_leaf_m"] == pytest.approx(5.0, rel=0.02)
    assert db.params["normal_radius_m"] == pytest.approx(15.0, rel=0.02)
    res = loo_predictions(db)
    assert res["esf"].accuracy == res["esf+vfh"].accuracy == 1.0


def test_cli_evaluate_and_build_on_views_in_millimetres(tmp_path, capsys):
    """The issue's failure: `semslam evaluate` on a folder of views in another unit stopped with "compute_vfh ...
    Got 0"; the folder now gets its grid and normal radius from its measured spacing (and db build takes auto)."""
    import json as _json

    from semslam.cli.main import main
    from semslam.cloud import PointCloud
    from semslam.simulation.synthetic_views import synthetic_shape_views
    from semslam.io import write_point_cloud

    views, _ = synthetic_shape_views(4, n_points=400, seed=3)
    for label, view_id, cloud in views:
        mm = PointCloud(cloud.points_xyz_m * 1000.0, viewpoint_xyz_m=cloud.viewpoint_xyz_m * 1000.0)
        write_point_cloud(tmp_path / "views" / label / f"{view_id}.pcd", mm)
    assert main(["evaluate", str(tmp_path / "views"), "--descriptor", "esf", "--classifier", "chi2", "--json"]) == 0
    result = _json.loads(capsys.readouterr().out)
    assert result["accuracy"] >= 0.9
    assert main(["db", "build", str(tmp_path / "views"), "--out", str(tmp_path / "db.npz"), "--normal-radius", "auto",
                 "--voxel", "auto", "--esf-samples", "2000", "--json"]) == 0
    built = _json.loads(capsys.readouterr().out)
    assert built["n_views"] == len(views)
