"""Issue #29, item 1: the views' preprocessing is recorded in the database and applied to every query.

Oracle: a query with the artefacts the preprocessing removes (invalid-depth points at the sensor origin, a drawn
line, points out of range) must get exactly the descriptors of the same query without them, through every entry
point (``ViewDatabase.describe``, ``Recognizer.match``, ``ScanRecognizer.recognize`` describes clusters with it);
a query the preprocessing cannot meet is a SemslamError, not a silent mismatch.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.errors import DatabaseError, DescriptorError, InputError
from semslam.simulation.synthetic_views import synthetic_shape_views
from semslam.recognition import (Recognizer, build_database, build_database_from_folder, compute_view_descriptors,
                                 load_database, save_database)
from semslam.recognition.preprocessing import MAX_SPACING_RATIO, PREPROCESSING_VERSION, ViewPreprocessing

N_SAMPLES = 2000  # ESF triplets: enough for these small views, keeps the tests fast


def _dirty(cloud: PointCloud, *, n_origin: int = 15, line_points: int = 40, far_points: int = 0) -> PointCloud:
    """``cloud`` with what a real capture adds: points at the sensor origin, a drawn line (1 mm steps from halfway
    between the sensor and the centroid, collinear to float precision) and, optionally, points 5 m away."""
    p = cloud.points_xyz_m
    vp = np.asarray(cloud.viewpoint_xyz_m, dtype=float)
    line = 0.5 * (p.mean(axis=0) + vp) + np.outer(np.arange(line_points) * 1e-3, [1.0, 0.0, 0.0])  # in free space
    far = vp + np.outer(np.ones(far_points), [0.0, 0.0, 5.0]) + np.outer(np.arange(far_points) * 0.01, [1, 0, 0])
    pts = np.concatenate([p[:10], np.repeat(vp[None], n_origin, axis=0), p[10:], line, far])
    return PointCloud(pts, viewpoint_xyz_m=vp, frame_id=cloud.frame_id)


@pytest.fixture(scope="module")
def shapes():
    return synthetic_shape_views(3, n_points=300, seed=1)


@pytest.fixture(scope="module")
def clean_db(shapes):
    """A database whose views were cleaned (they carried origin points and drawn lines)."""
    views, classes = shapes
    dirty = [(lab, vid, _dirty(c)) for lab, vid, c in views]
    return build_database(dirty, classes, seed=3, voxel_leaf_m=None, normal_radius_m=0.02, esf_n_samples=N_SAMPLES,
                          preprocessing=ViewPreprocessing(clean=True))


def test_build_cleans_the_views_and_records_it(clean_db, shapes):
    views, _ = shapes
    for i, (_, _, c) in enumerate(views):  # the stored views are the views without the artefacts
        np.testing.assert_allclose(clean_db.view_points(i), c.points_xyz_m, atol=1e-6)
    rec = clean_db.params["preprocessing"]
    assert rec["version"] == PREPROCESSING_VERSION and rec["clean"] is True and rec["view_spacing_m"] > 0
    assert clean_db.preprocessing.clean and "sensor-origin points" in clean_db.summary()["preprocessing"]


def test_a_dirty_query_is_described_as_its_clean_self(clean_db, shapes):
    query = shapes[0][4][2]
    kwargs = dict(normal_radius_m=0.02, esf_n_samples=N_SAMPLES, voxel_leaf_m=None, seed=5,
                  vfh_variant=clean_db.params["vfh_variant"])
    expected = compute_view_descriptors(query, **kwargs)
    got = clean_db.describe(_dirty(query), seed=5)
    np.testing.assert_array_equal(got.esf, expected.esf)
    np.testing.assert_array_equal(got.vfh, expected.vfh)
    # without the record (the old behaviour) the artefacts change the descriptors: the test can fail
    unclean = compute_view_descriptors(_dirty(query), **kwargs)
    assert not np.array_equal(unclean.esf, expected.esf)
    # Recognizer.match goes through the same door
    rec = Recognizer(clean_db, descriptor="esf+vfh", rejection="none")
    assert rec.match(_dirty(query), seed=5).distance == rec.match(query, seed=5).distance


def test_range_limits_apply_to_views_and_queries(shapes):
    views, classes = shapes
    prep = ViewPreprocessing(max_range_m=3.0)
    far = [(lab, vid, _dirty(c, n_origin=0, line_points=0, far_points=12)) for lab, vid, c in views]
    db = build_database(far, classes, seed=3, voxel_leaf_m=None, normal_radius_m=0.02, esf_n_samples=N_SAMPLES,
                        preprocessing=prep)
    assert db.point_offsets[-1] == sum(c.n_points for _, _, c in views)  # the far points were not stored
    query = views[1][2]
    a, b = db.describe(_dirty(query, n_origin=0, line_points=0, far_points=12), seed=1), db.describe(query, seed=1)
    np.testing.assert_array_equal(a.esf, b.esf)
    with pytest.raises(DescriptorError, match=r"no point within the database's range limits \[0, 3\] m"):
        db.describe(PointCloud(np.array([[0, 0, 9.0], [0, 0.1, 9], [0.1, 0, 9]]), viewpoint_xyz_m=np.zeros(3)))


def test_record_survives_the_file_and_old_files_read_as_unknown(clean_db, shapes, tmp_path):
    path = save_database(clean_db, tmp_path / "db.npz")
    loaded = load_database(path)
    assert loaded.preprocessing == clean_db.preprocessing
    query = _dirty(shapes[0][1][2])
    np.testing.assert_array_equal(loaded.describe(query, seed=2).esf, clean_db.describe(query, seed=2).esf)
    # a version-2 file: written before the record; nothing is applied to its queries, and it says so
    _rewrite(path, lambda meta: meta.update(version=2) or meta["params"].pop("preprocessing"))
    old = load_database(path)
    assert not old.preprocessing.known and old.summary()["preprocessing"].startswith("unknown")
    expected = compute_view_descriptors(query, normal_radius_m=0.02, esf_n_samples=N_SAMPLES, seed=2,
                                        vfh_variant=old.params["vfh_variant"])
    np.testing.assert_array_equal(old.describe(query, seed=2).esf, expected.esf)
    # a record from a newer semslam, or with a step this one does not know: refused when loaded
    save_database(clean_db, path)
    _rewrite(path, lambda meta: meta["params"]["preprocessing"].update(version=PREPROCESSING_VERSION + 1))
    with pytest.raises(DatabaseError, match=r"db.npz'.*preprocessing in version 2; this semslam applies version 1"):
        load_database(path)
    save_database(clean_db, path)
    _rewrite(path, lambda meta: meta["params"]["preprocessing"].update(deconvolve=True))
    with pytest.raises(DatabaseError, match="preprocessing steps this semslam does not know: deconvolve"):
        load_database(path)


def _rewrite(path, mutate):
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays.pop("meta")[()]))
    mutate(meta)
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)


def test_queries_the_preprocessing_cannot_meet_are_errors(clean_db, shapes):
    query = shapes[0][2][2]
    # only origin points and a drawn line: nothing left once cleaned as the views were
    only_artefacts = PointCloud(np.concatenate([np.zeros((5, 3)), np.outer(np.arange(30) * 1e-3, [1.0, 0, 0])
                                                + [0, 0, 0.5]]), viewpoint_xyz_m=np.zeros(3))
    with pytest.raises(DescriptorError, match="query has no points left after cleaning.*cleaned the same way"):
        clean_db.describe(only_artefacts)
    # the query in millimetres against views in metres: far sparser than the views can be, refused
    mm = PointCloud(query.points_xyz_m * 1000.0, viewpoint_xyz_m=query.viewpoint_xyz_m * 1000.0)
    with pytest.raises(DescriptorError, match=r"point spacing .* times the database views'.*another unit"):
        Recognizer(clean_db).match(mm)
    # just inside the limit it is accepted
    s = clean_db.preprocessing.view_spacing_m
    ok = PointCloud(query.points_xyz_m * (0.9 * MAX_SPACING_RATIO * s / _spacing(query)),
                    viewpoint_xyz_m=query.viewpoint_xyz_m)
    clean_db.describe(ok)
    with pytest.raises(InputError, match="'preprocessing' argument of build_database has an unknown field"):
        build_database(shapes[0], shapes[1], preprocessing={"clean": True, "denoise": 3})
    with pytest.raises(InputError, match="min_range_m < max_range_m"):
        ViewPreprocessing(min_range_m=2.0, max_range_m=1.0)


def _spacing(cloud):
    from semslam.descriptors import point_spacing_m

    return point_spacing_m(cloud.points_xyz_m, seed=0, sample=500)


def test_folder_database_of_real_views_cleans_raw_queries(shared_dir, tmp_path):
    """Real RealSense views (../shared; each file ends with 405 drawn points): a database built from the folder
    records its cleaning, and a held-out raw view is described exactly as when cleaned by hand."""
    from tests._support.shared import require_shared
    from semslam.io import read_point_cloud
    from semslam.segmentation.clean import clean_view

    valves = require_shared(shared_dir / "data" / "real" / "valves", "real RealSense valve views")
    for cls in ("ball_valve", "globe_valve"):
        (tmp_path / cls).mkdir()
        shutil.copy(valves / cls / "pitch000_yaw000_30cm" / "1" / "RANSAC.pcd", tmp_path / cls / "yaw000.pcd")
    db = build_database_from_folder(tmp_path, esf_n_samples=N_SAMPLES)
    assert db.preprocessing.clean and db.preprocessing.view_spacing_m > 0
    raw = read_point_cloud(valves / "globe_valve" / "pitch000_yaw030_30cm" / "1" / "RANSAC.pcd")
    cleaned, report = clean_view(raw)
    assert report.n_drawn > 0  # the raw file does carry the artefacts
    np.testing.assert_array_equal(db.describe(raw, seed=0).vfh, db.describe(cleaned, seed=0).vfh)
    # --no-clean records no cleaning: the raw query is then described raw
    db_raw = build_database_from_folder(tmp_path, clean=False, esf_n_samples=N_SAMPLES)
    assert not db_raw.preprocessing.clean
    assert not np.array_equal(db_raw.describe(raw, seed=0).vfh, db_raw.describe(cleaned, seed=0).vfh)


def test_scan_recognizer_applies_the_record_to_its_clusters(shapes):
    """``ScanRecognizer.recognize`` (so ``detect_dataset``, ``run`` and the node) describes clusters through the same
    door: a database recorded with a 1.5 m range limit recognises the object at 0.45 m and rejects the same object
    at 2.45 m with the reason, instead of matching it as the views were never treated."""
    from semslam.pipeline import ScanRecognizer
    from semslam.pipeline.config import PipelineConfig
    from semslam.segmentation.scene import SegmentationConfig

    views, classes = synthetic_shape_views(3, n_points=800, seed=1)
    db = build_database(views, classes, seed=0, esf_n_samples=N_SAMPLES, preprocessing=ViewPreprocessing(max_range_m=1.5))
    rec = ScanRecognizer(db, PipelineConfig(segmentation=SegmentationConfig(max_planes=0), estimate_pose=False,
                                            border="keep"))
    view = views[4][2]  # a box, object frame: moved to the scanner frame (sensor at the origin)
    vp = view.viewpoint_xyz_m
    away = -vp / np.linalg.norm(vp)
    reasons = []
    for shift in (0.0, 2.0):
        res = rec.recognize(PointCloud(view.points_xyz_m - vp + away * shift, viewpoint_xyz_m=np.zeros(3)))
        assert len(res.clusters) == 1
        reasons.append((res.clusters[0].label, res.clusters[0].reason))
    assert reasons[0][0] == "box"
    assert reasons[1][0] == "unknown" and "range limits [0, 1.5] m" in reasons[1][1]
