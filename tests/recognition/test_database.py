"""View database: building, exact save/load round trip, corruption detection, folder import."""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

import semslam.descriptors
from semslam.cloud import PointCloud
from semslam.errors import DatabaseError, InputError
from semslam.recognition import (
    FORMAT_VERSION,
    ViewDatabase,
    build_database,
    build_database_from_folder,
    load_database,
    save_database,
)
from semslam.simulation.synthetic_views import StandInDescriptors, synthetic_shape_views
from semslam.symmetry import Symmetry


@pytest.fixture
def standin(monkeypatch):
    fake = StandInDescriptors()
    for name in ("compute_esf", "estimate_normals", "compute_vfh"):
        monkeypatch.setattr(semslam.descriptors, name, getattr(fake, name), raising=False)
    return fake


@pytest.fixture
def small_db(standin):
    views, classes = synthetic_shape_views(4, n_points=150, seed=1)
    return build_database(views, classes, seed=3, voxel_leaf_m=None), views, classes


def test_voxel_leaf_applies_to_views_and_queries(standin):
    from semslam.segmentation import voxel_downsample

    views, classes = synthetic_shape_views(2, n_points=400, seed=1)
    db = build_database(views, classes, seed=3, voxel_leaf_m=0.01)
    assert db.params["voxel_leaf_m"] == 0.01
    expected = [len(voxel_downsample(c.points_xyz_m, 0.01)) - 1 for _, _, c in views]  # minus the NaN normal
    assert standin.vfh_inputs == expected and max(expected) < 399
    standin.vfh_inputs.clear()
    db.describe(views[0][2], seed=0)  # the query goes through the same grid
    assert standin.vfh_inputs == expected[:1]
    with pytest.raises(InputError, match="voxel_leaf_m"):
        build_database(views, classes, voxel_leaf_m=-1.0)


def test_build_database_contents(small_db, standin):
    db, views, _ = small_db
    assert db.n_views == len(views) == 12
    assert db.classes == ("box", "cylinder", "sphere")
    assert db.esf.shape == (12, 640) and db.vfh.shape == (12, 308)
    assert db.esf.dtype == db.vfh.dtype == np.float32
    assert db.view_counts() == {"box": 4, "cylinder": 4, "sphere": 4}
    for i, (label, view_id, cloud) in enumerate(views):
        assert db.labels[i] == label and db.view_ids[i] == view_id
        np.testing.assert_allclose(db.view_points(i), cloud.points_xyz_m, atol=1e-7)  # float32 storage
        np.testing.assert_array_equal(db.viewpoints_xyz_m[i], cloud.viewpoint_xyz_m)
        assert db.view_cloud(i).frame_id == "object"
    # the view's own descriptors, computed through the one descriptor call site
    assert standin.vfh_inputs == [c.n_points - 1 for _, _, c in views]  # the NaN-normal point was left out
    cyl = db.class_info("cylinder")
    assert cyl.symmetry.kind == "continuous" and np.allclose(cyl.size_xyz_m, [0.04, 0.04, 0.12])
    assert db.params["vfh_variant"] == "standin-default"  # the default variant's name is recorded
    np.testing.assert_array_equal(db.views_of("box"), [4, 5, 6, 7])
    with pytest.raises(DatabaseError, match="'rock' is not in the database"):
        db.class_info("rock")
    with pytest.raises(InputError, match="'i'"):
        db.view_points(12)
    with pytest.raises(ValueError):
        db.esf[0, 0] = 1.0  # read-only


def test_build_is_seeded(standin):
    views, classes = synthetic_shape_views(2, n_points=100, seed=0)
    a = build_database(views, classes, seed=7)
    b = build_database(views, classes, seed=7)
    c = build_database(views, classes, seed=8)
    np.testing.assert_array_equal(a.esf, b.esf)
    assert not np.array_equal(a.esf, c.esf)


def test_features_combined_is_unit_sum_blocks(small_db):
    db = small_db[0]
    np.testing.assert_array_equal(db.features("esf"), db.esf.astype(float))
    both = db.features("esf+vfh")
    assert both.shape == (12, 948)
    np.testing.assert_allclose(both[:, :640].sum(axis=1), 1.0)
    np.testing.assert_allclose(both[:, 640:].sum(axis=1), 1.0)
    with pytest.raises(InputError, match="'descriptor'"):
        db.features("fpfh")


