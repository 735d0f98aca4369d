"""Reading a user's model file as one triangle mesh in metres (the mesh-file half of
:mod:`semslam.simulation.cad_models`, which describes ``models.toml``, the formats and the units).

Formats (:data:`MESH_FORMATS`, read with trimesh): STL, OBJ and PLY state no unit (``unit`` is required);
COLLADA ``.dae`` (``pycollada``), glTF ``.gltf``/``.glb`` and STEP ``.step``/``.stp`` (``cascadio``) state
theirs, which a ``unit`` in models.toml overrides (:class:`ModelUnitWarning`). A scene holding several
meshes is concatenated into one rigid object (:class:`MultiMeshSceneWarning`).
"""

from __future__ import annotations

import contextlib
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

from ..errors import DatabaseError
from .mesh_orientation import orient_outward

__all__ = [
    "MAX_MESH_FACES",
    "MAX_MESH_FILE_BYTES",
    "MESH_FORMATS",
    "MESH_SUFFIXES",
    "OPTIONAL_READERS",
    "UNITS_M",
    "ModelUnitWarning",
    "MultiMeshSceneWarning",
    "load_mesh",
    "step_length_unit_m",
]

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
#: Triangles of one model read at most: building a database takes ~1.5 GB of memory and ~30 s per million triangles
#: (benchmarks/database.py --only dense-model: 976k triangles 34 s / 1.65 GB, 3.2 million 97 s / 4.9 GB), and
#: recognition gains nothing from a finer tessellation than the scanner's millimetres.
MAX_MESH_FACES = 5_000_000
#: Model files larger than this are refused before they are read (an ASCII STL of ~5 million triangles).
MAX_MESH_FILE_BYTES = 1536 << 20
_DECIMATE = ("decimate it to about a millimetre's detail (MeshLab's quadric edge collapse, or a coarser export "
             "tolerance in your CAD tool): recognition does not use finer detail.")
#: Model files read (suffixes, lower case).
MESH_SUFFIXES = tuple(MESH_FORMATS)
#: Optional readers: module -> (PyPI package, semslam extra that installs it).
OPTIONAL_READERS = {"collada": ("pycollada", "models"), "cascadio": ("cascadio", "step")}
#: Metres per length unit named in a STEP file (``SI_UNIT`` prefixes of the metre; ``CONVERSION_BASED_UNIT`` names).
_STEP_SI_PREFIX_M = {"$": 1.0, ".KILO.": 1e3, ".DECI.": 0.1, ".CENTI.": 0.01, ".MILLI.": 1e-3, ".MICRO.": 1e-6,
                     ".NANO.": 1e-9}
_STEP_NAMED_M = {"INCH": 0.0254, "FOOT": 0.3048, "YARD": 0.9144, "MILE": 1609.344, "MILLIMETRE": 1e-3,
                 "MILLIMETER": 1e-3, "CENTIMETRE": 1e-2, "CENTIMETER": 1e-2, "METRE": 1.0, "METER": 1.0}


class MultiMeshSceneWarning(UserWarning):
    """A COLLADA, glTF or STEP file holds several meshes: concatenated into one rigid object (one class)."""


class ModelUnitWarning(UserWarning):
    """The ``unit`` of models.toml differs from the unit the model file states: the models file wins."""


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


def load_mesh(path: Path, unit: str | None, where: str) -> tuple[trimesh.Trimesh, str, float]:
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
    size = path.stat().st_size
    if size > MAX_MESH_FILE_BYTES:
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} must be at most {MAX_MESH_FILE_BYTES >> 20} MiB "
                            f"({MAX_MESH_FACES:,} triangles at most are read). Got {size / 2**20:,.0f} MiB instead: "
                            f"{_DECIMATE}")
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
    n_faces = sum(len(m.faces) for m in meshes)
    if n_faces > MAX_MESH_FACES:
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} must hold at most {MAX_MESH_FACES:,} triangles. "
                            f"Got {n_faces:,} instead: {_DECIMATE}")
    mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    vertices = np.asarray(mesh.vertices, dtype=float)
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        raise DatabaseError(f"{where}: the mesh file {str(path)!r} must have finite vertex coordinates. Got "
                            f"{int(bad.sum())} vertices with NaN or infinite coordinates instead.")
    mesh = trimesh.Trimesh(vertices * scale, np.asarray(mesh.faces), process=False)
    mesh.merge_vertices()  # STL repeats each triangle's corners: merged, in metres, so m and mm files agree
    mesh.remove_unreferenced_vertices()
    mesh, _ = orient_outward(mesh)  # face normals orient the visibility term's model points
    return mesh, unit_text, number_m
