"""PointCloud2 decoding: every layout round-trips through encode_pointcloud2, lying sizes raise BagError."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semslam.cloud import PointCloud
from semslam.errors import BagError, InputError
from semslam.io.ros import decode_pointcloud2, encode_pointcloud2

STAMP_NS = 1_700_000_123_456_789_000


def _cloud(n: int = 24, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-20, 20, (n, 3)), rng.uniform(0, 255, n).round(), np.sort(rng.uniform(0, 0.1, n))


LAYOUTS = {
    "default": {},
    "float64": {"coords_dtype": "float64"},
    "big_endian": {"big_endian": True},
    "big_endian_float64": {"big_endian": True, "coords_dtype": "float64"},
    "padding": {"field_gap_bytes": 3, "point_padding_bytes": 5, "row_padding_bytes": 7},
    "organised": {"height": 4, "row_padding_bytes": 6},
    "field_order": {"field_order": ["t", "intensity", "z", "x", "y"]},
    "everything": {"height": 3, "big_endian": True, "coords_dtype": "float64", "field_gap_bytes": 1,
                   "point_padding_bytes": 2, "row_padding_bytes": 3, "field_order": ["z", "t", "y", "intensity", "x"]},
}


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_round_trip_layouts(name: str) -> None:
    pts, inten, t = _cloud()
    opts = LAYOUTS[name]
    msg = encode_pointcloud2(pts, intensity=inten, time_offset_s=t, stamp_ns=STAMP_NS, frame_id="os_lidar", **opts)
    if "padding" in name or name == "everything":
        assert msg.point_step > 2 * 4 + (8 if opts.get("coords_dtype") == "float64" else 4) * 3
        assert msg.row_step > msg.point_step * msg.width
    d = decode_pointcloud2(msg, source="test")
    tol = 0 if opts.get("coords_dtype") == "float64" else 1e-5 * 20
    np.testing.assert_allclose(d.points_xyz_m, pts, atol=tol, rtol=0)
    assert d.points_xyz_m.dtype == np.float64 and d.points_xyz_m.shape == (24, 3)
    np.testing.assert_array_equal(d.intensity, inten)
    np.testing.assert_allclose(d.time_offset_s, t, atol=1e-9)  # uint32 ns: rounded to 1 ns
    assert d.time_field == "t" and d.frame_id == "os_lidar" and d.n_dropped == 0
    assert d.stamp_ns == STAMP_NS and d.stamp_s == pytest.approx(STAMP_NS * 1e-9)
    assert d.valid_mask.shape == (opts.get("height", 1), 24 // opts.get("height", 1)) and d.valid_mask.all()


def test_time_fields_float_seconds_and_absolute() -> None:
    pts, _, t = _cloud()
    msg = encode_pointcloud2(pts, time_offset_s=t, time_field="time", time_encoding="float32_s")
    d = decode_pointcloud2(msg)  # Velodyne: float32 seconds relative to the stamp
    assert d.time_field == "time" and d.time_offset_s.dtype == np.float64
    np.testing.assert_allclose(d.time_offset_s, t, atol=1e-7)
    stamp_s = STAMP_NS * 1e-9
    msg = encode_pointcloud2(pts, time_offset_s=stamp_s + t, time_field="timestamp", time_encoding="float64_s",
                             stamp_ns=STAMP_NS)  # Hesai: absolute float64 seconds
    np.testing.assert_allclose(decode_pointcloud2(msg).time_offset_s, t, atol=1e-6)
    msg = encode_pointcloud2(pts, time_offset_s=(STAMP_NS + t * 1e9), time_field="timestamp",
                             time_encoding="float64_s", stamp_ns=STAMP_NS)  # Livox: absolute float64 ns
    np.testing.assert_allclose(decode_pointcloud2(msg).time_offset_s, t, atol=1e-6)
    for name in ("time_offset", "offset_time"):
        msg = encode_pointcloud2(pts, time_offset_s=t, time_field=name, time_encoding="uint32_ns")
        d = decode_pointcloud2(msg)
        assert d.time_field == name
        np.testing.assert_allclose(d.time_offset_s, t, atol=1e-9)


def test_non_finite_points_dropped_with_mask() -> None:
    pts, inten, t = _cloud(12)
    pts[[1, 6, 7]] = [[np.nan, 0, 0], [0, np.inf, 0], [0, 0, -np.inf]]
    msg = encode_pointcloud2(pts, intensity=inten, time_offset_s=t, height=3)
    assert msg.is_dense is False
    d = decode_pointcloud2(msg)
    keep = np.ones(12, bool)
    keep[[1, 6, 7]] = False
    assert d.n_dropped == 3 and d.n_points == 9
    np.testing.assert_array_equal(d.valid_mask, keep.reshape(3, 4))
    np.testing.assert_allclose(d.points_xyz_m, pts[keep], atol=1e-4)
    np.testing.assert_array_equal(d.intensity, inten[keep])
    np.testing.assert_allclose(d.time_offset_s, t[keep], atol=1e-9)
    # is_dense = True is not trusted
    msg.is_dense = True
    assert decode_pointcloud2(msg).n_dropped == 3


@pytest.mark.parametrize("time_encoding", ["uint32_ns", "float32_s"])
@pytest.mark.parametrize("coords_dtype", ["float32", "float64"])
def test_native_kernel_decodes_like_swapped_byte_order(time_encoding: str, coords_dtype: str) -> None:
    """Native-endian fields go through the one-pass kernel, swapped ones through numpy: the same cloud either way,
    non-finite points, rows and row padding included."""
    pts, inten, t = _cloud(60, seed=11)
    pts[[0, 7, 33, 59]] = [[np.nan, 0, 0], [0, np.inf, 0], [0, 0, -np.inf], [np.nan] * 3]
    kw = dict(intensity=inten, time_offset_s=t, time_encoding=time_encoding, height=5, row_padding_bytes=4,
              coords_dtype=coords_dtype)
    native = decode_pointcloud2(encode_pointcloud2(pts, big_endian=False, **kw))
    swapped = decode_pointcloud2(encode_pointcloud2(pts, big_endian=True, **kw))
    assert native.n_dropped == swapped.n_dropped == 4
    for name in ("points_xyz_m", "intensity", "time_offset_s", "valid_mask"):
        got, want = getattr(native, name), getattr(swapped, name)
        assert got.dtype == want.dtype, name
        np.testing.assert_array_equal(got, want, err_msg=name)


def _manual(fields: list[tuple[str, int, str, int]], values: dict[str, np.ndarray], n: int, *, point_step: int,
            big: bool = False, height: int = 1) -> NS:
    """A duck-typed PointCloud2 with fields (name, offset, numpy code, count)."""
    bo = ">" if big else "<"
    dt = np.dtype({"names": [f[0] for f in fields], "offsets": [f[1] for f in fields], "itemsize": point_step,
                   "formats": [np.dtype((bo + f[2], (f[3],))) if f[3] > 1 else np.dtype(bo + f[2]) for f in fields]})
    arr = np.zeros(n, dt)
    for name, v in values.items():
        arr[name] = v
    codes = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
    header = NS(stamp=NS(sec=10, nanosec=500_000_000), frame_id="velodyne")
    return NS(header=header, height=height, width=n // height, is_bigendian=big, point_step=point_step,
              row_step=point_step * (n // height), is_dense=True, data=arr.tobytes(),
              fields=[NS(name=f[0], offset=f[1], datatype=codes[f[2]], count=f[3]) for f in fields])


@pytest.mark.parametrize("big", [False, True])
def test_all_datatypes_count_and_extra_fields(big: bool) -> None:
    n = 6
    rng = np.random.default_rng(5)
    xyz = rng.normal(size=(n, 3))
    fields = [("x", 0, "f4", 1), ("y", 4, "f4", 1), ("z", 8, "f4", 1), ("a_i1", 12, "i1", 1), ("a_u1", 13, "u1", 1),
              ("a_i2", 14, "i2", 1), ("a_u2", 16, "u2", 1), ("a_i4", 20, "i4", 1), ("a_u4", 24, "u4", 1),
              ("a_f8", 32, "f8", 1), ("normal", 40, "f4", 3), ("intensity", 52, "u2", 2), ("ring", 58, "u2", 1)]
    values = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "a_i1": -np.arange(n), "a_u1": 250 + np.arange(n),
              "a_i2": -30000 + np.arange(n), "a_u2": 65000 + np.arange(n), "a_i4": -(2**31) + np.arange(n),
              "a_u4": 2**32 - 1 - np.arange(n), "a_f8": np.pi * np.arange(n), "normal": rng.normal(size=(n, 3)),
              "intensity": np.stack([np.arange(n) * 100, np.ones(n)], axis=1), "ring": np.arange(n) % 2}
    d = decode_pointcloud2(_manual(fields, values, n, point_step=64, big=big, height=2))
    np.testing.assert_allclose(d.points_xyz_m, xyz, rtol=1e-6)
    np.testing.assert_array_equal(d.intensity, np.arange(n) * 100.0)  # count 2: first element
    assert d.time_offset_s is None and d.time_field is None
    assert d.stamp_s == pytest.approx(10.5) and d.frame_id == "velodyne"
    for name, code, _, count in [(f[0], f[2], f[1], f[3]) for f in fields[3:-2]]:
        got = d.fields[name]
        assert got.dtype == np.dtype(code) and got.dtype.isnative, name
        np.testing.assert_array_equal(got, np.asarray(values[name]).astype(code).reshape(got.shape))
    assert d.fields["normal"].shape == (n, 3)
    cloud = d.to_point_cloud()
    assert isinstance(cloud, PointCloud) and cloud.frame_id == "velodyne" and len(cloud) == n
    assert set(cloud.fields) == {f[0] for f in fields[3:]} - {"intensity"}
    assert d.to_point_cloud(frame_id="scanner").frame_id == "scanner"


def test_velodyne_like_layout_and_point_cloud() -> None:
    """x, y, z at 0/4/8, intensity at 16, 12 bytes of padding: the real bag's layout."""
    pts, inten, t = _cloud(10)
    fields = [("x", 0, "f4", 1), ("y", 4, "f4", 1), ("z", 8, "f4", 1), ("intensity", 16, "f4", 1),
              ("time", 20, "f4", 1)]
    msg = _manual(fields, {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "intensity": inten, "time": t}, 10,
                  point_step=32)
    d = decode_pointcloud2(msg)
    np.testing.assert_allclose(d.points_xyz_m, pts, atol=1e-5)
    cloud = d.to_point_cloud()
    np.testing.assert_allclose(cloud.fields["time_offset_s"], t, atol=1e-7)
    np.testing.assert_array_equal(cloud.intensity, inten)
    msg.header.frame_id = ""
    assert decode_pointcloud2(msg).to_point_cloud().frame_id == "sensor"