def test_build_rejects_bad_views(standin):
    views, classes = synthetic_shape_views(2, n_points=100, seed=0)
    with pytest.raises(InputError, match="appears twice"):
        build_database(views + views[:1], classes)
    with pytest.raises(InputError, match="'classes' does not describe"):
        build_database(views, {k: v for k, v in classes.items() if k != "box"})
    with pytest.raises(InputError, match="without views: extra"):
        build_database(views, {**classes, "extra": classes["box"]})
    with pytest.raises(InputError, match="reserved"):
        build_database([("unknown", "v", views[0][2])], {"unknown": classes["box"]})
    with pytest.raises(InputError, match="at least 3 points"):
        build_database([("box", "v", PointCloud(np.zeros((2, 3))))], {"box": classes["box"]})
    with pytest.raises(InputError, match=r"\(label, view_id, PointCloud\)"):
        build_database([("box", "v")], {"box": classes["box"]})


def test_save_load_round_trip_is_exact(small_db, tmp_path):
    db = small_db[0]
    path = save_database(db, tmp_path / "sub" / "db.npz")
    assert path.exists() and not list(path.parent.glob(".*.tmp"))  # atomic: no temp file left
    loaded = load_database(path)
    for name in ("labels", "view_ids", "point_offsets", "points_xyz_m", "viewpoints_xyz_m", "esf", "vfh"):
        a, b = getattr(db, name), getattr(loaded, name)
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert loaded.params == db.params
    assert loaded.classes == db.classes
    for c in db.classes:
        assert loaded.class_info(c).to_dict() == db.class_info(c).to_dict()
    with zipfile.ZipFile(path) as z:  # plain npz, no pickled object
        meta = json.loads(np.load(z.open("meta.npy"), allow_pickle=False)[()])
    assert meta["format"] == "semslam-view-database" and meta["version"] == FORMAT_VERSION
    assert set(meta["checksums"]) == {"labels", "view_ids", "point_offsets", "points_xyz_m",
                                      "viewpoints_xyz_m", "esf", "vfh", "model_labels", "model_point_offsets",
                                      "model_points_xyz_m", "model_viewpoints_xyz_m"}


def _rewrite(path, mutate):
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays.pop("meta")[()]))
    mutate(meta, arrays)
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)


def test_corruption_is_detected(small_db, tmp_path):
    db = small_db[0]
    good = save_database(db, tmp_path / "good.npz")
    raw = good.read_bytes()

    flipped = tmp_path / "flipped.npz"
    data = bytearray(raw)
    start = raw.index(b"points_xyz_m.npy")  # inside the points array's data
    for k in range(start + 300, start + 310):
        data[k] ^= 0xFF
    flipped.write_bytes(bytes(data))
    with pytest.raises(DatabaseError, match="flipped.npz.*(corrupted|checksum)"):
        load_database(flipped)

    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DatabaseError, match="truncated.npz.*truncated or corrupted"):
        load_database(truncated)

    bumped = tmp_path / "bumped.npz"
    bumped.write_bytes(raw)
    _rewrite(bumped, lambda meta, arrays: meta.update(version=FORMAT_VERSION + 1))
    with pytest.raises(DatabaseError, match=f"bumped.npz.*version {FORMAT_VERSION + 1}"):
        load_database(bumped)

    # consistent zip, but an array no longer matches its recorded checksum
    tampered = tmp_path / "tampered.npz"
    tampered.write_bytes(raw)
    _rewrite(tampered, lambda meta, arrays: arrays.update(esf=arrays["esf"] * 2))
    with pytest.raises(DatabaseError, match="tampered.npz.*checksum of the array 'esf'"):
        load_database(tampered)
    assert load_database(tampered, verify=False).esf[0].sum() == pytest.approx(2 * db.esf[0].sum(), rel=1e-6)

    wrong_sum = tmp_path / "wrong_sum.npz"
    wrong_sum.write_bytes(raw)
    _rewrite(wrong_sum, lambda meta, arrays: meta["checksums"].update(labels="0" * 8))
    with pytest.raises(DatabaseError, match="checksum of the array 'labels'"):
        load_database(wrong_sum)

    inconsistent = tmp_path / "inconsistent.npz"
    inconsistent.write_bytes(raw)

    def drop_view(meta, arrays):
        arrays["vfh"] = arrays["vfh"][:-1]
        meta["checksums"]["vfh"] = f"{zlib.crc32(arrays['vfh'].data):08x}"

    _rewrite(inconsistent, drop_view)
    with pytest.raises(DatabaseError, match="'vfh' must have shape"):
        load_database(inconsistent)

    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    with pytest.raises(DatabaseError, match="not a semslam view database"):
        load_database(other)
    text = tmp_path / "text.npz"
    text.write_text("hello")
    with pytest.raises(DatabaseError, match="text.npz"):
        load_database(text)
    with pytest.raises(DatabaseError, match="does not exist"):
        load_database(tmp_path / "missing.npz")


