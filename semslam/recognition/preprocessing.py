"""The preprocessing of a view database's views, recorded in the database and applied to every query.

A database's descriptors are only comparable with a query's when both clouds went through the same steps: a
real RealSense view keeps its invalid-depth points at the sensor origin and its drawn axes unless it is cleaned,
and a database of cleaned views matched against uncleaned queries mistakes one class for another (issue #29:
71 % instead of 95 % right class on the real valves). :class:`ViewPreprocessing` says what was done to the
views before their descriptors; :func:`~semslam.recognition.build_database` applies it to the views and stores
it in ``params["preprocessing"]``; :meth:`~semslam.recognition.ViewDatabase.describe` (the one door of
``Recognizer.match``, ``ScanRecognizer.recognize``, ``detect_dataset``, ``run`` and the live node) applies it to
every query. The voxel grid and the normal radius are recorded beside it (``params["voxel_leaf_m"]``,
``params["normal_radius_m"]``) and applied by :func:`~semslam.recognition.compute_view_descriptors`.

Steps, in order (each optional):

1. **range limits**: keep the points whose distance to the cloud's sensor origin (``viewpoint_xyz_m``) is in
   ``[min_range_m, max_range_m]``;
2. **cleaning** (:func:`semslam.segmentation.clean.clean_view`): drop the points at the sensor origin and the
   drawn straight lines.

A query that cannot be treated the same way is an error, never a silent mismatch:

* nothing left after the steps: :class:`~semslam.errors.DescriptorError` (a scan's cluster is then rejected
  with that reason);
* a query sparser than the views could ever be made (its point spacing above :data:`MAX_SPACING_RATIO` times
  the views' spacing after the database's voxel grid, ``view_spacing_m``; e.g. a query in millimetres against a
  database in metres, or a 2 cm laser cluster against 1 mm depth-camera views): :class:`DescriptorError`;
* a record this semslam does not know (a newer preprocessing version, an unknown step):
  :class:`~semslam.errors.DatabaseError`.

Databases written before the record (format versions 1 and 2) read as ``known=False``: nothing is applied to
their queries (as before), and :meth:`ViewPreprocessing.describe` says it is unknown.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..cloud import PointCloud
from ..errors import DatabaseError, DescriptorError, InputError

__all__ = ["MAX_SPACING_RATIO", "PREPROCESSING_VERSION", "ViewPreprocessing"]

#: Version of the record in ``params["preprocessing"]``; a database with a higher one is refused.
PREPROCESSING_VERSION = 1

#: A query whose raw point spacing exceeds this many times the views' spacing after the database's voxel grid is
#: refused: no grid can bring it to the views' density. Measured headroom: in ``semslam demo --quick`` (built-in
#: database, laser clusters) the clusters' spacing is 0.88x the views' at the median and 1.18x at most (55 clusters);
#: a query in millimetres against views in metres is 1000x.
MAX_SPACING_RATIO = 4.0

_KEYS = ("version", "known", "clean", "drop_origin", "drop_drawn_lines", "min_line_points", "min_range_m",
         "max_range_m", "view_spacing_m")


@dataclass(frozen=True)
class ViewPreprocessing:
    """What was done to a database's views before their descriptors, and is done to every query.

    Attributes
    ----------
    clean : bool, default False
        Apply :func:`~semslam.segmentation.clean.clean_view` (with ``drop_origin``, ``drop_drawn_lines`` and
        ``min_line_points``).
    drop_origin, drop_drawn_lines : bool, default True
    min_line_points : int, default 10
    min_range_m, max_range_m : float, optional
        Range limits, metres from the cloud's ``viewpoint_xyz_m`` (None: no limit).
    view_spacing_m : float, optional
        Median point spacing of the views after the database's voxel grid (set by ``build_database``): queries
        sparser than :data:`MAX_SPACING_RATIO` times it are refused. None: not checked.
    known : bool, default True
        False for databases written before the preprocessing was recorded: nothing is applied to queries.
    """

    clean: bool = False
    drop_origin: bool = True
    drop_drawn_lines: bool = True
    min_line_points: int = 10
    min_range_m: float | None = None
    max_range_m: float | None = None
    view_spacing_m: float | None = None
    known: bool = True

    def __post_init__(self) -> None:
        caller = "ViewPreprocessing"
        for name in ("clean", "drop_origin", "drop_drawn_lines", "known"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputError(f"The {name!r} argument of {caller} must be True or False. "
                                 f"Got {getattr(self, name)!r} instead.")
            object.__setattr__(self, name, bool(getattr(self, name)))
        n = self.min_line_points
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            raise InputError(f"The 'min_line_points' argument of {caller} must be an integer >= 2. Got {n!r} instead.")
        object.__setattr__(self, "min_line_points", int(n))
        for name in ("min_range_m", "max_range_m", "view_spacing_m"):
            v = getattr(self, name)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not np.isfinite(v) \
                    or v < 0 or (v == 0 and name != "min_range_m"):
                raise InputError(f"The {name!r} argument of {caller} must be a finite number of metres "
                                 f"{'>= 0' if name == 'min_range_m' else '> 0'} or None. Got {v!r} instead.")
            object.__setattr__(self, name, float(v))
        if self.min_range_m is not None and self.max_range_m is not None and self.min_range_m >= self.max_range_m:
            raise InputError(f"The range limits of {caller} must satisfy min_range_m < max_range_m. "
                             f"Got {self.min_range_m} and {self.max_range_m} instead.")

    @classmethod
    def unknown(cls) -> ViewPreprocessing:
        """The record of a database written before preprocessing was recorded: nothing applied."""
        return cls(known=False)

    @property
    def is_identity(self) -> bool:
        """True when :meth:`apply` returns every cloud unchanged."""
        return not self.known or not (self.clean or self.min_range_m is not None or self.max_range_m is not None)

    def to_dict(self) -> dict:
        """The JSON record stored in ``params["preprocessing"]``."""
        if not self.known:
            return {"version": PREPROCESSING_VERSION, "known": False}
        return {"version": PREPROCESSING_VERSION, "known": True, "clean": self.clean, "drop_origin": self.drop_origin,
                "drop_drawn_lines": self.drop_drawn_lines, "min_line_points": self.min_line_points,
                "min_range_m": self.min_range_m, "max_range_m": self.max_range_m,
                "view_spacing_m": self.view_spacing_m}

    @classmethod
    def from_dict(cls, record: Any, where: str = "The database") -> ViewPreprocessing:
        """Read a record written by :meth:`to_dict`; None (a database built in memory without one) is the
        identity. A record this semslam cannot apply is a :class:`DatabaseError` naming ``where``."""
        if record is None:
            return cls()
        if isinstance(record, cls):
            return record
        if not isinstance(record, Mapping):
            raise DatabaseError(f"{where} has an invalid preprocessing record: expected a table, got {record!r:.80}.")
        version = record.get("version")
        if version != PREPROCESSING_VERSION:
            raise DatabaseError(f"{where} records its views' preprocessing in version {version!r}; this semslam "
                                f"applies version {PREPROCESSING_VERSION} only, so it cannot treat queries as the "
                                f"views were. Upgrade semslam or rebuild the database with this one.")
        unknown = sorted(set(record) - set(_KEYS))
        if unknown:
            raise DatabaseError(f"{where} records preprocessing steps this semslam does not know: "
                                f"{', '.join(unknown)}; it cannot treat queries as the views were. Upgrade semslam "
                                f"or rebuild the database with this one.")
        try:
            return cls(**{k: v for k, v in record.items() if k != "version"})
        except (InputError, TypeError) as exc:
            raise DatabaseError(f"{where} has an invalid preprocessing record: {exc}") from None

    def describe(self) -> str:
        """One line for people: what is applied to queries."""
        if not self.known:
            return "unknown (database written before the preprocessing was recorded): none applied to queries"
        steps = []
        if self.min_range_m is not None or self.max_range_m is not None:
            steps.append(f"range {self.min_range_m or 0:g}-{self.max_range_m or float('inf'):g} m")
        if self.clean:
            what = [w for w, on in (("sensor-origin points", self.drop_origin),
                                    (f"drawn lines (>= {self.min_line_points} points)", self.drop_drawn_lines)) if on]
            steps.append("clean: drop " + " and ".join(what) if what else "clean: nothing")
        return "; ".join(steps) or "none"

    def with_view_spacing(self, view_spacing_m: float | None) -> ViewPreprocessing:
        """A copy with ``view_spacing_m`` set."""
        return ViewPreprocessing(**{**{k: getattr(self, k) for k in _KEYS if k != "version"},
                                    "view_spacing_m": view_spacing_m})

    def apply(self, cloud: PointCloud, *, name: str = "query") -> PointCloud:
        """``cloud`` after the recorded steps (the same object when nothing applies).

        Raises :class:`DescriptorError` naming ``name`` when no point is left, or when the cloud is too sparse
        for the database (see the module docstring).
        """
        if not isinstance(cloud, PointCloud):
            raise InputError(f"The {name} must be a PointCloud. Got {type(cloud).__name__} instead.")
        if not self.known:
            return cloud
        out = cloud
        if self.min_range_m is not None or self.max_range_m is not None:
            r = np.linalg.norm(cloud.points_xyz_m - np.asarray(cloud.viewpoint_xyz_m, dtype=float)[None, :], axis=1)
            keep = np.ones(len(r), dtype=bool)
            if self.min_range_m is not None:
                keep &= r >= self.min_range_m
            if self.max_range_m is not None:
                keep &= r <= self.max_range_m
            if not keep.any():
                raise DescriptorError(f"The {name} has no point within the database's range limits "
                                      f"[{self.min_range_m or 0:g}, {self.max_range_m or float('inf'):g}] m of its "
                                      f"sensor origin {np.round(cloud.viewpoint_xyz_m, 4).tolist()} "
                                      f"({cloud.n_points} points read).")
            if not keep.all():
                out = cloud.select(np.flatnonzero(keep))
        if self.clean:
            from ..segmentation.clean import clean_view

            try:
                out = clean_view(out, drop_origin=self.drop_origin, drop_drawn_lines=self.drop_drawn_lines,
                                 min_line_points=self.min_line_points, name=name)[0]
            except InputError as exc:
                raise DescriptorError(f"{exc} The database's views were cleaned the same way "
                                      f"(preprocessing: {self.describe()}).") from None
        self.check_spacing(out, name=name)
        return out

    def check_spacing(self, cloud: PointCloud, *, name: str = "query") -> None:
        """Refuse a cloud sparser than :data:`MAX_SPACING_RATIO` times the views' spacing (DescriptorError)."""
        if self.view_spacing_m is None or cloud.n_points < 5:
            return
        from ..descriptors import point_spacing_m
        from ..errors import SemslamError

        try:
            spacing = point_spacing_m(cloud.points_xyz_m, seed=0, sample=500)
        except SemslamError:
            return  # duplicated points: the descriptors say what is wrong
        if spacing > MAX_SPACING_RATIO * self.view_spacing_m:
            raise DescriptorError(
                f"The {name} has a point spacing of {spacing:.4g} m, {spacing / self.view_spacing_m:.1f} times the "
                f"database views' {self.view_spacing_m:.4g} m (after its voxel grid; at most {MAX_SPACING_RATIO:g} "
                f"times is accepted): it cannot be described as the views were. Is it in another unit (metres "
                f"expected), or from a sparser sensor? Build the database from views of this sensor "
                f"('semslam db build --models' renders them) or with a voxel grid at its density.")