def _valid_msg() -> NS:
    pts, inten, _ = _cloud(8)
    return _manual([("x", 0, "f4", 1), ("y", 4, "f4", 1), ("z", 8, "f4", 1), ("intensity", 12, "f4", 1)],
                   {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "intensity": inten}, 8, point_step=20, height=2)


LIES = {  # case: (mutation, what the message must say)
    "short data": (lambda m: setattr(m, "data", m.data[:-1]),
                   r"data must hold row_step\*height = 80\*2 = 160 bytes\. Got 159"),
    "row_step": (lambda m: setattr(m, "row_step", 79),
                 r"'row_step' must be >= point_step\*width = 20\*4 = 80\. Got 79"),
    "field outside": (lambda m: setattr(m.fields[3], "offset", 17),
                      r"field 'intensity' .*must end within point_step = 20\. Got end 21"),
    "count outside": (lambda m: setattr(m.fields[2], "count", 4), r"field 'z' \(offset 8, 4 x f4\).*Got end 24"),
    "point_step small": (lambda m: (setattr(m, "point_step", 12), setattr(m, "row_step", 48)),
                         r"field 'intensity'.*point_step = 12"),
    "missing z": (lambda m: m.fields.pop(2), r"must have fields x, y and z\. Got fields \['intensity', 'x', 'y'\]"),
    "unknown datatype": (lambda m: setattr(m.fields[1], "datatype", 9),
                         r"field 'y' must have a datatype in 1\.\.8 .*Got 9"),
    "datatype 0": (lambda m: setattr(m.fields[0], "datatype", 0), r"field 'x' must have a datatype in 1\.\.8 .*Got 0"),
    "absurd size": (lambda m: (setattr(m, "width", 2**31), setattr(m, "height", 2**31)),
                    r"declares width\*height = 2147483648\*2147483648 = 4611686018427387904 points "
                    r"but its data holds only 160 bytes"),
    "absurd steps": (lambda m: (setattr(m, "point_step", 2**40), setattr(m, "row_step", 2**42)),
                     r"data must hold row_step\*height"),
    "zero point_step": (lambda m: (setattr(m, "point_step", 0), setattr(m, "row_step", 0)),
                        r"'point_step' must be positive"),
    "negative": (lambda m: setattr(m, "width", -1), r"'width' must be a non-negative integer\. Got -1"),
    "not an int": (lambda m: setattr(m, "height", 2.0), r"'height' must be a non-negative integer\. Got 2\.0"),
    "no data": (lambda m: setattr(m, "data", None), r"'data' must be a byte buffer\. Got NoneType"),
    "bad stamp": (lambda m: setattr(m.header.stamp, "sec", None), r"'header\.stamp' must have integer sec and nanosec"),
}