def test_subset(small_db):
    db = small_db[0]
    sub = db.subset([5, 0])
    assert sub.n_views == 2 and sub.classes == ("box", "sphere")
    np.testing.assert_array_equal(sub.view_points(0), db.view_points(5))
    np.testing.assert_array_equal(sub.view_points(1), db.view_points(0))
    np.testing.assert_array_equal(sub.esf[0], db.esf[5])


def test_build_from_folder(standin, tmp_path):
    from semslam.io import write_point_cloud

    views, _ = synthetic_shape_views(2, n_points=120, seed=2)
    for label, view_id, cloud in views:
        write_point_cloud(tmp_path / label / f"{view_id}.pcd", cloud)
    (tmp_path / "notes.txt").write_text("ignored")
    (tmp_path / "classes.json").write_text(json.dumps(
        {"cylinder": {"symmetry": {"kind": "continuous", "axis_object": [0, 0, 1], "flip": True},
                      "size_xyz_m": [0.04, 0.04, 0.12]}}))
    db = build_database_from_folder(tmp_path, seed=0)
    assert db.classes == ("box", "cylinder", "sphere") and db.n_views == 6
    assert list(db.view_ids[:2]) == ["view_00", "view_01"]
    assert db.class_info("cylinder").symmetry.kind == "continuous" and db.class_info("cylinder").symmetry.flip
    # a plain cylinder's end-for-end symmetry survives the file and is shown by `db info`
    from semslam.cli.cmd_db import format_summary

    saved = load_database(save_database(db, tmp_path / "saved.npz"))
    assert saved.class_info("cylinder").symmetry.flip and not saved.class_info("box").symmetry.flip
    assert "continuous about (0.0, 0.0, 1.0), same end for end" in format_summary(saved.summary(), "saved.npz")
    assert db.class_info("box").symmetry.kind == "none"
    box_pts = np.concatenate([c.points_xyz_m for lab, _, c in views if lab == "box"])
    np.testing.assert_allclose(db.class_info("box").size_xyz_m, box_pts.max(0) - box_pts.min(0), atol=1e-6)
    i = int(db.views_of("sphere")[1])
    np.testing.assert_allclose(db.viewpoints_xyz_m[i], views[5][2].viewpoint_xyz_m, atol=1e-6)
    with pytest.raises(DatabaseError, match="does not exist"):
        build_database_from_folder(tmp_path / "nope")
    (tmp_path / "classes.json").write_text("{broken")
    with pytest.raises(DatabaseError, match="classes.json.*not valid JSON"):
        build_database_from_folder(tmp_path)


def test_viewdatabase_validates_construction():
    with pytest.raises(InputError, match="'esf' must have shape"):
        ViewDatabase(np.array(["a"]), np.array(["v"]), np.array([0, 1]), np.zeros((1, 3), np.float32),
                     np.zeros((1, 3)), np.zeros((2, 640), np.float32), np.zeros((1, 308), np.float32),
                     {"a": {"symmetry": Symmetry(), "size_xyz_m": np.ones(3)}})


def test_build_with_real_descriptors(tmp_path):
    """The real ESF / VFH / normals (semslam.descriptors): separable synthetic shapes, exact round trip."""
    from semslam.recognition import compute_view_descriptors
    from semslam.evaluation.classifier import leave_one_out

    views, classes = synthetic_shape_views(5, n_points=300, seed=5)
    db = build_database(views, classes, normal_radius_m=0.015, esf_n_samples=5000, seed=0)
    assert db.params["vfh_variant"] == "pcl-1.13"
    np.testing.assert_allclose(db.esf.sum(axis=1), 1.0, atol=1e-4)  # ESF sums to 1
    assert (db.vfh[:, 135:180] == 0).all()  # PCL's default VFH has no size component
    np.testing.assert_allclose(db.vfh[:, 180:].sum(axis=1), 100.0, rtol=1e-4)  # viewpoint part: 100 / N each
    d = compute_view_descriptors(views[3][2], normal_radius_m=0.015, esf_n_samples=5000, voxel_leaf_m=0.005, seed=0)
    np.testing.assert_array_equal(d.vfh, db.vfh[3])  # VFH is deterministic: recomputed identically
    np.testing.assert_array_equal(db.describe(views[3][2]).vfh, db.vfh[3])  # describe uses the db's grid
    res = leave_one_out(db, descriptor="esf", classifier="chi2")
    assert res.accuracy == 1.0
    loaded = load_database(save_database(db, tmp_path / "real.npz"))
    np.testing.assert_array_equal(loaded.esf, db.esf)
    np.testing.assert_array_equal(loaded.vfh, db.vfh)


