"""Object models: triangle meshes of the papers' four PVC pressure fittings, and user meshes.

Every model is a watertight :class:`trimesh.Trimesh` in metres, expressed in the object's **canonical
frame**: the origin is the centre of the mesh's axis-aligned bounding box and the axes are the ones
below, so that ``size_xyz_m`` is the bounding-box extent along x, y and z. The papers (Himri et al.
2018, 2019) give the bounding boxes; the shapes are our reconstruction (hollow PVC fittings with
sockets).

``reducing_tee`` (107 x 74 x 63 mm)
    Main run along x (63 mm sockets, 58 mm body), reduced branch (40 mm) along +y. Symmetry: discrete,
    order 2 about y (a half turn about the branch axis maps the run onto itself).
``reducing_socket`` (57 x 57 x 63 mm; the papers' "57 x 43 x 63" read as large OD x small OD x length)
    A stepped reducer along z: 57 mm OD socket on the -z side, 43 mm OD socket on the +z side.
    Symmetry: continuous about z. This is the one box that differs from the papers' numbers: a
    round fitting cannot be 57 x 43 across.
``elbow`` (76 x 41 x 63 mm)
    A 90-degree knee of 41 mm OD pipe bending in the x-z plane: one leg along +x, the other along +z
    (legs of different lengths, so no rotational symmetry: ``none``).
``ball_valve`` (85 x 125 x 63 mm)
    Body along x (63 mm end sockets and ball housing), stem along +y and a lever handle pointing
    along +x at the top. The lever breaks every rotational symmetry: ``none``.

Stable resting poses (convex-hull facets under the centre of mass, uniform density) are returned as
``T_rest_object`` transforms of a frame whose z axis points **up** with the floor at z = 0, with
their probabilities.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from ..errors import SimulationError
from ..symmetry import Symmetry

#: Labels of the built-in objects, in the papers' order.
BUILTIN_LABELS = ("reducing_tee", "reducing_socket", "elbow", "ball_valve")
_SECTIONS = 48  # facets around a cylinder: 63 mm pipe -> chord error < 0.07 mm


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """A recognisable object class.

    Parameters
    ----------
    label : str
        Class label (``"ball_valve"``).
    mesh : trimesh.Trimesh
        Surface in the object's canonical frame, metres (origin at the bounding-box centre).
    symmetry : Symmetry
        Declared symmetry in the canonical frame.
    size_xyz_m : ndarray of shape (3,)
        Bounding-box extent along the canonical x, y, z axes (metres).
    resting_poses : list of ndarray of shape (4, 4)
        ``T_rest_object`` for each stable resting pose: the object on a floor at z = 0 of a z-up frame,
        most probable first.
    resting_probabilities : ndarray of shape (K,)
        Probability of each resting pose (quasi-static drop model of trimesh), sums to <= 1.
    """

    label: str
    mesh: trimesh.Trimesh
    symmetry: Symmetry
    size_xyz_m: np.ndarray
    resting_poses: list = field(default_factory=list)
    resting_probabilities: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __repr__(self) -> str:
        s = ", ".join(f"{v * 1000:.0f}" for v in self.size_xyz_m)
        return (
            f"ObjectModel({self.label!r}, size_mm=[{s}], symmetry={self.symmetry.kind!r}, faces={len(self.mesh.faces)})"
        )


# ---------------------------------------------------------------------------------------------
# mesh construction helpers (trimesh primitives + manifold3d booleans)
def _cyl(radius_m: float, p0, p1) -> trimesh.Trimesh:
    """Closed cylinder of ``radius_m`` from point ``p0`` to point ``p1``."""
    return trimesh.creation.cylinder(radius=radius_m, segment=np.array([p0, p1], dtype=float), sections=_SECTIONS)


def _box(extents_m, centre_m) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents_m, transform=trimesh.transformations.translation_matrix(centre_m))


def _solid(parts, holes=()) -> trimesh.Trimesh:
    body = trimesh.boolean.union(parts, engine="manifold") if len(parts) > 1 else parts[0]
    if holes:
        body = trimesh.boolean.difference([body, *holes], engine="manifold")
    return body


def _centre(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Translate the mesh so that its bounding-box centre is the origin."""
    mesh = mesh.copy()
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def _reducing_tee() -> trimesh.Trimesh:
    R, r_body, r_br = 0.0315, 0.029, 0.020  # socket, body, branch outer radii
    half, branch_top = 0.0535, 0.0425  # 107 mm run; 74 mm = 31.5 + 42.5
    parts = [
        _cyl(r_body, (-half, 0, 0), (half, 0, 0)),
        _cyl(R, (-half, 0, 0), (-half + 0.030, 0, 0)),
        _cyl(R, (half - 0.030, 0, 0), (half, 0, 0)),
        _cyl(r_br, (0, 0, 0), (0, branch_top, 0)),
    ]
    holes = [
        _cyl(0.0255, (-half - 0.01, 0, 0), (half + 0.01, 0, 0)),
        _cyl(0.0165, (0, 0, 0), (0, branch_top + 0.01, 0)),
    ]
    return _solid(parts, holes)


