"""PCD reading/writing against PCL: its real scans, golden files written by PCL 1.13, and pcl_ref live."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semslam.cloud import PointCloud
from semslam.errors import PcdError
from semslam.io import read_point_cloud, write_point_cloud
from semslam.io.pcd import PcdData, read_pcd, write_pcd

ENCODINGS = ("ascii", "binary", "binary_compressed")
IO = Path(__file__).resolve().parents[1] / "data" / "io"

# (file, width, height, points, NaN points, encoding, fields) as PCL 1.13 reports them (shared README, pcl_ref read)
REAL = [
    (
        "table_scene_mug_stereo_textured.pcd",
        640,
        480,
        307200,
        97920,
        "binary_compressed",
        ["x", "y", "z", "rgba"],
    ),
    (
        "milk_cartoon_all_small_clorox.pcd",
        640,
        480,
        307200,
        65793,
        "binary_compressed",
        ["x", "y", "z", "rgba"],
    ),
    ("milk.pcd", 13704, 1, 13704, 0, "binary_compressed", ["x", "y", "z"]),
    (
        "bun0.pcd",
        397,
        1,
        397,
        0,
        "ascii",
        ["x", "y", "z", "normal_x", "normal_y", "normal_z", "curvature"],
    ),
    ("bun4.pcd", 361, 1, 361, 0, "ascii", ["x", "y", "z"]),
    (
        "sac_plane_test.pcd",
        3283,
        1,
        3283,
        0,
        "ascii",
        ["x", "y", "z", "normal_x", "normal_y", "normal_z", "curvature"],
    ),
    (
        "chef.pcd",
        5092,
        1,
        5092,
        0,
        "binary_compressed",
        ["x", "y", "z", "normal_x", "normal_y", "normal_z"],
    ),
    ("rs1.pcd", 289541, 1, 289541, 0, "binary_compressed", ["x", "y", "z"]),
]


def assert_same_fields(a: PcdData, b: PcdData) -> None:
    """Bit-exact equality of every field (dtype, shape and bits; a float ``rgb`` may come back as its uint32 bits)."""
    assert list(a.fields) == list(b.fields)
    for name, x in a.fields.items():
        y = b.fields[name]
        if name == "rgb" and x.dtype != y.dtype:
            y = y.view(x.dtype)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        if (
            x.dtype.kind == "f"
        ):  # NaN payloads are not kept by ascii: compare NaN positions, bits elsewhere
            nan = np.isnan(x)
            assert np.array_equal(nan, np.isnan(y)), name
            assert np.array_equal(x[~nan].view(np.uint8), y[~nan].view(np.uint8)), name
        else:
            assert np.array_equal(x, y), name


# ------------------------------------------------------------------------------------------- real scans


@pytest.mark.parametrize(
    "name,width,height,points,nans,encoding,fields", REAL, ids=[r[0] for r in REAL]
)
def test_real_scans_match_pcl_counts(
    real_data, name, width, height, points, nans, encoding, fields
):
    data = read_pcd(real_data / name)
    assert (data.width, data.height, data.n_points, data.n_nan) == (width, height, points, nans)
    assert data.encoding == encoding and list(data.fields) == fields
    assert all(len(v) == points for v in data.fields.values())
    cloud = read_point_cloud(real_data / name)
    assert cloud.n_points == points - nans
    assert np.isfinite(cloud.points_xyz_m).all()
    assert cloud.has_normals == ("normal_x" in fields)


def test_real_scan_values_and_viewpoint(real_data):
    data = read_pcd(real_data / "bun0.pcd")
    # first data line of bun0.pcd, parsed as float32 like PCL's reader
    first = np.array(
        [0.0054215998, 0.11349, 0.040748999, -0.16884723, -0.45159745, -0.87609947, 0.0030943851],
        dtype=np.float32,
    )
    got = np.array([data.fields[k][0] for k in data.fields])
    assert np.array_equal(got, first)
    mug = read_pcd(real_data / "table_scene_mug_stereo_textured.pcd")
    assert np.array_equal(mug.viewpoint, [0, 0, 0, 0, 1, 0, 0])
    assert mug.fields["rgba"].dtype == np.uint32
    # organised: the NaN mask is laid out row by row (HEIGHT rows of WIDTH)
    assert mug.valid_mask.reshape(480, 640).sum() == 307200 - 97920
    cloud = mug.to_point_cloud()
    assert np.array_equal(cloud.fields["rgba"], mug.fields["rgba"][mug.valid_mask])
    assert np.array_equal(
        cloud.points_xyz_m[:, 0], mug.fields["x"][mug.valid_mask].astype(np.float64)
    )
    with pytest.raises(PcdError, match="97920 point"):
        mug.to_point_cloud(drop_nan=False)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_real_scan_round_trip_bit_exact(real_data, tmp_path, encoding):
    src = read_pcd(real_data / "milk_cartoon_all_small_clorox.pcd")
    rows = 480
    if (
        encoding == "ascii"
    ):  # ascii of 307,200 points takes seconds: rows 200-239 of the scan (with NaNs)
        rows = 40
        src = PcdData(
            {k: v[200 * 640 : 240 * 640] for k, v in src.fields.items()}, 640, rows, src.viewpoint
        )
    nans = 65793 if rows == 480 else src.n_nan
    assert 0 < nans < 640 * rows
    out = tmp_path / "out.pcd"
    write_pcd(out, src, encoding=encoding)
    back = read_pcd(out)
    assert (back.width, back.height, back.n_nan) == (640, rows, nans)
    assert np.array_equal(back.viewpoint, src.viewpoint)
    assert_same_fields(src, back)


# ------------------------------------------------------------------------------------- golden PCL files


@pytest.mark.parametrize("name", ["fields", "vfh", "esf"])
@pytest.mark.parametrize("encoding", ENCODINGS)
def test_reads_pcl_written_golden_files(name, encoding):
    expected = np.load(IO / "expected.npz")
    data = read_pcd(IO / f"pcl_{name}_{encoding}.pcd")
    assert data.encoding == encoding
    keys = [k.split("/", 1)[1] for k in expected.files if k.startswith(name + "/")]
    assert list(data.fields) == keys
    for key in keys:
        want, got = expected[f"{name}/{key}"], data.fields[key]
        assert got.shape == want.shape, key
        if key == "rgb" and encoding == "ascii":
            # PCL writes a float rgb as the integer of its bits, TYPE U: the bits survive
            assert got.dtype == np.uint32
            got = got.view(np.float32)
        assert got.dtype == want.dtype, key
        if encoding == "ascii" and want.dtype.kind == "f":
            # PCL's ascii writer keeps 8 significant digits: half a unit of the 8th digit (5e-8) plus float32 rounding
            rtol = 1.2e-7 if want.dtype == np.float32 else 5e-8
            np.testing.assert_allclose(got, want, rtol=rtol, atol=0, equal_nan=True, err_msg=key)
        else:
            nan = np.isnan(want) if want.dtype.kind == "f" else np.zeros(want.shape, bool)
            assert np.array_equal(got[~nan].view(np.uint8), want[~nan].view(np.uint8)), key
    if name == "fields":
        assert (data.width, data.height, data.n_nan) == (4, 3, 2)
        assert data.fields["hist"].shape == (12, 5)
    if name == "vfh":
        assert data.fields["vfh"].shape == (2, 308)
    if name == "esf":
        assert data.fields["esf"].shape == (1, 640)


def test_our_source_files_match_pcl_binary_exactly():
    for name in ("fields", "vfh", "esf"):
        ours, pcl = read_pcd(IO / f"src_{name}.pcd"), read_pcd(IO / f"pcl_{name}_binary.pcd")
        assert_same_fields(ours, pcl)


def test_padding_fields_are_skipped():
    data = read_pcd(IO / "pad_binary.pcd")
    assert [f.name for f in data.file_fields] == ["x", "_", "y", "z", "_"]
    assert list(data.fields) == ["x", "y", "z"]
    assert np.array_equal(data.fields["x"], np.float32([0.25, 1.25, 2.25]))
    assert np.array_equal(data.fields["y"], np.float32([0, 2, 4]))
    assert np.array_equal(data.fields["z"], np.float32([0, -1, -2]))


# ------------------------------------------------------------------------------------------- round trips

_DTYPES = ["<f4", "<f8", "i1", "<i2", "<i4", "<i8", "u1", "<u2", "<u4", "<u8"]


@st.composite
def pcd_data(draw):
    n = draw(st.integers(0, 6))
    height = draw(st.sampled_from([1, 2])) if n % 2 == 0 and n else 1
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    fields = {}
    for i in range(draw(st.integers(1, 4))):
        dt = np.dtype(draw(st.sampled_from(_DTYPES)))
        count = draw(st.sampled_from([1, 1, 3]))
        shape = (n,) if count == 1 else (n, count)
        arr = (
            rng.integers(0, 256, (n * count * dt.itemsize,), dtype=np.uint8).view(dt).reshape(shape)
        )
        if dt.kind == "f":  # random bit patterns, with the NaNs made standard (ascii writes 'nan')
            arr = np.where(np.isnan(arr), np.array(np.nan, dt), arr)
        fields[f"f{i}"] = arr
    if draw(st.booleans()):
        fields["rgb"] = rng.integers(0, 2**32, n, dtype=np.uint32).view(np.float32)
    return PcdData(
        fields,
        width=n // height,
        height=height,
        viewpoint=np.array([0.5, -1.0, 2.0, 0.0, 0.0, 0.0, 1.0]),
    )


@settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(data=pcd_data(), first=st.sampled_from(ENCODINGS), second=st.sampled_from(ENCODINGS))
def test_round_trip_any_fields_bit_exact(tmp_path, data, first, second):
    p1, p2 = tmp_path / "a.pcd", tmp_path / "b.pcd"
    write_pcd(p1, data, encoding=first)
    once = read_pcd(p1)
    write_pcd(p2, once, encoding=second)
    twice = read_pcd(p2)
    for got in (once, twice):
        assert (got.width, got.height) == (data.width, data.height)
        assert np.array_equal(got.viewpoint, data.viewpoint)
        assert_same_fields(data, got)


def test_point_cloud_mapping_and_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    n = 50
    cloud = PointCloud(
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.uniform(0, 10, n).astype(np.float32),
        np.array([0.5, 0.25, -1.0]),
        "scanner",
        {
            "rgba": rng.integers(0, 2**32, n, dtype=np.uint32),
            "vfh": rng.uniform(size=(n, 308)).astype(np.float32),
        },
    )
    for enc in ENCODINGS:
        path = tmp_path / f"c_{enc}.pcd"
        write_point_cloud(path, cloud, encoding=enc)
        data = read_pcd(path)
        assert list(data.fields) == [
            "x",
            "y",
            "z",
            "normal_x",
            "normal_y",
            "normal_z",
            "intensity",
            "rgba",
            "vfh",
        ]
        assert data.fields["x"].dtype == np.float32
        back = read_point_cloud(path, frame_id="scanner")
        assert np.array_equal(back.points_xyz_m, cloud.points_xyz_m)
        assert np.array_equal(back.normals_xyz, cloud.normals_xyz)
        assert np.array_equal(back.intensity, cloud.intensity)
        assert np.array_equal(back.viewpoint_xyz_m, cloud.viewpoint_xyz_m)
        assert back.frame_id == "scanner"
        assert set(back.fields) == {"rgba", "vfh"}
        assert np.array_equal(back.fields["vfh"], cloud.fields["vfh"])
        assert back.fields["rgba"].dtype == np.uint32


def test_float64_coordinates(tmp_path):
    pts = np.array([[0.1, 1e-12, 123456.789012345]])
    cloud = PointCloud(pts)
    write_point_cloud(tmp_path / "d.pcd", cloud, coords_dtype="float64")
    assert np.array_equal(read_point_cloud(tmp_path / "d.pcd").points_xyz_m, pts)
    write_point_cloud(tmp_path / "f.pcd", cloud)  # float32, PCL's type
    assert np.array_equal(read_point_cloud(tmp_path / "f.pcd").points_xyz_m, pts.astype(np.float32))
    with pytest.raises(PcdError, match="float32 range"):
        write_point_cloud(tmp_path / "g.pcd", PointCloud(np.array([[1e39, 0, 0]])))


def test_nan_normals_kept(tmp_path):
    normals = np.array([[0, 0, 1.0], [np.nan] * 3])
    write_point_cloud(tmp_path / "n.pcd", PointCloud(np.zeros((2, 3)), normals), encoding="ascii")
    back = read_point_cloud(tmp_path / "n.pcd")
    assert np.array_equal(back.normals_xyz, normals, equal_nan=True)


def test_empty_cloud(tmp_path):
    for enc in ENCODINGS:
        write_point_cloud(tmp_path / "e.pcd", PointCloud(np.zeros((0, 3))), encoding=enc)
        data = read_pcd(tmp_path / "e.pcd")
        assert data.n_points == 0 and data.fields["x"].shape == (0,)
        assert read_point_cloud(tmp_path / "e.pcd").n_points == 0


# ---------------------------------------------------------------------------------------- atomic writes


def test_failed_write_keeps_old_file(tmp_path, monkeypatch):
    import contextlib

    import semslam.io.pcd as pcd_mod

    path = tmp_path / "keep.pcd"
    write_point_cloud(path, PointCloud(np.ones((3, 3))))
    before = path.read_bytes()
    real_open = pcd_mod.atomic_open

    @contextlib.contextmanager
    def failing_open(p, mode="wb"):
        """The real atomic_open, whose file fails on the second write (the body, after the header)."""
        with real_open(p, mode) as fh:

            class HalfFile:
                calls = 0

                def write(self, chunk):
                    HalfFile.calls += 1
                    if HalfFile.calls == 2:
                        raise OSError(5, "Input/output error")
                    return fh.write(chunk)

            yield HalfFile()

    monkeypatch.setattr(pcd_mod, "atomic_open", failing_open)
    with pytest.raises(PcdError, match="keep.pcd.*Input/output error"):
        write_point_cloud(path, PointCloud(np.zeros((5, 3))))
    with pytest.raises(PcdError, match="new.pcd"):
        write_point_cloud(tmp_path / "new.pcd", PointCloud(np.zeros((5, 3))))
    assert path.read_bytes() == before  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "keep.pcd"
    ]  # no new file, no temporary left


# ------------------------------------------------------------------------------------------ bad input

GOOD_HEAD = (
    "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n"
)


def _bad_cases(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    good = np.arange(6, dtype=np.float32).tobytes()
    cases = {
        "empty": (b"", "empty"),
        "no_data_line": (GOOD_HEAD.encode(), "no DATA line"),
        "truncated_binary": ((GOOD_HEAD + "DATA binary\n").encode() + good[:-3], "truncated"),
        "points_lie": (
            GOOD_HEAD.replace("POINTS 2", "POINTS 3").encode() + b"DATA binary\n" + good,
            "POINTS",
        ),
        "width_lie_binary": (
            GOOD_HEAD.replace("WIDTH 2", "WIDTH 5").replace("POINTS 2", "POINTS 5").encode()
            + b"DATA binary\n"
            + good,
            "truncated",
        ),
        "size_mismatch": (
            GOOD_HEAD.replace("SIZE 4 4 4", "SIZE 4 4").encode() + b"DATA binary\n" + good,
            "SIZE",
        ),
        "unknown_type": (
            GOOD_HEAD.replace("TYPE F F F", "TYPE F F Q").encode() + b"DATA binary\n" + good,
            "TYPE Q",
        ),
        "float_size_2": (
            GOOD_HEAD.replace("SIZE 4 4 4", "SIZE 4 4 2").encode() + b"DATA binary\n" + good,
            "SIZE 2",
        ),
        "bad_encoding": ((GOOD_HEAD + "DATA zip\n").encode(), "DATA must be"),
        "non_utf8": (
            GOOD_HEAD.replace("FIELDS x", "FIELDS \xe9").encode("latin-1")
            + b"DATA binary\n"
            + good,
            "UTF-8",
        ),
        "ascii_short_line": ((GOOD_HEAD + "DATA ascii\n1 2 3\n4 5\n").encode(), "point 1"),
        "ascii_missing_line": ((GOOD_HEAD + "DATA ascii\n1 2 3\n").encode(), "1 non-empty line"),
        "ascii_not_number": (
            (GOOD_HEAD + "DATA ascii\n1 2 3\n4 five 6\n").encode(),
            "point 1, field 'y'",
        ),
        "ascii_int_range": (
            (
                GOOD_HEAD.replace("TYPE F F F", "TYPE F F U").replace("SIZE 4 4 4", "SIZE 4 4 1")
                + "DATA ascii\n1 2 3\n4 5 300\n"
            ).encode(),
            "outside",
        ),
        "ascii_int_not_number": (
            (
                GOOD_HEAD.replace("TYPE F F F", "TYPE F F I") + "DATA ascii\n1 2 3\n4 5 6.5\n"
            ).encode(),
            "not a valid number",
        ),
        "compressed_no_sizes": (
            (GOOD_HEAD + "DATA binary_compressed\n").encode() + b"\x01\x00",
            "size block",
        ),
        "compressed_wrong_size": (
            (GOOD_HEAD + "DATA binary_compressed\n").encode()
            + np.uint32([10, 99]).tobytes()
            + b"x" * 10,
            "uncompressed",
        ),
        "compressed_truncated": (
            (GOOD_HEAD + "DATA binary_compressed\n").encode()
            + np.uint32([100, 24]).tobytes()
            + b"x" * 10,
            "truncated",
        ),
        "compressed_corrupt": (
            (GOOD_HEAD + "DATA binary_compressed\n").encode()
            + np.uint32([4, 24]).tobytes()
            + b"\xff\xff\xff\xff",
            "LZF",
        ),
        "duplicate_field": (
            GOOD_HEAD.replace("FIELDS x y z", "FIELDS x y x").encode() + b"DATA binary\n" + good,
            "twice",
        ),
        "bad_viewpoint": (
            (GOOD_HEAD + "VIEWPOINT 0 0 0 1 0 0\nDATA binary\n").encode() + good,
            "VIEWPOINT",
        ),
        "unknown_line": (
            (GOOD_HEAD + "COLOR red\nDATA binary\n").encode() + good,
            "unknown header line",
        ),
    }
    out = {}
    for name, (content, message) in cases.items():
        path = tmp_path / f"{name}.pcd"
        path.write_bytes(content)
        out[name] = (path, message)
    return out


def test_bad_files_raise_pcd_error_naming_file(tmp_path):
    for name, (path, message) in _bad_cases(tmp_path).items():
        with pytest.raises(PcdError) as info:
            read_pcd(path)
        assert path.name in str(info.value), name
        assert message in str(info.value), (name, str(info.value))


def test_corrupted_lzf_block_of_a_real_file(tmp_path):
    src = tmp_path / "ok.pcd"
    write_pcd(src, read_pcd(IO / "src_fields.pcd"), encoding="binary_compressed")
    raw = bytearray(src.read_bytes())
    start = raw.index(b"DATA binary_compressed\n") + len("DATA binary_compressed\n") + 8
    raw[start] = 0xFF  # a back-reference before the start of the output
    bad = tmp_path / "bad.pcd"
    bad.write_bytes(bytes(raw))
    with pytest.raises(PcdError, match="bad.pcd.*LZF"):
        read_pcd(bad)


def test_missing_directory_and_suffix(tmp_path):
    with pytest.raises(PcdError, match="nope.pcd.*no such file"):
        read_point_cloud(tmp_path / "nope.pcd")
    (tmp_path / "dir.pcd").mkdir()
    with pytest.raises(PcdError, match="dir.pcd.*directory"):
        read_point_cloud(tmp_path / "dir.pcd")
    with pytest.raises(PcdError, match="dir.pcd.*directory"):
        write_point_cloud(tmp_path / "dir.pcd", PointCloud(np.zeros((1, 3))))
    with pytest.raises(PcdError, match="scan.xyz.*'.xyz'"):
        read_point_cloud(tmp_path / "scan.xyz")
    with pytest.raises(PcdError, match="scan.txt"):
        write_point_cloud(tmp_path / "scan.txt", PointCloud(np.zeros((1, 3))))
    with pytest.raises(PcdError, match="encoding"):
        write_point_cloud(tmp_path / "a.pcd", PointCloud(np.zeros((1, 3))), encoding="lz4")


def test_not_a_point_cloud(tmp_path):
    data = read_pcd(IO / "pcl_vfh_binary.pcd")
    with pytest.raises(PcdError, match="no scalar field.*x, y, z"):
        data.to_point_cloud()


def test_bad_in_memory_data():
    with pytest.raises(PcdError, match="'x' must have 4 rows"):
        PcdData({"x": np.zeros(3, np.float32)}, width=2, height=2)
    with pytest.raises(PcdError, match="dtype complex128"):
        PcdData({"c": np.zeros(2, complex)}, width=2)
    with pytest.raises(PcdError, match="field names"):
        PcdData({"a b": np.zeros(2, np.float32)}, width=2)


# ------------------------------------------------------------------------------------- PCL reads ours


@pytest.mark.pcl
@pytest.mark.parametrize("encoding", ENCODINGS)
def test_pcl_reads_what_we_write(pcl_ref, tmp_path, encoding):
    src = read_pcd(IO / "src_fields.pcd")
    ours = tmp_path / f"ours_{encoding}.pcd"
    write_pcd(ours, src, encoding=encoding)
    res = json.loads(
        subprocess.run(
            [pcl_ref, "read", str(ours)], check=True, capture_output=True, text=True
        ).stdout.splitlines()[0]
    )
    assert (res["width"], res["height"], res["points"], res["nan_points"]) == (4, 3, 12, 2)
    # PCL rewrites it in binary: every field must come back bit-exact
    back = tmp_path / "pcl.pcd"
    subprocess.run([pcl_ref, "convert", str(ours), str(back), "1"], check=True, capture_output=True)
    assert_same_fields(src, read_pcd(back))
