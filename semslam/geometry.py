"""Rigid transforms and rotation conventions.

Conventions (used everywhere in semslam):

* SI units, radians inside.
* World frame NED (x north, y east, z down); body frame x forward, y starboard, z down.
* ``T_parent_child`` is the 4x4 homogeneous matrix taking points from the child frame to the parent
  frame: ``p_parent = T_parent_child @ p_child``. Composition reads left to right:
  ``T_world_object = T_world_vehicle @ T_vehicle_scanner @ T_scanner_object``.
* Roll-pitch-yaw are intrinsic Z-Y-X (aerospace) angles: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* Quaternions are ``quat_wxyz`` (scalar first), unit norm, sign chosen with ``w >= 0``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from ._validation import as_float_array
from .errors import InputError

#: Largest deviation of ``R.T @ R`` from identity (and of det from 1) accepted as a rotation.
ORTHONORMAL_TOL = 1e-6


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """3x3 rotation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (radians)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rotations_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """Vectorised :func:`rotation_from_rpy`: ``(N, 3)`` angles to ``(N, 3, 3)`` rotations."""
    rpy = np.asarray(rpy, dtype=np.float64).reshape(-1, 3)
    cr, sr = np.cos(rpy[:, 0]), np.sin(rpy[:, 0])
    cp, sp = np.cos(rpy[:, 1]), np.sin(rpy[:, 1])
    cy, sy = np.cos(rpy[:, 2]), np.sin(rpy[:, 2])
    R = np.empty((len(rpy), 3, 3))
    R[:, 0, 0] = cy * cp
    R[:, 0, 1] = cy * sp * sr - sy * cr
    R[:, 0, 2] = cy * sp * cr + sy * sr
    R[:, 1, 0] = sy * cp
    R[:, 1, 1] = sy * sp * sr + cy * cr
    R[:, 1, 2] = sy * sp * cr - cy * sr
    R[:, 2, 0] = -sp
    R[:, 2, 1] = cp * sr
    R[:, 2, 2] = cp * cr
    return R