def _reducing_socket() -> trimesh.Trimesh:
    big, small, length = 0.0285, 0.0215, 0.063
    parts = [_cyl(big, (0, 0, 0), (0, 0, 0.033)), _cyl(small, (0, 0, 0.033), (0, 0, length))]
    holes = [_cyl(0.0250, (0, 0, -0.01), (0, 0, 0.028)), _cyl(0.0180, (0, 0, 0.02), (0, 0, length + 0.01))]
    return _solid(parts, holes)


def _elbow() -> trimesh.Trimesh:
    r, r_in = 0.0205, 0.0170
    leg_x, leg_z = 0.076 - r, 0.063 - r  # extents: r + leg
    parts = [_cyl(r, (0, 0, 0), (leg_x, 0, 0)), _cyl(r, (0, 0, 0), (0, 0, leg_z)),
             trimesh.creation.icosphere(subdivisions=3, radius=r)]
    holes = [_cyl(r_in, (0, 0, 0), (leg_x + 0.01, 0, 0)), _cyl(r_in, (0, 0, 0), (0, 0, leg_z + 0.01)),
             trimesh.creation.icosphere(subdivisions=3, radius=r_in)]
    return _solid(parts, holes)


def _ball_valve() -> trimesh.Trimesh:
    R, half = 0.0315, 0.0425  # 85 mm body
    top = 0.125 - R  # handle top above the run axis
    parts = [
        _cyl(0.028, (-half, 0, 0), (half, 0, 0)),
        _cyl(R, (-half, 0, 0), (-half + 0.022, 0, 0)),
        _cyl(R, (half - 0.022, 0, 0), (half, 0, 0)),
        trimesh.creation.icosphere(subdivisions=3, radius=R),  # ball housing
        _cyl(0.011, (0, 0, 0), (0, top - 0.012, 0)),  # stem
        _box((0.024, 0.012, 0.024), (0, top - 0.018, 0)),  # lever hub
        _box((0.0425, 0.012, 0.018), (0.0425 / 2, top - 0.006, 0)),  # lever along +x
    ]
    holes = [_cyl(0.0255, (-half - 0.01, 0, 0), (-0.012, 0, 0)), _cyl(0.0255, (0.012, 0, 0), (half + 0.01, 0, 0))]
    return _solid(parts, holes)


_BUILDERS = {
    "reducing_tee": (_reducing_tee, Symmetry("discrete", (0.0, 1.0, 0.0), 2)),
    "reducing_socket": (_reducing_socket, Symmetry("continuous", (0.0, 0.0, 1.0))),
    "elbow": (_elbow, Symmetry("none")),
    "ball_valve": (_ball_valve, Symmetry("none")),
}


def _resting(mesh: trimesh.Trimesh, n_max: int = 4) -> tuple[list, np.ndarray]:
    """Stable resting poses on a flat floor: the convex-hull facets onto which the centre of mass
    (uniform density) projects, weighted by the solid angle they subtend from it (the quasi-static
    drop probability without the topple graph). Returns ``T_rest_object`` (z up, floor z = 0)."""
    hull = mesh.convex_hull
    com = np.asarray(mesh.center_mass, dtype=float)
    tri = hull.triangles - com  # (F, 3, 3) relative to the centre of mass
    # solid angle of each hull triangle seen from the centre of mass (Van Oosterom & Strackee)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    den = (
        la * lb * lc
        + np.einsum("ij,ij->i", a, b) * lc
        + np.einsum("ij,ij->i", a, c) * lb
        + np.einsum("ij,ij->i", b, c) * la
    )
    omega = 2.0 * np.arctan2(num, den)
    groups = [list(f) for f in hull.facets]
    grouped = {i for g in groups for i in g}
    groups += [[i] for i in range(len(hull.faces)) if i not in grouped]
    poses, probs = [], []
    for g in groups:
        n = hull.face_normals[g[0]]
        h = -float(np.dot(n, -tri[g[0], 0]))  # distance of the centre of mass below the facet plane
        foot = -h * n  # projection of the centre of mass onto the facet plane (relative)
        inside = False
        for f in g:  # barycentric test on each triangle of the (convex) facet
            p0, p1, p2 = tri[f]
            m = np.column_stack([p1 - p0, p2 - p0])
            uv, *_ = np.linalg.lstsq(m, foot - p0, rcond=None)
            if uv.min() >= -1e-9 and uv.sum() <= 1 + 1e-9:
                inside = True
                break
        if not inside:
            continue
        T = np.eye(4)
        T[:3, :3] = trimesh.geometry.align_vectors(n, [0.0, 0.0, -1.0])[:3, :3]
        T[:3, 3] = -T[:3, :3] @ com
        T[2, 3] += h
        poses.append(T)
        probs.append(float(omega[g].sum()) / (4 * np.pi))
    order = np.argsort(-np.asarray(probs), kind="stable")[:n_max]
    return [poses[i] for i in order], np.asarray(probs)[order]


