"""A recognised object: the output of the scan-to-detections pipeline and the input of the filter."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._validation import as_float_array
from .errors import InputError
from .geometry import RigidTransform

#: Order of the pose covariance: translation then roll-pitch-yaw (see :mod:`semslam.geometry`).
POSE_COVARIANCE_ORDER = ("x", "y", "z", "roll", "pitch", "yaw")


@dataclass(frozen=True, eq=False)
class Detection:
    """One recognised object in one scan.

    Parameters
    ----------
    label : str
        Class label (``"ball_valve"``), never ``"unknown"`` for a detection that is passed to the filter.
    score : float
        Matching distance (chi-square, smaller is better) or classifier score, as named by ``score_kind``.
    T_sensor_object : RigidTransform
        The object's canonical frame expressed in the sensor frame.
    covariance_6x6 : array of shape (6, 6)
        Covariance of the pose, order x y z roll pitch yaw (m, rad), symmetric positive semi-definite.
        A rotation that the object's symmetry makes unobservable has a very large variance.
    """

    label: str
    score: float
    T_sensor_object: RigidTransform
    covariance_6x6: np.ndarray
    score_kind: str = "chi2"
    fitness: float = float("nan")
    rmse_m: float = float("nan")
    n_points: int = 0
    reliable: bool = True
    stamp_s: float = float("nan")
    scan_id: int = -1
    extras: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.label, str) or not self.label:
            raise InputError(
                f"The 'label' argument of Detection must be a non-empty string. Got {self.label!r} instead."
            )
        if not isinstance(self.T_sensor_object, RigidTransform):
            object.__setattr__(self, "T_sensor_object", RigidTransform(self.T_sensor_object))
        cov = as_float_array("covariance_6x6", self.covariance_6x6, (6, 6), caller="Detection")
        asym = float(np.abs(cov - cov.T).max())
        if asym > 1e-9 * max(1.0, float(np.abs(cov).max())):
            raise InputError(
                f"The 'covariance_6x6' argument of Detection must be symmetric. Got max |C - C^T| = {asym:.3g} instead."
            )
        min_eig = float(np.linalg.eigvalsh(0.5 * (cov + cov.T)).min())
        if min_eig < -1e-12 * max(1.0, float(np.abs(cov).max())):
            raise InputError(
                f"The 'covariance_6x6' argument of Detection must be positive semi-definite. Got smallest eigenvalue "
                f"{min_eig:.3g} instead."
            )
        cov = 0.5 * (cov + cov.T)
        cov.setflags(write=False)
        object.__setattr__(self, "covariance_6x6", cov)

    def to_dict(self) -> dict:
        """JSON-friendly form (pose as 4x4, xyz, rpy, quat_wxyz)."""
        return {
            "label": self.label,
            "score": float(self.score),
            "score_kind": self.score_kind,
            "T_sensor_object": self.T_sensor_object.to_dict(),
            "covariance_6x6": self.covariance_6x6.tolist(),
            "covariance_order": list(POSE_COVARIANCE_ORDER),
            "fitness": _num(self.fitness),
            "rmse_m": _num(self.rmse_m),
            "n_points": int(self.n_points),
            "reliable": bool(self.reliable),
            "stamp_s": _num(self.stamp_s),
            "scan_id": int(self.scan_id),
            **({"extras": self.extras} if self.extras else {}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Detection":
        if not isinstance(d, dict):
            raise InputError(f"A detection record must be a JSON object. Got {type(d).__name__} instead.")
        if not isinstance(d.get("reliable", True), bool):  # "false" would be truthy
            raise InputError(
                f"A detection record's 'reliable' must be true or false. Got {d.get('reliable')!r} instead."
            )
        if not isinstance(d.get("label"), str):
            raise InputError(f"A detection record's 'label' must be a string. Got {d.get('label')!r} instead.")
        try:
            return cls(
                label=d["label"],
                score=float(d["score"]),
                T_sensor_object=RigidTransform(np.asarray(d["T_sensor_object"]["matrix"], dtype=float)),
                covariance_6x6=np.asarray(d["covariance_6x6"], dtype=float),
                score_kind=d.get("score_kind", "chi2"),
                fitness=_unnum(d.get("fitness")),
                rmse_m=_unnum(d.get("rmse_m")),
                n_points=int(d.get("n_points", 0)),
                reliable=d.get("reliable", True),
                stamp_s=_unnum(d.get("stamp_s")),
                scan_id=int(d.get("scan_id", -1)),
                extras=dict(d.get("extras", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"A detection record is malformed: {exc!r}") from None


def _num(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _unnum(x: Any) -> float:
    return float("nan") if x is None else float(x)