@pytest.mark.parametrize("case", list(LIES))
def test_lying_sizes_raise_bag_error(case: str) -> None:
    msg = _valid_msg()
    decode_pointcloud2(msg)  # valid before the lie
    mutate, pattern = LIES[case]
    mutate(msg)
    with pytest.raises(BagError, match=r"^topic '/points' message 7: PointCloud2 .*" + pattern) as info:
        decode_pointcloud2(msg, source="topic '/points' message 7")
    assert "\n" not in str(info.value)


def test_empty_cloud_and_extra_data() -> None:
    d = decode_pointcloud2(encode_pointcloud2(np.zeros((0, 3)), intensity=np.zeros(0)))
    assert d.n_points == 0 and d.points_xyz_m.shape == (0, 3) and d.intensity.shape == (0,) and d.n_dropped == 0
    msg = _valid_msg()
    msg.data = msg.data + b"\x00" * 13  # trailing bytes are allowed (ignored)
    assert decode_pointcloud2(msg).n_points == 8


def test_encode_rejects_bad_options() -> None:
    with pytest.raises(InputError, match="'height' argument of encode_pointcloud2"):
        encode_pointcloud2(np.zeros((5, 3)), height=2)
    with pytest.raises(InputError, match="'coords_dtype'"):
        encode_pointcloud2(np.zeros((5, 3)), coords_dtype="float16")
    with pytest.raises(InputError, match="'field_order'"):
        encode_pointcloud2(np.zeros((5, 3)), field_order=["x", "y"])


