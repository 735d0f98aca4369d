"""Users' CAD models as object classes of a view database (``semslam db build --models MODELS_DIR``).

``MODELS_DIR`` holds the model files and ``models.toml``, one table per class, the table's name being the
class label::

    [spool]
    file = "spool.stl"          # relative to MODELS_DIR
    unit = "mm"                 # the file's unit: m, mm, cm or inch (required for STL, OBJ and PLY, which state
                                # none; optional for COLLADA, glTF and STEP, which do, and then it overrides them)
    symmetry = "none"           # optional, default "none"; "discrete:2:z" (order 2 about the object's z axis),
                                # "continuous:z" (axisymmetric about z); axes x, y or z of the object frame
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

import contextlib
import dataclasses
import importlib.util
import math
import os
import re
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .._progress import Progress, progress_steps
from .._tables import read_table
from .._validation import as_rng, check_int
from ..cloud import PointCloud
from ..errors import DatabaseError, SemslamError
from ..symmetry import Symmetry
from .config import KinectConfig
from .objects import ObjectModel, make_object

__all__ = [
    "MESH_FORMATS",
    "MESH_SUFFIXES",
    "MODELS_FILE",
    "UNITS_M",
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
#: Metres per unit of the mesh files.
UNITS_M = {"m": 1.0, "mm": 0.001, "cm": 0.01, "inch": 0.0254}
#: Model file formats read: suffix -> (format name, whether the file states its unit, the optional module
#: trimesh needs to read it or None).
MESH_FORMATS = {
    ".stl": ("STL", False, None), ".obj": ("OBJ", False, None), ".ply": ("PLY", False, None),
    ".dae": ("COLLADA", True, "collada"),
    ".gltf": ("glTF", True, None), ".glb": ("glTF", True, None),
    ".step": ("STEP", True, "cascadio"), ".stp": ("STEP", True, "cascadio"),
}
#: Model files read (suffixes, lower case).
MESH_SUFFIXES = tuple(MESH_FORMATS)
#: Optional readers: module -> (PyPI package, semslam extra that installs it).
OPTIONAL_READERS = {"collada": ("pycollada", "models"), "cascadio": ("cascadio", "step")}
#: Metres per length unit named in a STEP file (``SI_UNIT`` prefixes of the metre; ``CONVERSION_BASED_UNIT`` names).
_STEP_SI_PREFIX_M = {"$": 1.0, ".KILO.": 1e3, ".DECI.": 0.1, ".CENTI.": 0.01, ".MILLI.": 1e-3, ".MICRO.": 1e-6,
                     ".NANO.": 1e-9}
_STEP_NAMED_M = {"INCH": 0.0254, "FOOT": 0.3048, "YARD": 0.9144, "MILE": 1609.344, "MILLIMETRE": 1e-3,
                 "MILLIMETER": 1e-3, "CENTIMETRE": 1e-2, "CENTIMETER": 1e-2, "METRE": 1.0, "METER": 1.0}
#: Keys of a class table.
KEYS = ("file", "unit", "symmetry", "T_mesh_object")
#: Plausible object sizes: bounding-box diagonal, metres (after the unit conversion).
MIN_DIAGONAL_M, MAX_DIAGONAL_M = 0.005, 20.0
#: Tolerance on the rotation block of ``T_mesh_object`` (hand-typed matrices: 4 decimals), re-orthonormalised.
ROTATION_TOL = 1e-3
#: Resting poses this close in probability (second / first) are both used for the pose-model views.
TIE_RATIO = 0.9

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class NonWatertightMeshWarning(UserWarning):
    """A model mesh has holes: accepted, but without a centre of mass (see the module docstring)."""


class MultiMeshSceneWarning(UserWarning):
    """A COLLADA, glTF or STEP file holds several meshes: concatenated into one rigid object (one class)."""


class ModelUnitWarning(UserWarning):
    """The ``unit`` of models.toml differs from the unit the model file states: the models file wins."""


def parse_symmetry(text: Any, *, where: str = "The symmetry") -> Symmetry:
    """``"none"``, ``"discrete:ORDER:AXIS"`` or ``"continuous:AXIS"`` (AXIS one of x, y, z) as a
    :class:`~semslam.symmetry.Symmetry`; ``where`` names the value in the error."""
    expected = "'none', 'discrete:ORDER:AXIS' (ORDER an integer >= 2) or 'continuous:AXIS', AXIS one of x, y, z"
    if not isinstance(text, str):
        raise DatabaseError(f"{where} must be a string: {expected}. Got {text!r} instead.")
    parts = [p.strip() for p in text.strip().lower().split(":")]
    if parts == ["none"]:
        return Symmetry("none")
    if len(parts) == 3 and parts[0] == "discrete" and parts[2] in _AXES and parts[1].isdigit() and int(parts[1]) >= 2:
        return Symmetry("discrete", _AXES[parts[2]], int(parts[1]))
    if len(parts) == 2 and parts[0] == "continuous" and parts[1] in _AXES:
        return Symmetry("continuous", _AXES[parts[1]])
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
                            f"tolerance {ROTATION_TOL:g}). Got max |R^T R - I| = {ortho:.3g} and det = {det:.6g} instead.")
    U, _, Vt = np.linalg.svd(R)
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return T


def _formats_text() -> str:
    names = dict.fromkeys(name for name, _, _ in MESH_FORMATS.values())
    return f"{', '.join(names)} ({', '.join(MESH_SUFFIXES)})"


def _has_module(name: str) -> bool:
    """Whether ``name`` can be imported (without importing it; a ``None`` in ``sys.modules`` blocks it)."""
    if name in sys.modules:
        return sys.modules[name] is not None
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


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


def step_length_unit_m(path: str | Path) -> float | None:
    """Metres per length unit of the STEP file ``path`` (its first ``LENGTH_UNIT``: an ``SI_UNIT`` of the metre
    with its prefix, or a ``CONVERSION_BASED_UNIT`` such as ``'INCH'``), or None when it states none readable."""
    text = Path(path).read_text(encoding="latin-1", errors="replace")
    for match in re.finditer(r"=\s*\(([^;]*?LENGTH_UNIT\s*\(\s*\)[^;]*);", text, flags=re.S | re.I):
        entity = re.sub(r"\s+", "", match.group(1)).upper()
        si = re.search(r"SI_UNIT\(([^,]*),\.METRE\.\)", entity)
        if si and si.group(1) in _STEP_SI_PREFIX_M:
            return _STEP_SI_PREFIX_M[si.group(1)]
        named = re.search(r"CONVERSION_BASED_UNIT\('([^']*)'", entity)
        if named and named.group(1).strip().upper() in _STEP_NAMED_M:
            return _STEP_NAMED_M[named.group(1).strip().upper()]
    return None


def _file_unit_m(scene: Any, name: str, path: Path) -> tuple[float | None, str]:
    """Metres per number written in the COLLADA/glTF/STEP file ``path`` as the file states it (None when
    unreadable), and its description for messages."""
    if name == "glTF":
        return 1.0, "glTF's metres"
    if name == "STEP":
        unit_m = step_length_unit_m(path)
        return unit_m, ("an unreadable STEP length unit" if unit_m is None else f"the STEP length unit {unit_m:g} m")
    units = str(getattr(scene, "units", None) or "meters")  # trimesh: "meters" or "<unitmeter> * meters"
    m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*\*\s*meters?\s*", units)
    unit_m = float(m.group(1)) if m else (1.0 if units.strip() in ("meters", "meter", "m") else None)
    if unit_m is None or not math.isfinite(unit_m) or unit_m <= 0:
        return None, f"the unreadable COLLADA unit {units!r}"
    return unit_m, f'the COLLADA <unit meter="{unit_m:g}">'


@contextlib.contextmanager
def _native_output_captured():
    """Yields a list filled, on exit, with the lines native code (OpenCASCADE) wrote to file descriptors 1 and 2
    meanwhile, instead of letting them reach the terminal."""
    lines: list[str] = []
    saved = []
    with tempfile.TemporaryFile(mode="w+b") as sink:
        try:
            for fd in (1, 2):
                saved.append((fd, os.dup(fd)))
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, _ in saved:
                os.dup2(sink.fileno(), fd)
        except OSError:  # no usable descriptors (embedded interpreter): leave the output alone
            pass
        try:
            yield lines
        finally:
            for fd, copy in saved:
                os.dup2(copy, fd)
                os.close(copy)
            sink.seek(0)
            text = re.sub(r"\x1b\[[0-9;]*m", "", sink.read().decode("utf-8", errors="replace"))
            lines.extend(line.strip(" *") for line in text.splitlines() if line.strip(" *"))


def _load_scene(path: Path, name: str, where: str) -> tuple[list[trimesh.Trimesh], Any]:
    """The triangle meshes of a COLLADA/glTF/STEP file placed by its scene graph (in the file's numbers)."""
    load = getattr(trimesh, "load_scene", None)
    native: list[str] = []
    try:
        if name == "STEP":  # OpenCASCADE prints its parse errors: kept for the message
            with _native_output_captured() as native:
                scene = load(path, process=False) if load else trimesh.load(path, force="scene", process=False)
        else:
            scene = load(path, process=False) if load else trimesh.load(path, force="scene", process=False)
    except Exception as exc:  # trimesh and its readers raise many types on a bad file
        reason = native[0] if native else (str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        raise DatabaseError(f"{where}: cannot read the {name} file {str(path)!r}: "
                            f"{'OpenCASCADE: ' if native else ''}{reason}") from None
    if isinstance(scene, trimesh.Trimesh):
        return ([scene] if len(scene.faces) else []), scene
    meshes = []
    for node in scene.graph.nodes_geometry:
        T, geometry_name = scene.graph[node]
        geometry = scene.geometry.get(geometry_name)
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            meshes.append(trimesh.Trimesh(np.asarray(geometry.vertices, dtype=float), np.asarray(geometry.faces),
                                          process=False).apply_transform(np.asarray(T, dtype=float)))
    return meshes, scene


def _load_mesh(path: Path, unit: str | None, where: str) -> tuple[trimesh.Trimesh, str, float]:
    """The triangles of ``path`` in metres (vertices merged), checked for emptiness and non-finite values, the
    unit used (for messages) and metres per unit of the file's numbers (for ``T_mesh_object``). ``unit``
    (models.toml) overrides the unit the file states."""
    if not path.is_file():
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} does not exist or is not a regular file.")
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} is in a format semslam does not read; expected "
                            f"one of {_formats_text()}. Got {path.suffix or 'no suffix'!r} instead.")
    name, states_unit, module = MESH_FORMATS[suffix]
    if module is not None and not _has_module(module):
        package, extra = OPTIONAL_READERS[module]
        raise DatabaseError(f"{where}: reading the {name} file {str(path)!r} needs the optional reader {package!r}, "
                            f"which is not installed: pip install 'semslam[{extra}]' (or pip install {package}).")
    if not states_unit:
        try:
            mesh = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types on a bad file
            raise DatabaseError(f"{where}: cannot read the mesh file {str(path)!r}: {exc}") from None
        meshes = [mesh] if isinstance(mesh, trimesh.Trimesh) and len(mesh.faces) else []
        assert unit is not None  # read_models requires it for these formats
        scale, unit_text, number_m = UNITS_M[unit], f"unit {unit!r}", UNITS_M[unit]
    else:
        meshes, scene = _load_scene(path, name, where)
        file_unit_m, file_unit_text = _file_unit_m(scene, name, path)
        # trimesh gives COLLADA's and glTF's numbers as written; OpenCASCADE converts STEP's to metres
        loaded_per_number = file_unit_m if name == "STEP" else 1.0
        if unit is not None:
            if loaded_per_number is None:
                raise DatabaseError(f"{where}: 'unit' cannot override the unit of the STEP file {str(path)!r}: its "
                                    f"length unit is unreadable. Remove 'unit' to use OpenCASCADE's conversion.")
            number_m, unit_text = UNITS_M[unit], f"unit {unit!r} (from the models file)"
            scale = number_m / loaded_per_number
            if file_unit_m is not None and not math.isclose(number_m, file_unit_m, rel_tol=1e-6):
                warnings.warn(f"{where}: the models file's 'unit' = {unit!r} ({number_m:g} m) overrides "
                              f"{file_unit_text} of {str(path)!r}.", ModelUnitWarning, stacklevel=3)
        elif name == "STEP":  # already metres (an unreadable unit: OpenCASCADE's default conversion)
            number_m, scale, unit_text = file_unit_m or 1.0, 1.0, f"{file_unit_text} (from the file)"
        elif file_unit_m is None:
            raise DatabaseError(f"{where}: the {name} file {str(path)!r} states {file_unit_text}; give the class "
                                f"a 'unit' (one of {', '.join(UNITS_M)}).")
        else:
            number_m = scale = file_unit_m
            unit_text = f"{file_unit_text} (from the file)"
        if len(meshes) > 1:
            warnings.warn(f"{where}: the {name} file {str(path)!r} holds {len(meshes)} meshes: concatenated into one "
                          f"rigid object (one class); put each object in its own file to make separate classes.",
                          MultiMeshSceneWarning, stacklevel=3)
    if not meshes:
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} must hold triangles. Got none instead (empty mesh).")
    mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    vertices = np.asarray(mesh.vertices, dtype=float)
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} must have finite vertex coordinates. Got "
                            f"{int(bad.sum())} vertices with NaN or infinite coordinates instead.")
    mesh = trimesh.Trimesh(vertices * scale, np.asarray(mesh.faces), process=False)
    mesh.merge_vertices()  # STL repeats each triangle's corners: merged, in metres, so m and mm files agree
    mesh.remove_unreferenced_vertices()
    return mesh, unit_text, number_m


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
        mesh, unit_text, number_m = _load_mesh(mesh_path, unit, where)
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


