"""Declared symmetry of an object class, in the object's canonical frame.

* ``none``: every rotation is observable.
* ``discrete``: the object looks the same after rotating by ``2*pi/order`` about ``axis_object``
  (an elbow or a tee: order 2).
* ``continuous``: the object is axisymmetric about ``axis_object`` (a reducing socket): rotation about that
  axis is unobservable. With ``flip=True`` it also looks the same turned end for end (a half turn about any
  axis perpendicular to ``axis_object``): a plain cylinder, a pipe spool, a sonobuoy.

Pose estimation uses it to measure errors modulo the symmetry, to canonicalise reported orientations, and
to give an unobservable rotation a very large variance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validation import as_float_array
from .errors import InputError

SYMMETRY_KINDS = ("none", "discrete", "continuous")


@dataclass(frozen=True, eq=False)
class Symmetry:
    """Symmetry of an object class (see module docstring)."""

    kind: str = "none"
    axis_object: np.ndarray | None = None
    order: int = 1
    #: continuous only: the object is also the same turned end for end (see the module docstring)
    flip: bool = False

    def __post_init__(self) -> None:
        if self.kind not in SYMMETRY_KINDS:
            raise InputError(
                f"The 'kind' argument of Symmetry must be one of {SYMMETRY_KINDS}. Got {self.kind!r} instead."
            )
        if not isinstance(self.flip, (bool, np.bool_)):
            raise InputError(f"The 'flip' argument of Symmetry must be True or False. Got {self.flip!r} instead.")
        object.__setattr__(self, "flip", bool(self.flip))
        if self.flip and self.kind != "continuous":
            raise InputError(f"The 'flip' argument of Symmetry is only defined for a continuous symmetry (an "
                             f"end-for-end turn of an axisymmetric object). Got flip=True with kind {self.kind!r} "
                             f"instead.")
        if self.kind == "none":
            object.__setattr__(self, "axis_object", None)
            object.__setattr__(self, "order", 1)
            return
        if self.axis_object is None:
            raise InputError(
                f"The 'axis_object' argument of Symmetry is required for kind {self.kind!r}. Got None instead."
            )
        axis = as_float_array("axis_object", self.axis_object, (3,), caller="Symmetry")
        n = float(np.linalg.norm(axis))
        if n < 1e-9:
            raise InputError(
                "The 'axis_object' argument of Symmetry must be a non-zero vector. Got a zero vector instead."
            )
        axis = axis / n
        axis.setflags(write=False)
        object.__setattr__(self, "axis_object", axis)
        if self.kind == "discrete":
            if isinstance(self.order, bool) or not isinstance(self.order, (int, np.integer)) or self.order < 2:
                raise InputError(
                    f"The 'order' argument of Symmetry must be an integer >= 2 for a discrete symmetry. Got "
                    f"{self.order!r} instead."
                )
            object.__setattr__(self, "order", int(self.order))
        else:
            object.__setattr__(self, "order", 0)  # 0 = infinite

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"kind": self.kind}
        if self.axis_object is not None:
            d["axis_object"] = self.axis_object.tolist()
        if self.kind == "discrete":
            d["order"] = self.order
        if self.flip:
            d["flip"] = True
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Symmetry":
        try:
            return cls(kind=d["kind"], axis_object=d.get("axis_object"), order=d.get("order", 1),
                       flip=d.get("flip", False))
        except (KeyError, TypeError, AttributeError) as exc:
            raise InputError(f"A symmetry record must have a 'kind'. Got {d!r} instead.") from exc

    # -- maths ----------------------------------------------------------------------------------
    @property
    def unobservable_axes(self) -> np.ndarray:
        """Object-frame unit axes about which a rotation is unobservable, shape ``(K, 3)``.

        ``(1, 3)`` (the axis) for a continuous symmetry, ``(0, 3)`` otherwise: a discrete symmetry makes the
        orientation ambiguous between ``order`` isolated solutions, but each of them is locally observable.
        """
        if self.kind == "continuous":
            return self.axis_object[None, :].copy()
        return np.zeros((0, 3))

    def group_rotations(self) -> np.ndarray:
        """The rotations of the discrete group about ``axis_object``, shape ``(order, 3, 3)`` (identity first).

        For ``none`` this is the identity alone; for ``continuous`` it is not defined and raises.
        """
        if self.kind == "continuous":
            raise InputError("Symmetry.group_rotations is not defined for a continuous symmetry (infinite group).")
        if self.kind == "none":
            return np.eye(3)[None]
        angles = 2.0 * np.pi * np.arange(self.order) / self.order
        return _axis_angle_matrices(self.axis_object, angles)

    @property
    def flip_rotation(self) -> np.ndarray | None:
        """The end-for-end half turn of a flipped continuous symmetry (object frame, about :meth:`perpendicular_axis`),
        ``None`` otherwise."""
        if not self.flip:
            return None
        return _axis_angle_matrices(self.perpendicular_axis(), np.array([np.pi]))[0]

    def perpendicular_axis(self) -> np.ndarray:
        """An object-frame unit vector perpendicular to ``axis_object``, chosen deterministically (the basis
        vector least aligned with the axis, projected); not defined for ``none``."""
        if self.axis_object is None:
            raise InputError("Symmetry.perpendicular_axis is not defined for the symmetry 'none' (no axis).")
        a = self.axis_object
        e = np.eye(3)[int(np.argmin(np.abs(a)))]
        u = e - (e @ a) * a
        return u / np.linalg.norm(u)

    def finite_rotations(self) -> np.ndarray:
        """The isolated (finite) part of the group, shape ``(K, 3, 3)``, identity first: the discrete group, the
        identity and the end-for-end half turn of a flipped continuous symmetry, the identity otherwise. Combined
        with free rotations about :attr:`unobservable_axes` it spans every equivalent orientation."""
        if self.kind == "discrete":
            return self.group_rotations()
        if self.flip:
            return np.stack([np.eye(3), self.flip_rotation])
        return np.eye(3)[None]

    def rotation_error_rad(self, R_est: Any, R_true: Any) -> float:
        """Rotation error (radians, in [0, pi]) between two orientations ``R_parent_object``, modulo the symmetry.

        * ``none``: the angle of ``R_true^T R_est``.
        * ``discrete``: the smallest such angle over the group, ``min_k angle(R_true^T R_est S_k)``.
        * ``continuous``: the angle between the symmetry axis mapped by each rotation,
          ``acos(R_est a . R_true a)``; this equals ``min_theta angle(R_true^T R_est Exp(theta a))``, i.e. the
          error once the unobservable rotation about the axis is ignored; with ``flip`` the axis's sign is
          ignored too, ``acos(|R_est a . R_true a|)``.
        """
        from .geometry import check_rotation

        Re = check_rotation("R_est", R_est, caller="Symmetry.rotation_error_rad")
        Rt = check_rotation("R_true", R_true, caller="Symmetry.rotation_error_rad")
        if self.kind == "continuous":
            a = self.axis_object
            c = float((Re @ a) @ (Rt @ a))
            return float(np.arccos(np.clip(abs(c) if self.flip else c, -1.0, 1.0)))
        M = Rt.T @ Re @ self.group_rotations()  # (order, 3, 3)
        traces = np.trace(M, axis1=1, axis2=2)
        return float(np.arccos(np.clip((traces.max() - 1.0) / 2.0, -1.0, 1.0)))

    def canonicalize(self, R_parent_object: Any, *, reference: Any = None) -> np.ndarray:
        """A deterministic representative of the orientations the symmetry makes indistinguishable.

        Parameters
        ----------
        R_parent_object : array-like of shape (3, 3)
            An orientation of the object (object frame -> parent frame).
        reference : array-like, optional
            * ``discrete``: a reference rotation ``(3, 3)`` (default identity); the group element
              ``R S_k`` closest to it (smallest angle; ties go to the lowest ``k``) is returned.
            * ``continuous``: a parent-frame reference direction ``(3,)`` (default ``+z``, down in NED).
              Among ``R Exp(theta a)``, the one whose object ``u`` axis (the first object-frame basis vector
              most perpendicular to ``a``, projected onto the plane normal to ``a``) maps closest to the
              reference direction is returned. When ``R a`` is parallel to the reference, ``+x`` then
              ``+y`` of the parent frame are used instead. With ``flip``, the end is chosen first: the one whose
              mapped axis ``R a`` points along the first of the same directions it is not perpendicular to.

        Returns
        -------
        ndarray of shape (3, 3)
            The canonical orientation, equivalent to ``R_parent_object`` under the symmetry. For ``none`` the
            input itself.
        """
        from .geometry import check_rotation

        R = check_rotation("R_parent_object", R_parent_object, caller="Symmetry.canonicalize")
        if self.kind == "none":
            return R.copy()
        if self.kind == "discrete":
            R_ref = (
                np.eye(3)
                if reference is None
                else check_rotation("reference", reference, caller="Symmetry.canonicalize")
            )
            cands = R @ self.group_rotations()
            traces = np.trace(R_ref.T @ cands, axis1=1, axis2=2)
            best = int(np.flatnonzero(traces >= traces.max() - 1e-12)[0])
            return cands[best]
        a = self.axis_object
        u = self.perpendicular_axis()
        v = np.cross(a, u)
        refs = [np.array([0.0, 0.0, 1.0]) if reference is None
                else as_float_array("reference", reference, (3,), caller="Symmetry.canonicalize"),
                np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])]
        if self.flip:
            for d in refs:
                c = float((R @ a) @ d)
                if abs(c) > 1e-6 * max(1.0, float(np.linalg.norm(d))):
                    if c < 0.0:
                        R = R @ self.flip_rotation
                    break
        a_p = R @ a
        for d in refs:
            d_perp = d - (d @ a_p) * a_p
            if np.linalg.norm(d_perp) > 1e-6 * max(1.0, float(np.linalg.norm(d))):
                break
        # R Exp(theta a) u = cos(theta) R u + sin(theta) R v : maximise the dot product with d
        theta = float(np.arctan2(d_perp @ (R @ v), d_perp @ (R @ u)))
        return R @ _axis_angle_matrices(a, np.array([theta]))[0]


def _axis_angle_matrices(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations by ``angles`` (K,) about the unit ``axis`` (3,), shape ``(K, 3, 3)``."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s = np.sin(angles)[:, None, None]
    c = np.cos(angles)[:, None, None]
    return np.eye(3)[None] + s * K[None] + (1.0 - c) * (K @ K)[None]