@pytest.fixture
def model_db(standin):
    """Recognition views of three shapes plus pose-model views for two of them (the sphere has none)."""
    views, classes = synthetic_shape_views(2, n_points=120, seed=1)
    models, _ = synthetic_shape_views(3, n_points=90, seed=2)
    models = [m for m in models if m[0] != "sphere"]
    return build_database(views, classes, seed=3, voxel_leaf_m=None, model_views=models), views, models


def test_pose_model_views_round_trip_and_fallback(model_db, tmp_path):
    db, _, models = model_db
    assert FORMAT_VERSION >= 2 and len(db.model_labels) == 6
    loaded = load_database(save_database(db, tmp_path / "db.npz"))
    for d in (db, loaded):
        box = d.pose_views("box")
        expected = [c for lab, _, c in models if lab == "box"]
        assert len(box) == 3
        for got, exp in zip(box, expected):
            np.testing.assert_allclose(got.points_xyz_m, exp.points_xyz_m, atol=1e-6)  # float32 storage
            np.testing.assert_allclose(got.viewpoint_xyz_m, exp.viewpoint_xyz_m)
            assert got.frame_id == "object"
        # no pose-model views: the recognition views
        sphere = d.pose_views("sphere")
        assert len(sphere) == 2
        np.testing.assert_array_equal(sphere[1].points_xyz_m, d.view_points(int(d.views_of("sphere")[1])))
    for name in ("model_labels", "model_point_offsets", "model_points_xyz_m", "model_viewpoints_xyz_m"):
        np.testing.assert_array_equal(getattr(db, name), getattr(loaded, name), err_msg=name)
    s = db.summary()
    assert s["n_model_views"] == 6 and s["classes"]["cylinder"]["n_model_views"] == 3
    assert s["classes"]["sphere"]["n_model_views"] == 0
    with pytest.raises(DatabaseError, match="'nope' is not in the database"):
        db.pose_views("nope")
    # subset keeps the model views of the kept classes only
    sub = db.subset(db.views_of("cylinder"))
    assert sub.classes == ("cylinder",) and set(sub.model_labels.tolist()) == {"cylinder"}
    np.testing.assert_array_equal(sub.pose_views("cylinder")[2].points_xyz_m, db.pose_views("cylinder")[2].points_xyz_m)


def test_version_1_files_are_still_read(small_db, tmp_path):
    db = small_db[0]
    old = save_database(db, tmp_path / "v1.npz")

    def to_v1(meta, arrays):
        for name in ("model_labels", "model_point_offsets", "model_points_xyz_m", "model_viewpoints_xyz_m"):
            del arrays[name], meta["checksums"][name]
        meta["version"] = 1

    _rewrite(old, to_v1)
    loaded = load_database(old)
    assert len(loaded.model_labels) == 0 and loaded.model_point_offsets.tolist() == [0]
    np.testing.assert_array_equal(loaded.esf, db.esf)
    views = loaded.pose_views("box")
    assert len(views) == 4
    np.testing.assert_array_equal(views[0].points_xyz_m, db.view_points(int(db.views_of("box")[0])))
    # a version-2 file without its model arrays is incomplete
    broken = save_database(db, tmp_path / "v2.npz")
    _rewrite(broken, lambda meta, arrays: arrays.pop("model_labels"))
    with pytest.raises(DatabaseError, match="v2.npz' is missing the arrays model_labels"):
        load_database(broken)


def test_build_rejects_bad_model_views(standin):
    views, classes = synthetic_shape_views(1, n_points=80, seed=1)
    with pytest.raises(InputError, match="Model view 0 .* class 'torus'"):
        build_database(views, classes, model_views=[("torus", "m0", views[0][2])])
    with pytest.raises(InputError, match="model view \\('box', 'm'\\) appears twice"):
        build_database(views, classes, model_views=[("box", "m", views[0][2])] * 2)
    with pytest.raises(InputError, match="at least 3 points"):
        build_database(views, classes, model_views=[("box", "m", PointCloud(np.zeros((2, 3))))])
    with pytest.raises(InputError, match="'model_views' .* must be \\(label, view_id, PointCloud\\)"):
        build_database(views, classes, model_views=[("box", "m")])