def models_view_clouds(models: dict[str, ObjectModel], *, seed: int | np.random.Generator | None = 0, n_views: int = 8,
                       config: KinectConfig | None = None, progress: Progress = False, tied_rests: bool = False,
                       ) -> tuple[list[tuple[str, str, PointCloud]], dict[str, dict]]:
    """The view-database inputs for ``models`` (as :func:`~semslam.simulation.kinect.builtin_view_clouds`).

    Each object is seen in its most probable resting pose, at azimuths ``360 * k / n_views`` degrees. With
    ``tied_rests``, an object whose second resting pose is about as probable (within :data:`TIE_RATIO`: a
    mirror-symmetric part lies on either face) is seen in both, alternately (even ``k`` in the first, odd
    ``k`` in the second, view id suffixed ``_rest1``): the pose-model views then cover both faces, which
    keeps a near-symmetric part (the elbow, whose legs differ by 13 mm) from being fitted turned over.

    Returns
    -------
    views : list of (label, view_id, PointCloud)
        ``n_views`` Kinect views per class, points in the object's canonical frame (metres), the camera
        centre as ``viewpoint_xyz_m``.
    classes : dict
        Per label ``{"symmetry": Symmetry, "size_xyz_m": ndarray (3,)}``.
    """
    from .kinect import kinect_view

    caller = "models_view_clouds"
    if not isinstance(models, dict) or not models or not all(isinstance(m, ObjectModel) for m in models.values()):
        raise DatabaseError(f"The 'models' argument of {caller} must be a non-empty dict label -> ObjectModel. "
                            f"Got {models!r:.60} instead.")
    n = check_int("n_views", n_views, caller=caller, minimum=1, maximum=360)
    cfg = config or KinectConfig()
    rng = as_rng(seed, caller=caller)
    views, classes = [], {}
    with progress_steps(progress, n * len(models), "render views", "view") as step:
        for label, model in models.items():
            rests = _tied_rests(model) if tied_rests else [0]
            mesh = model.mesh.copy().apply_transform(model.resting_poses[0])
            radius = float(np.linalg.norm(mesh.vertices - mesh.bounds.mean(axis=0), axis=1).max())
            if cfg.distance_m <= radius:
                raise DatabaseError(f"The Kinect distance {cfg.distance_m:g} m must exceed the bounding radius of the "
                                    f"class {label!r} ({radius:.3g} m). Give a larger distance (--kinect-distance, "
                                    f"--model-distance).")
            for k in range(n):
                az = 2 * np.pi * k / n
                rest = rests[k % len(rests)]
                posed = model if rest == 0 else dataclasses.replace(model, resting_poses=[model.resting_poses[rest]])
                cloud = kinect_view(posed, az, config=cfg, seed=rng)
                if cloud.n_points == 0:
                    raise DatabaseError(f"The Kinect view {k} of the class {label!r} saw no point (distance "
                                        f"{cfg.distance_m:g} m, elevation {math.degrees(cfg.elevation_rad):g} deg).")
                views.append((label, f"{label}_az{round(np.degrees(az)):03d}" + (f"_rest{rest}" if rest else ""), cloud))
                step()
            classes[label] = {"symmetry": model.symmetry, "size_xyz_m": np.array(model.size_xyz_m)}
    return views, classes