def _check_consistent(d, msg) -> None:
    n = msg.height * msg.width
    assert d.n_points + d.n_dropped == n
    assert d.points_xyz_m.shape == (d.n_points, 3) and np.isfinite(d.points_xyz_m).all()


def test_seeded_byte_fuzz_only_bag_error() -> None:
    rng = np.random.default_rng(14)
    base = encode_pointcloud2(*_cloud(16)[:1], intensity=_cloud(16)[1], time_offset_s=_cloud(16)[2], height=2,
                              point_padding_bytes=3)
    attrs = ["height", "width", "point_step", "row_step"]
    for _ in range(400):
        msg = NS(header=base.header, height=base.height, width=base.width, point_step=base.point_step,
                 row_step=base.row_step, is_bigendian=bool(rng.integers(2)), is_dense=False,
                 fields=[NS(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in base.fields])
        data = base.data.copy()
        data[rng.integers(0, len(data), 8)] = rng.integers(0, 256, 8)
        msg.data = data[: rng.integers(0, len(data) + 1)].tobytes() if rng.random() < 0.3 else data
        for a in rng.choice(attrs, rng.integers(0, 3)):
            setattr(msg, a, int(rng.choice([0, 1, 2, 3, 7, 16, 2**31, 2**32 - 1, rng.integers(0, 400)])))
        for f in msg.fields:
            if rng.random() < 0.1:
                f.offset = int(rng.integers(0, 40))
            if rng.random() < 0.05:
                f.datatype = int(rng.integers(0, 11))
            if rng.random() < 0.05:
                f.count = int(rng.integers(0, 4))
        try:
            _check_consistent(decode_pointcloud2(msg, source="fuzz"), msg)
        except BagError as err:
            assert str(err).startswith("fuzz: PointCloud2 ")


def _size(small: int, large: int):
    return st.one_of(st.integers(0, small), st.integers(0, large))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(height=_size(4, 2**33), width=_size(8, 2**33), point_step=_size(40, 2**33), row_step=_size(200, 2**34),
       n_bytes=st.integers(0, 900), big=st.booleans(),
       fields=st.lists(st.tuples(st.sampled_from(["x", "y", "z", "t", "intensity", "ring", ""]), _size(16, 2**32),
                                 st.integers(0, 10), _size(2, 2**32)), max_size=6),
       seed=st.integers(0, 2**32 - 1))
def test_hypothesis_declared_sizes_only_bag_error(
    height, width, point_step, row_step, n_bytes, big, fields, seed
) -> None:
    data = np.random.default_rng(seed).bytes(n_bytes)
    msg = NS(header=NS(stamp=NS(sec=1, nanosec=2), frame_id="f"), height=height, width=width, point_step=point_step,
             row_step=row_step, is_bigendian=big, is_dense=False, data=data,
             fields=[NS(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields])
    try:
        d = decode_pointcloud2(msg, source="hyp")
    except BagError as err:
        assert str(err).startswith("hyp: PointCloud2 ") and "\n" not in str(err)
    else:
        assert height * width <= n_bytes
        _check_consistent(d, msg)