def rpy_from_rotation(R: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (radians) of a rotation, inverse of :func:`rotation_from_rpy`.

    Never NaN: at pitch = +-90 degrees (gimbal lock) roll is set to 0 and yaw absorbs the rotation.
    """
    R = np.asarray(R, dtype=np.float64)
    sp = float(np.clip(-R[2, 0], -1.0, 1.0))
    pitch = float(np.arcsin(sp))
    cp = np.hypot(R[0, 0], R[1, 0])
    if cp > 1e-9:
        roll = float(np.arctan2(R[2, 1], R[2, 2]))
        yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    else:  # gimbal lock: only yaw - sign(pitch) * roll is defined
        roll = 0.0
        yaw = float(np.arctan2(-R[0, 1], R[1, 1]))
        pitch = float(np.copysign(np.pi / 2, sp))
    return np.array([roll, pitch, yaw])


def wrap_angle(angle: Any) -> Any:
    """Wrap angle(s) to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def quat_wxyz_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method: stable for every
    rotation, including 180-degree turns)."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cand = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
    k = int(np.argmax(cand))
    if k == 0:
        s = 2.0 * np.sqrt(max(1.0 + tr, 0.0))
        q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        q = np.array([(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
        q = np.array([(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
        q = np.array([(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def rotation_from_quat_wxyz(quat_wxyz: Any) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z); the quaternion must have a non-zero norm and is normalised."""
    q = as_float_array("quat_wxyz", quat_wxyz, (4,), caller="rotation_from_quat_wxyz")
    n = np.linalg.norm(q)
    if n < 1e-12:
        raise InputError(
            "The 'quat_wxyz' argument of rotation_from_quat_wxyz must have a non-zero norm. Got 0 instead."
        )
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[v]x`` with ``[v]x @ u == cross(v, u)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def check_rotation(name: str, R: Any, *, caller: str = "") -> np.ndarray:
    """Return ``R`` as a 3x3 float64 rotation; raise :class:`InputError` if not orthonormal with det +1."""
    R = as_float_array(name, R, (3, 3), caller=caller)
    ortho = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if ortho > ORTHONORMAL_TOL or abs(det - 1.0) > ORTHONORMAL_TOL:
        where = f" of {caller}" if caller else ""
        raise InputError(
            f"The {name!r} argument{where} must be a rotation (orthonormal, det +1, tolerance {ORTHONORMAL_TOL:g}). "
            f"Got max |R^T R - I| = {ortho:.3g} and det = {det:.6g} instead."
        )
    return R


def orthonormalize_transform(T: np.ndarray) -> np.ndarray:
    """``T`` (4x4, modified in place and returned) with its rotation block replaced by the nearest rotation
    (SVD, determinant +1) and its last row ``[0, 0, 0, 1]``: the one re-orthonormalisation of every
    iterative estimate (ICP, the coarse search) and of composed transforms."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    T[3] = [0.0, 0.0, 0.0, 1.0]
    return T


@dataclass(frozen=True, eq=False)
class RigidTransform:
    """A rigid transform ``T_parent_child`` (4x4): maps child-frame points into the parent frame.

    Construct from a matrix (validated: last row [0 0 0 1], orthonormal rotation, finite), or with
    :meth:`from_rotation_translation`, :meth:`from_quat_wxyz` or :meth:`from_xyz_rpy`. Compose with
    ``@`` (``T_a_b @ T_b_c -> T_a_c``), invert with :meth:`inverse`, apply to ``(N, 3)`` points with
    :meth:`apply`.
    """

    matrix: np.ndarray

    def __post_init__(self) -> None:
        T = as_float_array("matrix", self.matrix, (4, 4), caller="RigidTransform")
        if np.abs(T[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
            raise InputError(
                f"The 'matrix' argument of RigidTransform must have last row [0, 0, 0, 1]. Got {T[3].tolist()} instead."
            )
        check_rotation("matrix[:3, :3]", T[:3, :3], caller="RigidTransform")
        T = T.copy()
        T.setflags(write=False)
        object.__setattr__(self, "matrix", T)

    # -- constructors -------------------------------------------------------------------------
    @classmethod
    def identity(cls) -> "RigidTransform":
        return cls(np.eye(4))

    @classmethod
    def from_rotation_translation(cls, rotation: Any, translation_m: Any = (0.0, 0.0, 0.0)) -> "RigidTransform":
        R = check_rotation("rotation", rotation, caller="RigidTransform.from_rotation_translation")
        t = as_float_array("translation_m", translation_m, (3,), caller="RigidTransform.from_rotation_translation")
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = t
        return cls(T)

    @classmethod
    def from_quat_wxyz(cls, quat_wxyz: Any, translation_m: Any = (0.0, 0.0, 0.0)) -> "RigidTransform":
        return cls.from_rotation_translation(rotation_from_quat_wxyz(quat_wxyz), translation_m)

    @classmethod
    def from_xyz_rpy(cls, xyz_m: Any, rpy_rad: Any) -> "RigidTransform":
        rpy = as_float_array("rpy_rad", rpy_rad, (3,), caller="RigidTransform.from_xyz_rpy")
        return cls.from_rotation_translation(rotation_from_rpy(*rpy), xyz_m)

    # -- accessors ----------------------------------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        return self.matrix[:3, :3]

    @property
    def translation_m(self) -> np.ndarray:
        return self.matrix[:3, 3]

    def as_rpy(self) -> np.ndarray:
        return rpy_from_rotation(self.rotation)

    def as_quat_wxyz(self) -> np.ndarray:
        return quat_wxyz_from_rotation(self.rotation)

    def as_xyz_rpy(self) -> np.ndarray:
        """``[x, y, z, roll, pitch, yaw]`` (metres, radians)."""
        return np.concatenate([self.translation_m, self.as_rpy()])

    # -- algebra ------------------------------------------------------------------------------
    def inverse(self) -> "RigidTransform":
        R = self.rotation
        T = np.eye(4)
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ self.translation_m
        return RigidTransform(T)

    def __matmul__(self, other: "RigidTransform") -> "RigidTransform":
        if not isinstance(other, RigidTransform):
            return NotImplemented
        # re-orthonormalise so that long chains never drift out of tolerance
        return RigidTransform(orthonormalize_transform(self.matrix @ other.matrix))

    def apply(self, points_xyz_m: Any) -> np.ndarray:
        """Map ``(N, 3)`` child-frame points into the parent frame."""
        p = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller="RigidTransform.apply")
        return p @ self.rotation.T + self.translation_m

    def rotate(self, vectors: Any) -> np.ndarray:
        """Rotate ``(N, 3)`` direction vectors (normals) into the parent frame (no translation)."""
        v = as_float_array("vectors", vectors, (None, 3), caller="RigidTransform.rotate")
        return v @ self.rotation.T

    def to_dict(self) -> dict:
        """JSON-friendly form: 4x4 matrix, xyz, roll-pitch-yaw and quat_wxyz."""
        return {
            "matrix": self.matrix.tolist(),
            "xyz_m": self.translation_m.tolist(),
            "rpy_rad": self.as_rpy().tolist(),
            "quat_wxyz": self.as_quat_wxyz().tolist(),
        }

    def __repr__(self) -> str:
        x, y, z, r, p, yw = self.as_xyz_rpy()
        return (f"RigidTransform(xyz_m=[{x:.4f}, {y:.4f}, {z:.4f}], "
                f"rpy_deg=[{np.degrees(r):.2f}, {np.degrees(p):.2f}, {np.degrees(yw):.2f}])")
