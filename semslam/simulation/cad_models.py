"""Users' CAD models as object classes of a view database (``semslam db build --models MODELS_DIR``).

``MODELS_DIR`` holds the model files and ``models.toml``, one table per class, the table's name being the
class label::

    [spool]
    file = "spool.stl"          # relative to MODELS_DIR
    unit = "mm"                 # the file's unit: m, mm, cm or inch (required for STL, OBJ and PLY, which state
                                # none; optional for COLLADA, glTF and STEP, which do, and then it overrides them)
    symmetry = "none"           # optional, default "none"; "discrete:2:z" (order 2 about the object's z axis),
                                # "continuous:z" (axisymmetric about z), "continuous:z:flip" (and the same
                                # turned end for end: a plain cylinder); axes x, y or z of the object frame
    # T_mesh_object = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]   # optional

Formats (:data:`MESH_FORMATS`, read with trimesh): STL, OBJ and PLY; COLLADA ``.dae`` (needs ``pycollada``:
``pip install 'semslam[models]'``); glTF ``.gltf``/``.glb``; STEP ``.step``/``.stp`` (needs ``cascadio``, which
bundles OpenCASCADE under the LGPL-2.1: ``pip install 'semslam[step]'``). Units: STL, OBJ and PLY state none,
so ``unit`` is required; a COLLADA file's ``<unit meter="...">`` (1 m when absent, as the COLLADA spec says),
glTF's metres (its spec) and a STEP file's length unit (applied by OpenCASCADE) are used when ``unit`` is
not given. **A ``unit`` in models.toml wins** over the file's own: the file's numbers are then read in that
unit, with a :class:`ModelUnitWarning` when the two differ. Coordinates are taken as written (no up-axis
conversion: a glTF model is usually y-up, which matters only for ``symmetry`` and ``T_mesh_object`` axes).
A COLLADA, glTF or STEP scene holding several meshes is read as **one** rigid object: its meshes, placed by
the scene's transforms, are concatenated, with a :class:`MultiMeshSceneWarning` (put each object in its own
file to make separate classes). An OBJ file's groups are concatenated silently, as before.

The class's canonical (object) frame is, by default, the mesh's axes with the origin at the centre of its
axis-aligned bounding box (the convention of the built-in objects, :mod:`semslam.simulation.objects`).
``T_mesh_object`` overrides it: the 4x4 rigid transform mapping object-frame points into the mesh file's
frame (``p_mesh = T_mesh_object @ p_object``), its translation in the mesh file's unit. Detections report
``T_sensor_object`` in that frame, and ``symmetry`` axes are object-frame axes.

Checks (each a one-line :class:`~semslam.errors.DatabaseError` naming the file, the class and the key):
``models.toml`` missing or not valid TOML, a class that is not a table, an unknown key, a missing
``file``, a missing ``unit`` for a format that states none, a model file not found, in a format semslam does
not read (the message lists those it reads) or unreadable, a COLLADA or STEP file whose optional reader is not
installed (the message says what to install), an unknown unit, a bad symmetry string, a ``T_mesh_object``
that is not a rigid transform, a mesh without triangles, non-finite vertices, and an absurd size (bounding-box
diagonal below 5 mm or above 20 m after the unit conversion: usually the wrong unit). A mesh that is not
watertight is accepted with a
:class:`NonWatertightMeshWarning`: its views render, but it has no centre of mass, so it rests on its
canonical x-y plane (z up) instead of its most stable face, and the Kinect aims at its bounding-box centre.

Views are rendered by the simulator's Kinect-like camera (:func:`~semslam.simulation.kinect.acquire_views`)
around each object in its most probable resting pose, as for the built-in database.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .._progress import Progress
from .._tables import read_table
from ..errors import DatabaseError, SemslamError
from ..symmetry import Symmetry
from .config import KinectConfig
from .mesh_files import MESH_FORMATS, MESH_SUFFIXES, UNITS_M, ModelUnitWarning, MultiMeshSceneWarning, load_mesh
from .mesh_files import step_length_unit_m as step_length_unit_m  # re-exported: users and tests import it from here
from .model_views import _tied_rests as _tied_rests  # re-exported for tests/pipeline/test_up_from_attitude.py
from .model_symmetry import OBJECT_AXES, ModelSymmetryWarning, check_declared_symmetry
from .model_views import models_view_clouds
from .model_views import resting_up_objects as resting_up_objects  # re-exported: tests import it from here
from .model_views import with_resting_up as with_resting_up  # re-exported: benchmarks and tests import it here
from .objects import ObjectModel, make_object

__all__ = [
    "MESH_FORMATS",
    "MESH_SUFFIXES",
    "MODELS_FILE",
    "UNITS_M",
    "ModelSymmetryWarning",
    "ModelUnitWarning",
    "MultiMeshSceneWarning",
    "NonWatertightMeshWarning",
    "build_models_database",
    "models_view_clouds",
    "parse_symmetry",
    "read_models",
]

#: Name of the class table inside ``MODELS_DIR``.
MODELS_FILE = "models.toml"
#: Keys of a class table.
KEYS = ("file", "unit", "symmetry", "T_mesh_object")
#: Plausible object sizes: bounding-box diagonal, metres (after the unit conversion).
MIN_DIAGONAL_M, MAX_DIAGONAL_M = 0.005, 20.0
#: Tolerance on the rotation block of ``T_mesh_object`` (hand-typed matrices: 4 decimals), re-orthonormalised.
ROTATION_TOL = 1e-3


_AXES = OBJECT_AXES


class NonWatertightMeshWarning(UserWarning):
    """A model mesh has holes: accepted, but without a centre of mass (see the module docstring)."""


def parse_symmetry(text: Any, *, where: str = "The symmetry") -> Symmetry:
    """``"none"``, ``"discrete:ORDER:AXIS"``, ``"continuous:AXIS"`` or ``"continuous:AXIS:flip"`` (AXIS one of
    x, y, z; ``flip``: also the same turned end for end, a plain cylinder) as a
    :class:`~semslam.symmetry.Symmetry`; ``where`` names the value in the error."""
    expected = ("'none', 'discrete:ORDER:AXIS' (ORDER an integer >= 2), 'continuous:AXIS' or 'continuous:AXIS:flip' "
                "(axisymmetric and the same turned end for end), AXIS one of x, y, z")
    if not isinstance(text, str):
        raise DatabaseError(f"{where} must be a string: {expected}. Got {text!r} instead.")
    parts = [p.strip() for p in text.strip().lower().split(":")]
    if parts == ["none"]:
        return Symmetry("none")
    if len(parts) == 3 and parts[0] == "discrete" and parts[2] in _AXES and parts[1].isdigit() and int(parts[1]) >= 2:
        return Symmetry("discrete", _AXES[parts[2]], int(parts[1]))
    if len(parts) in (2, 3) and parts[0] == "continuous" and parts[1] in _AXES and parts[2:] in ([], ["flip"]):
        return Symmetry("continuous", _AXES[parts[1]], flip=len(parts) == 3)
    raise DatabaseError(f"{where} must be {expected}. Got {text!r} instead.")


def _transform(value: Any, where: str) -> np.ndarray:
    """``T_mesh_object`` checked: 4x4 finite numbers, last row 0 0 0 1, a rotation block (re-orthonormalised)."""
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError):
        T = None
    if T is None or T.shape != (4, 4) or not np.all(np.isfinite(T)):
        got = f"shape {T.shape}" if T is not None and T.ndim else repr(value)[:80]
        raise DatabaseError(f"{where} must be a 4x4 array of finite numbers (4 rows of 4). Got {got} instead.")
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise DatabaseError(f"{where} must be a rigid transform with last row [0, 0, 0, 1]. Got {T[3].tolist()} instead.")
    R = T[:3, :3]
    ortho = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if ortho > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise DatabaseError(f"{where} must be a rigid transform: its 3x3 block a rotation (orthonormal, det +1, "
                            f"tolerance {ROTATION_TOL:g}). Got max |R^T R - I| = {ortho:.3g} and det = {det:.6g} "
                            f"instead.")
    U, _, Vt = np.linalg.svd(R)
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return T


def _inside(root: Path, name: str, where: str) -> Path:
    """``root / name``, refused unless it is a file inside the models folder once every link is resolved (an
    absolute path, ``../``, or a symbolic link leading out is another folder's file: never read on a models.toml's
    word)."""
    p = Path(name)
    if p.is_absolute() or ".." in p.parts:
        raise DatabaseError(f"{where}: 'file' must be a path inside the models folder {str(root)!r}. Got {name!r} "
                            "instead.")
    full = root / p
    try:
        inside = full.resolve(strict=False).is_relative_to(root.resolve(strict=False))
    except (OSError, RuntimeError):
        inside = False
    if not inside:
        raise DatabaseError(f"{where}: 'file' {name!r} leads out of the models folder {str(root)!r} (a symbolic "
                            "link?): copy the model into the folder.")
    return full


def read_models(models_dir: str | Path) -> dict[str, ObjectModel]:
    """The object classes described by ``models_dir/models.toml`` (see the module docstring), keyed by label
    in the file's order; each mesh in metres in its class's canonical frame.

    Raises
    ------
    DatabaseError
        On any invalid entry (one line naming the file, the class and the key).

    Warns
    -----
    NonWatertightMeshWarning
        For a mesh with holes (its views still render).
    ModelSymmetryWarning
        When the declared ``symmetry`` and the mesh clearly disagree
        (:func:`~semslam.simulation.model_symmetry.check_declared_symmetry`).
    """
    root = Path(models_dir)
    if root.is_file() and root.suffix.lower() == ".toml":  # the models file itself
        toml_path, root = root, root.parent
    else:
        if not root.is_dir():
            raise DatabaseError(f"The models folder {str(root)!r} does not exist or is not a folder.")
        toml_path = root / MODELS_FILE
    table = read_table(toml_path, "models file", DatabaseError)
    name = str(toml_path)
    if not table:
        raise DatabaseError(f"The models file {name!r} must define at least one class table ([label]). Got none instead.")
    models: dict[str, ObjectModel] = {}
    for label, entry in table.items():
        where = f"The class {label!r} of the models file {name!r}"
        if not isinstance(entry, dict):
            raise DatabaseError(f"{where} must be a table [{label}] with 'file' and 'unit'. Got {entry!r:.60} instead.")
        if not label.strip() or label in ("unknown", "clutter"):
            raise DatabaseError(f"The models file {name!r} must name classes with a non-empty label other than "
                                f"'unknown' and 'clutter'. Got {label!r} instead.")
        unknown = [k for k in entry if k not in KEYS]
        if unknown:
            raise DatabaseError(f"{where} has the unknown key {unknown[0]!r}. Expected keys: {', '.join(KEYS)}.")
        if "file" not in entry:
            raise DatabaseError(f"{where} is missing the key 'file' (the mesh file, relative to the models folder). "
                                f"Got no such key.")
        for key in ("file", "unit"):
            if key in entry and (not isinstance(entry[key], str) or not entry[key]):
                raise DatabaseError(f"{where} must have a non-empty string {key!r}. Got {entry[key]!r} instead.")
        states_unit = MESH_FORMATS.get(Path(entry["file"]).suffix.lower(), ("", True, None))[1]
        if "unit" not in entry and not states_unit:
            raise DatabaseError(f"{where} is missing the key 'unit' (the mesh file's unit: one of {', '.join(UNITS_M)}; "
                                f"STL, OBJ and PLY files state none). Got no such key.")
        unit = entry.get("unit")
        if unit is not None and unit not in UNITS_M:
            raise DatabaseError(f"{where} has an unknown 'unit': expected one of {', '.join(UNITS_M)}. Got {unit!r} instead.")
        symmetry = parse_symmetry(entry.get("symmetry", "none"), where=f"{where}: 'symmetry'")
        T_mesh_object = None
        if "T_mesh_object" in entry:
            T_mesh_object = _transform(entry["T_mesh_object"], f"{where}: 'T_mesh_object'")
        mesh_path = _inside(root, entry["file"], where)
        mesh, unit_text, number_m = load_mesh(mesh_path, unit, where)
        diagonal = float(np.linalg.norm(np.ptp(mesh.bounds, axis=0)))
        if not MIN_DIAGONAL_M <= diagonal <= MAX_DIAGONAL_M:
            raise DatabaseError(f"{where}: the mesh {str(mesh_path)!r} is {diagonal * 1000:.4g} mm across (bounding-box "
                                f"diagonal) with {unit_text}; expected {MIN_DIAGONAL_M * 1000:g} mm to "
                                f"{MAX_DIAGONAL_M:g} m: check 'unit'.")
        if T_mesh_object is not None:
            T = T_mesh_object.copy()
            T[:3, 3] *= number_m
            mesh.apply_transform(np.linalg.inv(T))  # mesh frame -> object frame
        if not mesh.is_watertight:
            warnings.warn(f"{where}: the mesh {str(mesh_path)!r} is not watertight (holes or open edges); its views "
                          f"still render, but it rests on its canonical x-y plane instead of its most stable face.",
                          NonWatertightMeshWarning, stacklevel=2)
        try:
            models[label] = _stable_rest_order(make_object(label, mesh, symmetry, centre=T_mesh_object is None))
        except SemslamError as exc:
            raise DatabaseError(f"{where}: {exc}") from None
        disagreement = check_declared_symmetry(models[label].mesh, symmetry)
        if disagreement:
            warnings.warn(f"{where}: {disagreement}", ModelSymmetryWarning, stacklevel=2)
    return models


def _stable_rest_order(model: ObjectModel) -> ObjectModel:
    """``model`` with its resting poses sorted by probability rounded to 4 decimals, ties broken by the rounded
    rotation: a mirror-symmetric part has two equally probable faces, and which one comes first must not
    depend on rounding noise (the same mesh in m and in mm must give the same views)."""
    probs = np.asarray(model.resting_probabilities, dtype=float)
    if len(probs) < 2 or len(probs) != len(model.resting_poses):
        return model
    keys = [(-round(float(p), 4), tuple(-np.round(np.asarray(T)[:3, :3].ravel(), 2) + 0.0))
            for p, T in zip(probs, model.resting_poses)]
    order = sorted(range(len(keys)), key=keys.__getitem__)
    return dataclasses.replace(model, resting_poses=[model.resting_poses[i] for i in order],
                               resting_probabilities=probs[order])


def build_models_database(models_dir: str | Path, *, seed: int = 0, n_views: int = 8, n_model_views: int = 8,
                          kinect: KinectConfig | None = None, model_kinect: KinectConfig | None = None,
                          progress: Progress = False, **kwargs: Any):
    """A :class:`~semslam.recognition.ViewDatabase` of the classes of ``models_dir`` (see :func:`read_models`).

    Parameters
    ----------
    seed : int
        Seeds the rendered views and ESF.
    n_views : int
        Recognition views per class, at ``kinect`` (default :data:`~semslam.simulation.kinect.SURVEY_KINECT`).
    n_model_views : int
        Pose-model views per class at ``model_kinect`` (default
        :data:`~semslam.simulation.kinect.POSE_MODEL_KINECT`), in both resting poses when two are about equally
        probable (``tied_rests`` of :func:`models_view_clouds`); 0: pose estimation uses the recognition views.
    progress : bool or callable
        Bars (or ``progress(done, total)`` calls) for the rendering, then for the descriptors.
    **kwargs
        Passed to :func:`~semslam.recognition.build_database` (``vfh_variant``, ``normal_radius_m``,
        ``esf_n_samples``, ``voxel_leaf_m``).
    """
    from .model_database import sensor_database

    return sensor_database(read_models(models_dir), sensor="kinect", seed=seed, n_views=n_views,
                           n_model_views=n_model_views, kinect=kinect, model_kinect=model_kinect, progress=progress,
                           **kwargs)