def resting_up_objects(models: dict) -> dict[str, list]:
    """``{label: up}``: each class's up direction in its object frame when it rests on a level floor in its most
    probable resting pose, ``R_rest_object^T (0, 0, 1)``. Classes whose most probable rest is tied with another
    (a part that lies on either of two faces) are left out: their up is not one direction. Recorded in a
    database as ``params["up_object"]`` (:meth:`~semslam.recognition.ViewDatabase.up_object`), it lets the
    pipeline pose them upright when the scan's up is known (``recognize --up``, ``run --up-from-attitude``)."""
    out = {}
    for label, model in models.items():
        if not model.resting_poses or _tied_rests(model) != [0]:
            continue
        up = np.asarray(model.resting_poses[0], dtype=float)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        out[label] = [float(v) for v in up / np.linalg.norm(up)]
    return out


def with_resting_up(db: Any, models: dict) -> Any:
    """``db`` with :func:`resting_up_objects` of ``models`` recorded in its ``params["up_object"]``."""
    ups = {k: v for k, v in resting_up_objects(models).items() if k in db.classes}
    if ups:
        object.__setattr__(db, "params", {**db.params, "up_object": ups})
    return db


def _tied_rests(model: ObjectModel) -> list[int]:
    """Indices of the resting poses of ``model`` within TIE_RATIO of the most probable one (at most 2)."""
    p = np.asarray(model.resting_probabilities, dtype=float)
    if len(model.resting_poses) < 2 or len(p) < 2 or p[0] <= 0:
        return [0]
    return [0, 1] if p[1] >= TIE_RATIO * p[0] else [0]


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
    from ..recognition import build_database
    from .kinect import POSE_MODEL_KINECT, SURVEY_KINECT

    n_model = check_int("n_model_views", n_model_views, caller="build_models_database", minimum=0, maximum=360)
    models = read_models(models_dir)
    views, classes = models_view_clouds(models, seed=seed, n_views=n_views, config=kinect or SURVEY_KINECT,
                                        progress=progress)
    model_views = None
    if n_model:
        model_views, _ = models_view_clouds(models, seed=seed, n_views=n_model,
                                            config=model_kinect or POSE_MODEL_KINECT, progress=progress, tied_rests=True)
    return with_resting_up(build_database(views, classes, seed=seed, model_views=model_views, progress=progress,
                                          **kwargs), models)
