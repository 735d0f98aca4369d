"""The ROS 2 mcap export (``semslam/run/export_mcap.py``): attitude interpolation, stamps, landmark markers.

Oracles: scipy's ``Slerp`` for the attitude interpolation, linear interpolation for the position, the module
docstring for the landmark markers (label 0.15 m above the landmark; valid ROS poses: unit quaternions) and the
stamp check. One tiny result (3 epochs, 1 landmark): the mcap is written and read back in well under a second."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

pytest.importorskip('rosbags', reason='the mcap export needs rosbags')

from semslam.errors import InputError  # noqa: E402
from semslam.geometry import rotation_from_rpy  # noqa: E402
from semslam.io.ros import open_bag, vectors_enu_from_ned  # noqa: E402
from semslam.run.export_mcap import _slerp_rotation, _vehicle_pose_at, write_mcap  # noqa: E402
from semslam.slam import SlamConfig, SlamResult  # noqa: E402
from semslam.slam.results import LandmarkEstimate  # noqa: E402


def _result(t0=0.0):
    k = 3
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (k, 1, 1))
    lm = LandmarkEstimate(4, "valve", np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.7]), np.diag([1e-3, 2e-3, 3e-3, 1e-4,
                                                                                         1e-4, 1e-4]), 0.0, 1.0, 3)
    return SlamResult(mode="pose", stamps_s=t0 + np.arange(k) * 0.5, position_ned_m=np.arange(3.0 * k).reshape(k, 3),
                      position_cov_m2=cov, velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(),
                      yaw_bias_rad=np.zeros(k), truth_position_ned_m=None, landmarks=[lm], update_log=[], metrics={},
                      config=SlamConfig(), attitude_rpy_rad=np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 1.0],
                                                                      [0.0, 0.1, 2.0]]))


@pytest.mark.parametrize("a", [0.0, 0.25, 0.5, 0.9, 1.0])
def test_slerp_matches_scipy(a):
    """Catches a wrong slerp weight (``sin((2 - a) theta)`` for ``sin((1 - a) theta)``): the interpolated attitude
    is scipy's spherical linear interpolation between the two rotations, at every fraction."""
    R0, R1 = rotation_from_rpy(0.1, 0.2, 1.0), rotation_from_rpy(-0.3, 0.1, 2.2)
    want = Slerp([0.0, 1.0], Rotation.from_matrix([R0, R1]))([a]).as_matrix()[0]
    np.testing.assert_allclose(_slerp_rotation(R0, R1, a), want, atol=1e-12)


def test_vehicle_pose_between_epochs_is_interpolated():
    """Catches an inverted "epochs apart" test (``not dt > 0``: every detection placed at the previous epoch's
    pose) and a wrong interpolation weight (``(1 + a) p_k``): a quarter of the way between two epochs the vehicle
    position is the linear interpolation and the attitude the slerp, as the module doc says."""
    stamps = np.array([0.0, 2.0])
    pos = np.array([[1.0, 2.0, 3.0], [5.0, -6.0, 5.0]])
    R = np.array([rotation_from_rpy(0.0, 0.0, 0.0), rotation_from_rpy(0.2, 0.0, 1.2)])
    T = _vehicle_pose_at(0.5, stamps, pos, R)
    np.testing.assert_allclose(T.translation_m, [2.0, 0.0, 3.5], atol=1e-12)
    want = Slerp(stamps, Rotation.from_matrix(R))([0.5]).as_matrix()[0]
    np.testing.assert_allclose(T.rotation, want, atol=1e-12)


def test_a_stamp_before_the_ros_epoch_is_refused(tmp_path: Path):
    """Catches a time check in seconds instead of nanoseconds (``/ 1e9`` for ``* 1e9``): a result starting at
    -0.5 s with ``time_origin_ns = 0`` would need a negative ROS time and must be refused, writing nothing; with
    the origin 1 s later it is written."""
    with pytest.raises(InputError, match="'time_origin_ns' argument of write_mcap must make every stamp >= 0"):
        write_mcap(_result(-0.5), tmp_path / "a.mcap")
    assert not (tmp_path / "a.mcap").exists()
    assert write_mcap(_result(-0.5), tmp_path / "b.mcap", time_origin_ns=10**9).is_file()


