"""The built-in view database (the simulator's four fittings seen by its Kinect-like camera in the survey
geometry, :data:`~semslam.simulation.kinect.SURVEY_KINECT`, for recognition, and closer and lower,
:data:`~semslam.simulation.kinect.POSE_MODEL_KINECT`, as the classes' pose-model views), built once and
cached on disk.

The cache file is keyed by everything that changes its content: the database format version, the
semslam version, the Kinect settings (both), the numbers of views, the seed and the descriptor parameters.
It lives in ``$SEMSLAM_CACHE_DIR`` or ``~/.cache/semslam`` and is written atomically; a corrupted or
unreadable cache file is rebuilt.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from ..errors import DatabaseError
from .._cache import cache_dir
from ..recognition.build import build_database
from ..recognition.database import FORMAT_VERSION, ViewDatabase
from ..recognition.storage import load_database, save_database
from ..recognition.view_descriptors import DEFAULT_NORMAL_RADIUS_M, DEFAULT_VOXEL_LEAF_M

__all__ = ["builtin_database", "cache_dir"]


def builtin_database(*, seed: int = 0, n_views: int = 8, n_model_views: int = 8, cache: bool = True,
                     **kwargs: Any) -> ViewDatabase:
    """The built-in database, from the cache when an identical one was built before.

    Parameters
    ----------
    seed : int
        Seeds the simulated views and ESF.
    n_views : int
        Recognition views per object (azimuths every 360 / n_views degrees), survey geometry.
    n_model_views : int
        Pose-model views per object at :data:`~semslam.simulation.kinect.POSE_MODEL_KINECT` (0: none, pose
        estimation then fuses the recognition views).
    cache : bool
        Read and write the cache (False: always build, write nothing).
    **kwargs
        Passed to :func:`~semslam.recognition.build_database` (``vfh_variant``, ``normal_radius_m``,
        ``esf_n_samples``, ``voxel_leaf_m``).
    """
    from .. import __version__
    from .kinect import POSE_MODEL_KINECT, SURVEY_KINECT, builtin_view_clouds

    params = {"format_version": FORMAT_VERSION, "semslam": __version__, "kinect": SURVEY_KINECT.to_dict(),
              "model_kinect": POSE_MODEL_KINECT.to_dict(), "n_model_views": int(n_model_views),
              "n_views": int(n_views), "seed": int(seed), "normal_radius_m": DEFAULT_NORMAL_RADIUS_M,
              "voxel_leaf_m": DEFAULT_VOXEL_LEAF_M, "esf_n_samples": 20000, "vfh_variant": None,
              "vfh_arithmetic": "float32 as PCL 1.13", "resting_up": 2,  # 2: the ups of tied rests too
              **kwargs}  # a change of the descriptors (or of what the database records) renews the cache
    key = hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:16]
    path = cache_dir() / f"builtin_db_{key}.npz"
    if cache and path.is_file():
        try:
            return load_database(path)
        except DatabaseError:
            pass  # corrupted or stale: rebuild below
    views, classes = builtin_view_clouds(seed=seed, n_views=n_views, config=SURVEY_KINECT)
    model_views = None
    if n_model_views:
        model_views, _ = builtin_view_clouds(seed=seed, n_views=n_model_views, config=POSE_MODEL_KINECT)
    from .model_views import with_resting_up
    from .objects import builtin_objects

    db = with_resting_up(
        build_database(views, classes, seed=seed, model_views=model_views, **kwargs), builtin_objects()
    )
    if cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_database(db, path)
        except (OSError, DatabaseError):
            pass  # a read-only home must not stop recognition
    return db