def test_concurrent_descriptors_equal_serial_ones():
    """Normals + VFH on the helper thread (concurrent=True, the default) give exactly the serial results,
    and ESF's errors still come first."""
    from semslam.descriptors import compute_esf, compute_vfh, estimate_normals
    from semslam.errors import DescriptorError
    from semslam.recognition import compute_view_descriptors
    from semslam.segmentation.voxel import voxel_downsample

    views, _ = synthetic_shape_views(1, n_points=300, seed=7)
    clouds = [v[2] for v in views[:2]]

    def run(concurrent):
        return [compute_view_descriptors(c, normal_radius_m=0.015, esf_n_samples=1000, voxel_leaf_m=0.005, seed=i,
                                         concurrent=concurrent)
                for i, c in enumerate(clouds)]

    serial = run(False)
    # the serial path is the plain composition of the public descriptor functions
    pts = voxel_downsample(clouds[0].points_xyz_m, 0.005)
    np.testing.assert_array_equal(serial[0].esf, compute_esf(pts, n_samples=1000, seed=0))
    nrm = estimate_normals(pts, radius_m=0.015, viewpoint_xyz_m=clouds[0].viewpoint_xyz_m).normals_xyz
    ok = np.isfinite(nrm).all(axis=1)
    np.testing.assert_array_equal(serial[0].vfh, compute_vfh(pts[ok], nrm[ok], viewpoint_xyz_m=clouds[0].viewpoint_xyz_m)
                                  .astype(np.float32))
    for _ in range(2):
        for a, b in zip(run(True), serial):
            np.testing.assert_array_equal(a.esf, b.esf)
            np.testing.assert_array_equal(a.vfh, b.vfh)
    line = PointCloud(np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)])  # both fail: ESF's error wins
    with pytest.raises(DescriptorError, match="must span a surface"):
        compute_view_descriptors(line, esf_n_samples=100)


def test_crafted_database_files_are_refused_before_any_allocation(tmp_path):
    """An .npy given as a database, a .npy entry declaring 10^9 rows (numpy would allocate terabytes), a zip
    bomb past the size cap, deep JSON metadata and parameters of the wrong type: each a DatabaseError naming the
    file, at once."""
    import io as _io
    import json as _json
    import zipfile as _zip

    from semslam.recognition import storage as D

    npy = tmp_path / "views.npy"
    np.save(npy, np.zeros((3, 3)))
    with pytest.raises(DatabaseError, match="views.npy.*not a readable zip archive"):
        load_database(npy)

    def npz_with(entries: dict) -> Path:
        path = tmp_path / "crafted.npz"
        with _zip.ZipFile(path, "w") as zf:
            for name, data in entries.items():
                zf.writestr(name, data)
        return path

    header = _io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**9, 3)})
    with pytest.raises(DatabaseError, match=r"crafted.npz.*'points_xyz_m.npy' declares 24000000000 bytes"):
        load_database(npz_with({"points_xyz_m.npy": header.getvalue() + b"\0" * 64}))
    deep = "[" * 100000 + "]" * 100000
    buf = _io.BytesIO()
    np.save(buf, np.array(deep))
    with pytest.raises(DatabaseError, match="crafted.npz"):
        load_database(npz_with({"meta.npy": buf.getvalue()}))
    old = D.MAX_DECOMPRESSED_BYTES
    try:
        D.MAX_DECOMPRESSED_BYTES = 1000
        with pytest.raises(DatabaseError, match="crafted.npz' would decompress to 5000 bytes"):
            load_database(npz_with({"a.bin": b"\0" * 5000}))
    finally:
        D.MAX_DECOMPRESSED_BYTES = old
    views, classes = synthetic_shape_views(2, n_points=150, seed=1)
    good = save_database(build_database(views, classes, seed=0, esf_n_samples=500), tmp_path / "good.npz")
    with np.load(good, allow_pickle=False) as npz:
        entries = {k: npz[k] for k in npz.files}
    meta = _json.loads(str(entries["meta"][()]))
    meta["params"] = ["not", "a", "table"]
    entries["meta"] = np.array(_json.dumps(meta))
    np.savez(tmp_path / "params.npz", **entries)
    with pytest.raises(DatabaseError, match="params.npz' has invalid descriptor parameters"):
        load_database(tmp_path / "params.npz", verify=False)
