"""The real-valve benchmark beyond pitch 0 (issue #16: "judged on other settings of the same rig").

The dataset the shared views come from also holds settings at camera pitch 30 and 45 degrees and at other yaw
steps and distances, in another folder layout. ``benchmarks/real_valves.py`` must read them, register each pair
about the rig's vertical *as the pitched camera sees it*, and judge it against the yaw step about that vertical.
No real pitched view is available here, so pitched views are made exactly from the committed level ones: the
same points seen by a camera turned about its x axis."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.io import write_point_cloud
from semslam.registration import align_upright

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
SUBSET = Path(__file__).parents[1] / "data" / "real_valves"


def camera_pitched_down(pitch_deg: float) -> np.ndarray:
    """Columns: the pitched camera's axes in the level camera's frame (x right, y down, z forward)."""
    p = np.radians(pitch_deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), np.sin(p)], [0.0, -np.sin(p), np.cos(p)]])


def test_setting_names_of_both_layouts(rv):
    assert rv.parse_setting("pitch000_yaw-030_30cm") == (0, -30, 30)
    assert rv.parse_setting("pitch030/pitch030yaw-015/40cm") == (30, -15, 40)
    assert rv.parse_setting("pitch045/pitch045yaw030") == (45, 30, None)
    with pytest.raises(ValueError, match="pitchPPP"):
        rv.parse_setting("yaw030_30cm")


def test_up_direction_and_yaw_rotation_of_a_pitched_camera(rv):
    for sign in (1, -1):
        np.testing.assert_allclose(rv.up_camera(0, sign), [0.0, -1.0, 0.0], atol=1e-15)
    R = camera_pitched_down(30.0)  # level-frame axes of a camera looking 30 degrees down
    np.testing.assert_allclose(rv.up_camera(30, 1), R.T @ [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(rv.up_camera(30, -1), camera_pitched_down(-30.0).T @ [0.0, -1.0, 0.0], atol=1e-12)
    for step in (-45, 15, 30):
        np.testing.assert_allclose(rv.rot_about_up(np.array([0.0, -1.0, 0.0]), step), rv.rot_about_camera_vertical(step),
                                   atol=1e-12)
        # the same turn of the rig seen by the pitched camera
        np.testing.assert_allclose(rv.rot_about_up(rv.up_camera(30, 1), step),
                                   R.T @ rv.rot_about_camera_vertical(step) @ R, atol=1e-12)


def test_pairs_of_a_pitched_camera_are_registered_about_the_tilted_vertical(rv):
    """Yaw 0 and +30 views of each valve seen by a camera pitched 30 degrees down: the benchmark's pairs use
    the tilted vertical and land within 10 degrees of the step; the level camera's vertical (the old rule)
    cannot represent the rotation and misses it."""
    R = camera_pitched_down(30.0)
    views = [v for v in rv.load_views(SUBSET) if v["frame"] == "1" and v["yaw"] in (0, 30)]
    assert len(views) == 4
    pitched = []
    for v in views:
        p = v["cloud"].points_xyz_m @ R  # = (R^T x) row by row
        pitched.append({**v, "pitch": 30, "cloud": PointCloud(p)})
    rows = rv.pairs(pitched, baseline=False, signs={(v["cls"], 30): (1, "test") for v in pitched})
    assert len(rows) == 4 and all(r["pitch"] == 30 for r in rows)
    for r in rows:
        assert r["err_deg"] < 10, r
    a, b = pitched[0], pitched[1]
    assert (a["cls"], a["yaw"], b["yaw"]) == ("ball_valve", 0, 30)
    res = align_upright(a["cloud"], b["cloud"], up_source=(0, -1, 0), up_target=(0, -1, 0))
    R_est = np.asarray(res.T_target_source.matrix)[:3, :3]
    assert rv.angle_deg(R_est.T @ rv.rot_about_up(rv.up_camera(30, 1), 30)) > 10


def _plane(normal: np.ndarray, distance_m: float, rng) -> PointCloud:
    n = normal / np.linalg.norm(normal)
    u = np.cross(n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    a, b = rng.uniform(-0.15, 0.15, size=(2, 4000))
    return PointCloud(-distance_m * n + a[:, None] * u + b[:, None] * w + rng.normal(0, 5e-4, (4000, 1)) * n)


@pytest.mark.parametrize("sign", [1, -1])
def test_pitch_sign_is_measured_from_the_turning_backboard(rv, tmp_path, sign):
    """Full frames whose dominant plane (the rig's backboard) turns with the valve about the rig's vertical: the
    sign of the camera's pitch comes out of the plane normals, whichever it is; a group without full frames
    falls back to a camera looking down, and says so."""
    rng = np.random.default_rng(3)
    up = rv.up_camera(30, sign)
    view = PointCloud(rng.normal(0.0, 0.02, (300, 3)) + [0.0, 0.0, 0.3])
    for yaw in (-15, 0, 30):
        d = tmp_path / "ball_valve" / f"pitch030_yaw{yaw:03d}_30cm" / "1"
        d.mkdir(parents=True)
        write_point_cloud(d / "RANSAC.pcd", view)
        toward_camera = rv.rot_about_up(up, yaw) @ (camera_pitched_down(30.0 * sign).T @ [0.0, 0.0, -1.0])
        write_point_cloud(d / "Captured_Frame.pcd", _plane(toward_camera, 0.4, rng))
        e = tmp_path / "globe_valve" / f"pitch030_yaw{yaw:03d}_30cm" / "1"
        e.mkdir(parents=True)
        write_point_cloud(e / "RANSAC.pcd", view)
    views = rv.load_views(tmp_path)
    assert {(v["cls"], v["pitch"], v["yaw"], v["dist"]) for v in views} >= {("ball_valve", 30, -15, 30)}
    signs = rv.pitch_signs(views)
    assert signs[("ball_valve", 30)][0] == sign and signs[("ball_valve", 30)][1].startswith("measured")
    assert signs[("globe_valve", 30)] == (1, "assumed (no backboard measurement)")


def test_max_frames_keeps_the_first_frames_of_every_setting(rv):
    views = rv.load_views(SUBSET, max_frames=1)
    assert len(views) == 6 and {v["frame"] for v in views} == {"1"}


def test_frames_benchmark_reads_the_original_layout_and_sets_up_per_setting(rv, tmp_path):
    """``real_valves_frames.py --up auto``: every frame of the original dataset's deeper layout is found, keyed by
    its whole setting path, and each setting gets its camera's up (sign measured from the backboard)."""
    sys.path.insert(0, str(BENCH))
    try:
        import real_valves_frames as rvf
    finally:
        sys.path.remove(str(BENCH))
    rng = np.random.default_rng(5)
    up = rv.up_camera(45, -1)
    view = PointCloud(rng.normal(0.0, 0.02, (300, 3)) + [0.0, 0.0, 0.3])
    for yaw in (-45, 15):
        d = tmp_path / "globe_valve" / "pitch045" / f"pitch045yaw{yaw:03d}" / "40cm" / "3"
        d.mkdir(parents=True)
        write_point_cloud(d / "RANSAC.pcd", view)
        toward_camera = rv.rot_about_up(up, yaw) @ (camera_pitched_down(-45.0).T @ [0.0, 0.0, -1.0])
        write_point_cloud(d / "Captured_Frame.pcd", _plane(toward_camera, 0.4, rng))
    frames = sorted(tmp_path.glob("*/**/Captured_Frame.pcd"))
    assert [rvf.frame_key(tmp_path, f) for f in frames] == [
        ("globe_valve", "pitch045/pitch045yaw-45/40cm", "3"), ("globe_valve", "pitch045/pitch045yaw015/40cm", "3")]
    ups = rvf.setting_ups(tmp_path)
    assert set(ups) == {"pitch045/pitch045yaw-45/40cm", "pitch045/pitch045yaw015/40cm"}
    for u in ups.values():
        np.testing.assert_allclose(u, up, atol=1e-12)


def test_pairs_are_judged_against_the_measured_turns_not_the_rig_labels(rv):
    """The shared README measures the "yaw -30" settings at 14.6 (ball) and 21.7 (globe) degrees from yaw 0: a pair
    across them is judged against that turn; a setting nobody measured keeps its nominal yaw."""
    ball = {"cls": "ball_valve", "pitch": 0, "dist": 30}
    assert rv.setting_turn({**ball, "yaw": -30}) == (-14.6, True)
    assert rv.setting_turn({**ball, "yaw": 30})[0] - rv.setting_turn({**ball, "yaw": -30})[0] == pytest.approx(47.0)
    assert rv.setting_turn({"cls": "globe_valve", "pitch": 0, "dist": 30, "yaw": -30}) == (-21.7, True)
    assert rv.setting_turn({**ball, "yaw": 15, "dist": 40}) == (15.0, False)


def test_face_plane_turn_of_a_plate_turned_about_the_vertical(rv):
    rng = np.random.default_rng(3)
    plate = np.column_stack([rng.uniform(-0.03, 0.03, 500), rng.uniform(-0.03, 0.03, 500), np.zeros(500)])
    up = np.array([0.0, -1.0, 0.0])
    yaws = []
    for step in (-21.7, 0.0, 32.0):
        pts = plate @ rv.rot_about_up(up, step).T + [0.0, 0.0, 0.35]
        yaws.append(rv.face_plane_yaw_deg(pts + rng.normal(0, 1e-4, pts.shape), up))
    assert yaws[1] - yaws[0] == pytest.approx(21.7, abs=0.3)
    assert yaws[2] - yaws[1] == pytest.approx(32.0, abs=0.3)
