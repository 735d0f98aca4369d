"""Declared symmetry of an object class, in the object's canonical frame.

* ``none``: every rotation is observable.
* ``discrete``: the object looks the same after rotating by ``2*pi/order`` about ``axis_object``
  (an elbow or a tee: order 2).
* ``continuous``: the object is axisymmetric about ``axis_object`` (a reducing socket): rotation about that
  axis is unobservable.

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

    def __post_init__(self) -> None:
        if self.kind not in SYMMETRY_KINDS:
            raise InputError(
                f"The 'kind' argument of Symmetry must be one of {SYMMETRY_KINDS}. Got {self.kind!r} instead."
            )
        if self.kind == "none":
            object.__setattr__(self, "axis_object", None)
            object.__setattr__(self, "order", 1)
            return
        if self.axis_object is None:
            raise InputError(f"The 'axis_object' argument of Symmetry is required for kind {self.kind!r}. Got None instead.")
        axis = as_float_array("axis_object", self.axis_object, (3,), caller="Symmetry")
        n = float(np.linalg.norm(axis))
        if n < 1e-9:
            raise InputError("The 'axis_object' argument of Symmetry must be a non-zero vector. Got a zero vector instead.")
        axis = axis / n
        axis.setflags(write=False)
        object.__setattr__(self, "axis_object", axis)
        if self.kind == "discrete":
            if isinstance(self.order, bool) or not isinstance(self.order, (int, np.integer)) or self.order < 2:
                raise InputError(f"The 'order' argument of Symmetry must be an integer >= 2 for a discrete symmetry. Got {self.order!r} instead.")
            object.__setattr__(self, "order", int(self.order))
        else:
            object.__setattr__(self, "order", 0)  # 0 = infinite

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"kind": self.kind}
        if self.axis_object is not None:
            d["axis_object"] = self.axis_object.tolist()
        if self.kind == "discrete":
            d["order"] = self.order
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Symmetry":
        try:
            return cls(kind=d["kind"], axis_object=d.get("axis_object"), order=d.get("order", 1))
        except (KeyError, TypeError, AttributeError) as exc:
            raise InputError(f"A symmetry record must have a 'kind'. Got {d!r} instead.") from exc