def make_object(
    label: str, mesh: trimesh.Trimesh, symmetry: Symmetry | None = None, *, centre: bool = True
) -> ObjectModel:
    """Wrap a mesh (metres) as an :class:`ObjectModel`, computing its size and resting poses.

    With ``centre`` the mesh is translated so that its bounding-box centre is the origin (the canonical
    frame's convention); the axes are kept.
    """
    if not isinstance(label, str) or not label or label in ("unknown", "clutter"):
        raise SimulationError(
            f"The 'label' argument of make_object must be a non-empty string other than 'unknown'/'clutter'. Got "
            f"{label!r} instead."
        )
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SimulationError(
            f"The 'mesh' argument of make_object must be a non-empty trimesh.Trimesh. Got {type(mesh).__name__} "
            f"instead."
        )
    symmetry = Symmetry("none") if symmetry is None else symmetry
    if not isinstance(symmetry, Symmetry):
        raise SimulationError(
            f"The 'symmetry' argument of make_object must be a Symmetry or None. Got {type(symmetry).__name__} instead."
        )
    mesh = _centre(mesh) if centre else mesh.copy()
    size = np.ptp(mesh.bounds, axis=0)
    size.setflags(write=False)
    if mesh.is_watertight and mesh.volume > 0:
        poses, probs = _resting(mesh)
    else:  # no centre of mass: rest on the canonical x-y plane (z up)
        T = np.eye(4)
        T[2, 3] = -mesh.bounds[0, 2]
        poses, probs = [T], np.ones(1)
    return ObjectModel(label, mesh, symmetry, size, poses, probs)


@functools.lru_cache(maxsize=1)
def _builtin() -> dict[str, ObjectModel]:
    return {label: make_object(label, build(), sym) for label, (build, sym) in _BUILDERS.items()}


def builtin_objects() -> dict[str, ObjectModel]:
    """The papers' four fittings, keyed by label (``reducing_tee``, ``reducing_socket``, ``elbow``,
    ``ball_valve``). Built once per process (~1 s) and cached; the dict is a fresh copy."""
    return dict(_builtin())


def load_object(path: str | Path, label: str, symmetry: Symmetry | None = None, *, scale: float = 1.0) -> ObjectModel:
    """Load a user mesh (STL, PLY, OBJ, ... anything trimesh reads) as a new object class.

    Parameters
    ----------
    path : path-like
        Mesh file; its units times ``scale`` must be metres (``scale=0.001`` for a file in mm).
    label : str
        Class label for the new object.
    symmetry : Symmetry, optional
        Declared symmetry in the file's axes (after centring), default none.

    Raises
    ------
    SimulationError
        If the file cannot be read or holds no triangles.
    """
    path = Path(path)
    if not path.is_file():
        raise SimulationError(
            f"The 'path' argument of load_object must be an existing mesh file. Got {str(path)!r} (not found) instead."
        )
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types on a bad file
        raise SimulationError(f"Cannot read the mesh file {str(path)!r}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SimulationError(f"The mesh file {str(path)!r} must hold triangles. Got none instead.")
    if not (np.isfinite(scale) and scale > 0):
        raise SimulationError(
            f"The 'scale' argument of load_object must be a finite number > 0. Got {scale!r} instead."
        )
    mesh = mesh.copy()
    mesh.apply_scale(scale)
    return make_object(label, mesh, symmetry)
