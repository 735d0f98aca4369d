"""The grid search's optional inputs of :func:`~semslam.pose.estimate.estimate_object_pose`, checked."""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validation import as_float_array
from ..errors import InputError

_CALLER = "estimate_object_pose"


def checked_search_inputs(partial: Any, surroundings_scanner: Any, admissible: Any, scene_scanner: Any,
                          floor_scanner: Any = None) -> tuple:
    """``partial`` as a bool, ``surroundings_scanner`` as an (K, 3) array (or None), ``admissible``,
    ``scene_scanner`` as two float arrays (S >= 1, 3), (K, 3) (or None) and ``floor_scanner`` as a unit normal (3,) and
    offset (or None), checked."""
    if not isinstance(partial, (bool, np.bool_)):
        raise InputError(f"The 'partial' argument of {_CALLER} must be true or false. Got {partial!r} instead.")
    if admissible is not None and not callable(admissible):
        raise InputError(f"The 'admissible' argument of {_CALLER} must be a function of a 4x4 pose or None. "
                         f"Got {type(admissible).__name__} instead.")
    surroundings = None if surroundings_scanner is None else \
        as_float_array("surroundings_scanner", surroundings_scanner, (None, 3), caller=_CALLER)
    return bool(partial), surroundings, admissible, _checked_scene(scene_scanner), _checked_floor(floor_scanner)


def _checked_floor(floor_scanner: Any) -> tuple[np.ndarray, float] | None:
    """``floor_scanner`` = (normal (3,), d) of the plane ``n . x + d = 0`` as a unit normal and its offset, or None."""
    if floor_scanner is None:
        return None
    if not isinstance(floor_scanner, (tuple, list)) or len(floor_scanner) != 2:
        raise InputError(f"The 'floor_scanner' argument of {_CALLER} must be a pair (normal (3,), d). "
                         f"Got {type(floor_scanner).__name__} instead.")
    n = as_float_array("floor_scanner[0]", floor_scanner[0], (3,), caller=_CALLER)
    norm = float(np.linalg.norm(n))
    try:
        d = float(floor_scanner[1])
    except (TypeError, ValueError):
        d = float("nan")
    if not (np.isfinite(norm) and norm > 1e-9 and np.isfinite(d)):
        raise InputError(f"The 'floor_scanner' argument of {_CALLER} must be a nonzero finite normal and a finite "
                         f"offset. Got normal {n.tolist()} and d {floor_scanner[1]!r} instead.")
    return n / norm, d / norm


def _checked_scene(scene_scanner: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """``scene_scanner`` as two float arrays (S, 3) and (K, 3), or None."""
    if scene_scanner is None:
        return None
    if not isinstance(scene_scanner, (tuple, list)) or len(scene_scanner) != 2:
        raise InputError(f"The 'scene_scanner' argument of {_CALLER} must be a pair (scene points, occluder points). "
                         f"Got {type(scene_scanner).__name__} instead.")
    scene, occluders = (as_float_array(n, a, (None, 3), caller=_CALLER)
                        for n, a in zip(("scene_scanner[0]", "scene_scanner[1]"), scene_scanner))
    if not len(scene):
        raise InputError(f"The 'scene_scanner' argument of {_CALLER} must hold at least one scene point. Got none.")
    return scene, occluders