def test_landmark_label_sits_above_the_landmark_and_every_marker_pose_is_valid(tmp_path: Path):
    """Catches a label marker placed elsewhere than the documented 0.15 m above the landmark (``1.15``) or given an
    invalid orientation (the quaternion ``(1, 0, 0, 1)``, not of unit norm): in the bag, the TEXT marker is 0.15 m
    above (ENU z) the landmark's position, and every marker orientation is a unit quaternion."""
    r = _result()
    path = write_mcap(r, tmp_path / "run.mcap", smoothed=False)
    with open_bag(path) as bag:
        (m,) = [m for m in bag.messages() if m.topic == "/semslam/landmarks"]
    markers = m.msg.markers
    (text,) = [mk for mk in markers if mk.ns == "labels"]
    p = text.pose.position
    np.testing.assert_allclose([p.x, p.y, p.z], vectors_enu_from_ned(r.landmarks[0].pose_xyzrpy[:3]) + [0, 0, 0.15],
                               atol=1e-12)
    assert len(markers) == 3
    for mk in markers:
        q = mk.pose.orientation
        assert np.linalg.norm([q.x, q.y, q.z, q.w]) == pytest.approx(1.0, abs=1e-12)


def test_a_stamp_shared_by_the_last_two_epochs_gives_a_finite_pose():
    """Catches a division by a zero epoch interval (``dt >= 0`` for ``dt > 0``): with the last two epochs at the same
    stamp (and the same pose), a detection at that stamp is placed at that pose, not at NaN."""
    stamps = np.array([0.0, 1.0, 1.0])
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    R = np.array([np.eye(3), rotation_from_rpy(0.1, 0.0, 0.5), rotation_from_rpy(0.1, 0.0, 0.5)])
    with np.errstate(all="ignore"):
        T = _vehicle_pose_at(1.0, stamps, pos, R)
    np.testing.assert_allclose(T.translation_m, [1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(T.rotation, R[2], atol=1e-12)


def test_markers_have_valid_colours_and_live_for_ever(tmp_path: Path):
    """Catches colours out of ROS's [0, 1] RGBA range (a palette entry, a sphere's or a label's alpha made > 1) and
    markers that expire (``lifetime`` 1 ns instead of 0 = for ever): with one landmark of each of 10 classes (every
    palette entry used), every marker colour component is in [0, 1] and every lifetime is 0."""
    from dataclasses import replace

    r = _result()
    lm0 = r.landmarks[0]
    lms = [replace(lm0, landmark_id=j, label=f"class{j}", pose_xyzrpy=lm0.pose_xyzrpy + [j, 0, 0, 0, 0, 0])
           for j in range(10)]
    path = write_mcap(replace(r, landmarks=lms), tmp_path / "run.mcap", smoothed=False)
    with open_bag(path) as bag:
        (m,) = [m for m in bag.messages() if m.topic == "/semslam/landmarks"]
    markers = m.msg.markers
    assert len(markers) == 30
    rgba = np.array([[mk.color.r, mk.color.g, mk.color.b, mk.color.a] for mk in markers])
    assert np.all((rgba >= 0.0) & (rgba <= 1.0))
    assert len({tuple(c) for c in rgba[::3, :3]}) == 10   # one colour per class
    assert all(mk.lifetime.sec == 0 and mk.lifetime.nanosec == 0 for mk in markers)


@pytest.mark.parametrize("kind", ["file", "directory"])
def test_refused_target_names_what_it_is(tmp_path: Path, kind):
    """Catches an inverted file/directory word in the refusal of an existing non-bag target: the message says
    ``an existing file`` for a file and ``an existing directory`` for a non-empty directory that is not a bag."""
    target = tmp_path / "out"
    if kind == "file":
        target.write_text("x")
    else:
        target.mkdir()
        (target / "other.txt").write_text("x")
    with pytest.raises(InputError, match=f"an existing {kind} that is not a bag"):
        write_mcap(_result(), target)
