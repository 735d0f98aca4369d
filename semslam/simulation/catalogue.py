"""A catalogue of twelve procedural pipework parts (DN50-DN100, 10-30 cm) for a harder recognition benchmark.

Every part is a watertight solid in metres built from the primitives of :mod:`semslam.simulation.objects`
(cylinders, boxes, spheres and manifold booleans), centred on its bounding box, with its declared symmetry.
Several pairs are deliberately alike: ``flange`` / ``blind_flange`` (a bored weld-neck flange vs a solid
plate with the same bolt circle), ``elbow_45`` / ``elbow_90``, ``equal_tee`` / ``cross`` / ``reducing_tee``,
``gate_valve`` / ``butterfly_valve`` / ``ball_valve``. Dimensions follow EN 1092-1 PN16 flanges and
EN 10253 fittings loosely (DN50: OD 60.3 mm, DN80: OD 88.9 mm, DN100: OD 114.3 mm).

Canonical frames (after centring):

=================  =================================================================  =========================
part               axes                                                               symmetry
=================  =================================================================  =========================
flange             bore along z, hub on +z, 8 bolt holes                              discrete 8 about z
blind_flange       plate normal z, raised face on +z, 8 bolt holes                    discrete 8 about z
cap                axis z, dome on +z                                                 continuous about z
elbow_45           legs in the x-z plane, at +-67.5 deg from x (45 deg deflection)    discrete 2 about z
elbow_90           legs in the x-z plane, at +-45 deg from x                          discrete 2 about z
equal_tee          run along x, branch along +y (DN80)                                discrete 2 about y
cross              runs along x and y (DN80)                                          discrete 4 about z
reducing_tee       run DN100 along x, branch DN50 along +y                            discrete 2 about y
reducing_socket    concentric reducer DN100 (-z) to DN50 (+z)                         continuous about z
gate_valve         flanged body along x, bonnet and handwheel along +y                discrete 2 about y
ball_valve         body along x, ball housing, stem +y, lever along +x                none
butterfly_valve    wafer ring axis x, neck +y, lever along +x                         none
union              along z, hex nut in the middle                                     discrete 6 about z
=================  =================================================================  =========================
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from ..symmetry import Symmetry
from .objects import ObjectModel, _box, _centre, _cyl, _solid, make_object

_DN = {50: 0.0302, 80: 0.0445, 100: 0.0572}  # outer radii (m)
_WALL = 0.004


def _sphere(radius_m: float, centre=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=radius_m).apply_translation(centre)


def _bolt_holes(pcd_r: float, hole_r: float, z0: float, z1: float, n: int = 8) -> list:
    a = 2 * np.pi * (np.arange(n) + 0.5) / n
    return [
        _cyl(hole_r, (pcd_r * np.cos(t), pcd_r * np.sin(t), z0), (pcd_r * np.cos(t), pcd_r * np.sin(t), z1)) for t in a
    ]


def _frustum(r0: float, r1: float, z0: float, z1: float, sections: int = 48) -> trimesh.Trimesh:
    t = 2 * np.pi * np.arange(sections) / sections
    ring = np.column_stack([np.cos(t), np.sin(t), np.zeros(sections)])
    pts = np.vstack([ring * [r0, r0, 0] + [0, 0, z0], ring * [r1, r1, 0] + [0, 0, z1]])
    return trimesh.convex.convex_hull(pts)


def _flange() -> trimesh.Trimesh:  # DN80 PN16 weld-neck: D 200, k 160, 8 x M16, b 20, hub 105 -> 89
    parts = [_cyl(0.100, (0, 0, 0), (0, 0, 0.020)), _frustum(0.0525, _DN[80], 0.020, 0.062)]
    holes = [_cyl(_DN[80] - _WALL, (0, 0, -0.01), (0, 0, 0.08)), *_bolt_holes(0.080, 0.009, -0.01, 0.03)]
    return _solid(parts, holes)


def _blind_flange() -> trimesh.Trimesh:  # DN80 PN16 blind: D 200, b 20, raised face 138 x 3
    parts = [_cyl(0.100, (0, 0, 0), (0, 0, 0.022)), _cyl(0.069, (0, 0, 0.021), (0, 0, 0.025))]
    return _solid(parts, _bolt_holes(0.080, 0.009, -0.01, 0.03))


def _cap() -> trimesh.Trimesh:  # DN100 cap: 114 x 114 x 90 (straight skirt + dome)
    R = _DN[100]
    dome = _sphere(R).apply_scale((1.0, 1.0, 0.6))
    parts = [_cyl(R, (0, 0, 0), (0, 0, 0.056)), dome.apply_translation((0, 0, 0.056))]
    inner = _sphere(R - _WALL).apply_scale((1.0, 1.0, 0.55)).apply_translation((0, 0, 0.056))
    return _solid(parts, [_cyl(R - _WALL, (0, 0, -0.01), (0, 0, 0.056)), inner])


def _elbow(deflection_deg: float, leg_m: float) -> trimesh.Trimesh:
    """DN80 elbow: two equal legs from the knee at +-(90 - deflection / 2) deg from x in the x-z plane."""
    r = _DN[80]
    t = np.radians(90.0 - deflection_deg / 2)
    ends = [(leg_m * np.cos(t), 0, leg_m * np.sin(t)), (-leg_m * np.cos(t), 0, leg_m * np.sin(t))]
    parts = [_cyl(r, (0, 0, 0), e) for e in ends] + [_sphere(r)]
    e2 = [np.array(e) * 1.1 for e in ends]
    holes = [_cyl(r - _WALL, (0, 0, 0), e) for e in e2] + [_sphere(r - _WALL)]
    return _solid(parts, holes)


def _tee(r_run: float, r_branch: float, half_run: float, branch: float, both: bool = False) -> trimesh.Trimesh:
    parts = [_cyl(r_run, (-half_run, 0, 0), (half_run, 0, 0)), _cyl(r_branch, (0, 0, 0), (0, branch, 0))]
    holes = [_cyl(r_run - _WALL, (-half_run - 0.01, 0, 0), (half_run + 0.01, 0, 0)),
             _cyl(r_branch - _WALL, (0, 0, 0), (0, branch + 0.01, 0))]
    if both:
        parts.append(_cyl(r_branch, (0, 0, 0), (0, -branch, 0)))
        holes.append(_cyl(r_branch - _WALL, (0, 0, 0), (0, -branch - 0.01, 0)))
    return _solid(parts, holes)


def _reducing_socket() -> trimesh.Trimesh:  # EN 10253 concentric reducer DN100 x DN50, L 102
    R, r = _DN[100], _DN[50]
    parts = [_cyl(R, (0, 0, 0), (0, 0, 0.030)), _frustum(R, r, 0.030, 0.077), _cyl(r, (0, 0, 0.077), (0, 0, 0.102))]
    holes = [_cyl(R - _WALL, (0, 0, -0.01), (0, 0, 0.030)), _frustum(R - _WALL, r - _WALL, 0.029, 0.078),
             _cyl(r - _WALL, (0, 0, 0.07), (0, 0, 0.11))]
    return _solid(parts, holes)


def _flanged_ends(half: float, r_bore: float) -> list:
    return [_cyl(0.0825, (s * half, 0, 0), (s * (half - 0.018), 0, 0)) for s in (-1, 1)]


def _gate_valve() -> trimesh.Trimesh:  # DN50 PN16 gate valve: face-to-face 178 mm, handwheel 160 mm at 260 mm
    half = 0.089
    parts = [_cyl(_DN[50], (-half, 0, 0), (half, 0, 0)), *_flanged_ends(half, _DN[50]),
             _cyl(0.048, (0, -0.03, 0), (0, 0.05, 0)).apply_scale((1.0, 1.0, 0.7)),  # flattened body
             _cyl(0.030, (0, 0.04, 0), (0, 0.150, 0)), _cyl(0.010, (0, 0.150, 0), (0, 0.190, 0)),  # bonnet, stem
             trimesh.creation.torus(0.070, 0.008, major_sections=48, minor_sections=12).apply_transform(
                 trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0))).apply_translation((0, 0.180, 0)),
             _box((0.144, 0.010, 0.012), (0, 0.180, 0)), _box((0.012, 0.010, 0.144), (0, 0.180, 0))]  # spokes
    return _solid(parts, [_cyl(_DN[50] - _WALL, (-half - 0.01, 0, 0), (half + 0.01, 0, 0))])


def _ball_valve() -> trimesh.Trimesh:  # DN50 threaded ball valve: 120 mm long, lever 160 mm
    half, R = 0.060, 0.040
    parts = [_cyl(_DN[50] - 0.002, (-half, 0, 0), (half, 0, 0)), _sphere(R),
             _cyl(0.011, (0, 0, 0), (0, 0.070, 0)), _box((0.030, 0.014, 0.030), (0, 0.062, 0)),
             _box((0.160, 0.010, 0.022), (0.065, 0.074, 0))]
    return _solid(parts, [_cyl(0.024, (-half - 0.01, 0, 0), (half + 0.01, 0, 0))])


def _butterfly_valve() -> trimesh.Trimesh:  # DN80 wafer butterfly: ring 150 x 46, neck, lever 220 mm
    parts = [_cyl(0.075, (-0.023, 0, 0), (0.023, 0, 0)), _cyl(0.016, (0, 0.06, 0), (0, 0.135, 0)),
             _box((0.060, 0.012, 0.060), (0, 0.140, 0)), _box((0.220, 0.014, 0.026), (0.085, 0.150, 0))]
    holes = [_cyl(_DN[80] - _WALL, (-0.04, 0, 0), (0.04, 0, 0))]
    disc = _cyl(0.040, (-0.004, 0, 0), (0.004, 0, 0)).apply_transform(  # the disc, half open
        trimesh.transformations.rotation_matrix(np.pi / 4, (0, 1, 0)))
    return _solid([_solid(parts, holes), disc])


def _union() -> trimesh.Trimesh:  # DN50 union: 2 x threaded ends, hex nut 90 AF, length 110
    hexnut = trimesh.creation.cylinder(radius=0.048, height=0.036, sections=6)
    parts = [_cyl(0.036, (0, 0, -0.055), (0, 0, 0.055)), hexnut, _cyl(0.042, (0, 0, -0.030), (0, 0, -0.018))]
    return _solid(parts, [_cyl(0.026, (0, 0, -0.07), (0, 0, 0.07))])


_Z, _Y = (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)
_BUILDERS = {
    "flange": (_flange, Symmetry("discrete", _Z, 8)),
    "blind_flange": (_blind_flange, Symmetry("discrete", _Z, 8)),
    "cap": (_cap, Symmetry("continuous", _Z)),
    "elbow_45": (lambda: _elbow(45.0, 0.110), Symmetry("discrete", _Z, 2)),
    "elbow_90": (lambda: _elbow(90.0, 0.110), Symmetry("discrete", _Z, 2)),
    "equal_tee": (lambda: _tee(_DN[80], _DN[80], 0.110, 0.110), Symmetry("discrete", _Y, 2)),
    "cross": (lambda: _tee(_DN[80], _DN[80], 0.110, 0.110, both=True), Symmetry("discrete", _Z, 4)),
    "reducing_tee": (lambda: _tee(_DN[100], _DN[50], 0.127, 0.125), Symmetry("discrete", _Y, 2)),
    "reducing_socket": (_reducing_socket, Symmetry("continuous", _Z)),
    "gate_valve": (_gate_valve, Symmetry("discrete", _Y, 2)),
    "ball_valve": (_ball_valve, Symmetry("none")),
    "butterfly_valve": (_butterfly_valve, Symmetry("none")),
    "union": (_union, Symmetry("discrete", _Z, 6)),
}
#: Labels of the catalogue, in a fixed order.
CATALOGUE_LABELS = tuple(_BUILDERS)


@functools.lru_cache(maxsize=1)
def _catalogue() -> dict[str, ObjectModel]:
    return {label: make_object(label, _centre(build()), sym) for label, (build, sym) in _BUILDERS.items()}


def catalogue_objects() -> dict[str, ObjectModel]:
    """The catalogue's parts keyed by label (see the module docstring); built once per process and cached,
    the dict is a fresh copy."""
    return dict(_catalogue())
