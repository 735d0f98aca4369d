"""The world: a CIRS-like tank (flat floor, sloped sides), the four fittings lying on its floor, and
optional clutter that is not in the database (rocks, pipe offcuts).

World frame NED: origin at the water surface above the tank's centre, x (north) along the tank's long
side, z down. The floor is at z = ``tank_depth_m`` inside the flat rectangle and rises linearly over
``slope_run_m`` to the rim (z = 0) at the walls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..geometry import RigidTransform, rotation_from_rpy
from .config import WorldConfig
from ..dataset import ObjectTruth
from .objects import ObjectModel, _resting

#: Order in which the vehicle visits the fittings (the papers' route: socket, elbow, tee, valve).
ROUTE_ORDER = ("reducing_socket", "elbow", "reducing_tee", "ball_valve")


@dataclass(frozen=True, eq=False)
class World:
    """A built world.

    Attributes
    ----------
    config : WorldConfig
    objects : list of ObjectTruth
        Placed objects (fittings first, in :data:`ROUTE_ORDER`, then clutter).
    scene : trimesh.Trimesh
        Tank + every object, world frame (metres).
    face_instance : ndarray of shape (F,), int
        For each scene face, the index of its object in ``objects`` (-1 for the tank).
    """

    config: WorldConfig
    objects: list
    scene: trimesh.Trimesh
    face_instance: np.ndarray

    def floor_depth_m(self, north_m, east_m) -> np.ndarray:
        return floor_depth_m(self.config, north_m, east_m)


def _slope_excess(cfg: WorldConfig, north_m, east_m) -> np.ndarray:
    """How far (m, horizontally) a point lies outside the flat floor (0 inside)."""
    hx, hy = cfg.tank_length_m / 2 - cfg.slope_run_m, cfg.tank_width_m / 2 - cfg.slope_run_m
    dx = np.maximum(np.abs(np.asarray(north_m, dtype=float)) - hx, 0.0)
    dy = np.maximum(np.abs(np.asarray(east_m, dtype=float)) - hy, 0.0)
    return np.maximum(dx, dy)


def floor_depth_m(cfg: WorldConfig, north_m, east_m) -> np.ndarray:
    """Depth (world z, metres) of the tank floor below horizontal position(s) (vectorised)."""
    excess = _slope_excess(cfg, north_m, east_m)
    if cfg.slope_run_m == 0:
        return np.full(np.shape(excess), cfg.tank_depth_m)
    return cfg.tank_depth_m * (1.0 - np.clip(excess / cfg.slope_run_m, 0.0, 1.0))


def over_slope(cfg: WorldConfig, north_m, east_m) -> np.ndarray:
    """True where the floor below is sloped (outside the flat rectangle)."""
    return _slope_excess(cfg, north_m, east_m) > 1e-9


def tank_mesh(cfg: WorldConfig) -> trimesh.Trimesh:
    """Floor rectangle and four sloped sides (a frustum open at the top), world NED."""
    L, W, D, s = cfg.tank_length_m / 2, cfg.tank_width_m / 2, cfg.tank_depth_m, cfg.slope_run_m
    inner = [(L - s, W - s), (-(L - s), W - s), (-(L - s), -(W - s)), (L - s, -(W - s))]
    outer = [(L, W), (-L, W), (-L, -W), (L, -W)]
    v = np.array([(x, y, D) for x, y in inner] + [(x, y, 0.0) for x, y in outer])
    faces = [(0, 1, 2), (0, 2, 3)]
    for i in range(4):
        j = (i + 1) % 4
        faces += [(i, 4 + i, 4 + j), (i, 4 + j, j)]
    return trimesh.Trimesh(v, np.array(faces), process=False)


def _T_world_rest(north_m: float, east_m: float, depth_m: float, yaw_rad: float) -> np.ndarray:
    """Rest frame (z up, floor z = 0) placed on the floor: translate, yaw, then flip z up -> NED down."""
    T = np.eye(4)
    T[:3, :3] = rotation_from_rpy(0.0, 0.0, yaw_rad) @ np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (north_m, east_m, depth_m)
    return T


#: How far inside the flat floor's edge an object pushed off the sloped sides ends (m).
FLOOR_EDGE_MARGIN_M = 0.005


def _on_flat_floor(cfg: WorldConfig, vertices_object: np.ndarray, T_rest_object: np.ndarray, north_m: float,
                   east_m: float, yaw_rad: float) -> tuple[float, float]:
    """``(north_m, east_m)`` moved towards the tank's centre just enough that the whole object, resting in
    ``T_rest_object`` at that yaw, lies on the flat floor (unchanged when it does already). An object placed across
    the foot of a sloped side would otherwise reach into the slope, a scene no scan of a real tank shows (its right
    pose then lies behind the slope's surface, which the pipeline's floor check rightly refuses)."""
    hx, hy = cfg.tank_length_m / 2 - cfg.slope_run_m, cfg.tank_width_m / 2 - cfg.slope_run_m
    T = _T_world_rest(0.0, 0.0, 0.0, yaw_rad) @ T_rest_object
    V = vertices_object @ T[:3, :3].T + T[:3, 3]  # about the placement point
    out = [float(north_m), float(east_m)]
    for axis, half in ((0, hx), (1, hy)):
        lo, hi = out[axis] + V[:, axis].min(), out[axis] + V[:, axis].max()
        if hi > half:
            out[axis] -= hi - half + FLOOR_EDGE_MARGIN_M
        elif lo < -half:
            out[axis] += -half - lo + FLOOR_EDGE_MARGIN_M
    return out[0], out[1]


def _rock(rng: np.random.Generator) -> trimesh.Trimesh:
    radii = rng.uniform([0.05, 0.04, 0.025], [0.12, 0.09, 0.06])
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    pts = d * radii * rng.uniform(0.8, 1.0, (40, 1))
    return trimesh.convex.convex_hull(pts)


def _offcut(rng: np.random.Generator) -> trimesh.Trimesh:
    r = rng.uniform(0.02, 0.045)
    length = rng.uniform(0.12, 0.35)
    outer = trimesh.creation.cylinder(radius=r, height=length, sections=32)
    inner = trimesh.creation.cylinder(radius=r * 0.85, height=length + 0.02, sections=32)
    tube = trimesh.boolean.difference([outer, inner], engine="manifold")
    return tube.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))  # axis along x: lying


def build_world(config: WorldConfig, models: dict[str, ObjectModel], *, seed: int | np.random.Generator = 0) -> World:
    """Place the fittings (and clutter if ``config.clutter``) on the tank floor.

    The fittings in ``models`` whose labels are in :data:`ROUTE_ORDER` go to the corners of the square
    (in that order, counter-clockwise seen from above: +north, then +east ...), other user models
    are spread along the square's diagonals. Each rests in its most probable pose with a random yaw, wholly on the
    flat floor (moved towards the centre, by as little as needed, when it would reach into a sloped side).
    """
    from .._validation import as_rng

    rng = as_rng(seed, caller="build_world")
    cn, ce = config.objects_centre_ne_m
    h = config.object_spacing_m / 2
    corners = [(cn - h, ce - h), (cn + h, ce - h), (cn + h, ce + h), (cn - h, ce + h)]
    labels = [lab for lab in ROUTE_ORDER if lab in models] + [lab for lab in models if lab not in ROUTE_ORDER]
    meshes, truths = [], []
    for i, label in enumerate(labels):
        model = models[label]
        if i < 4:
            n, e = corners[i]
        else:  # extra user objects: inside the square
            a = 2 * np.pi * (i - 4) / max(1, len(labels) - 4)
            n, e = cn + 0.5 * h * np.cos(a), ce + 0.5 * h * np.sin(a)
        n, e = (n, e) + rng.uniform(-config.placement_jitter_m, config.placement_jitter_m, 2)
        yaw = rng.uniform(-np.pi, np.pi)
        n, e = _on_flat_floor(config, model.mesh.vertices, model.resting_poses[0], n, e, yaw)
        T = _T_world_rest(n, e, float(floor_depth_m(config, n, e)), yaw) @ model.resting_poses[0]
        truths.append(ObjectTruth(name=f"{label}_{i}", label=label, T_world_object=RigidTransform(T)))
        meshes.append(model.mesh.copy().apply_transform(T))
    if config.clutter:
        placed = np.array([t.T_world_object.translation_m[:2] for t in truths])
        for k in range(config.n_clutter):
            mesh = _rock(rng) if k % 2 == 0 else _offcut(rng)
            for _ in range(100):  # on the flat floor, 0.35 m away from everything placed
                n, e = cn + rng.uniform(-1.6, 1.6) * h, ce + rng.uniform(-1.6, 1.6) * h
                far = np.min(np.hypot(placed[:, 0] - n, placed[:, 1] - e)) > 0.35
                if far and _slope_excess(config, n, e) == 0:
                    break
            if k % 2 == 0 and mesh.is_watertight:  # a rock settles; an offcut lies on its side
                T_rest = _resting(mesh, 1)[0][0]
            else:
                T_rest = np.eye(4)
                T_rest[2, 3] = -mesh.bounds[0, 2]
            T = _T_world_rest(n, e, float(floor_depth_m(config, n, e)), rng.uniform(-np.pi, np.pi)) @ T_rest
            truths.append(
                ObjectTruth(name=f"clutter_{k}", label="clutter", T_world_object=RigidTransform(T), in_database=False)
            )
            meshes.append(mesh.apply_transform(T))
            placed = np.vstack([placed, (n, e)])
    tank = tank_mesh(config)
    scene = trimesh.util.concatenate([tank, *meshes])
    owner = np.concatenate([np.full(len(tank.faces), -1)] + [np.full(len(m.faces), i) for i, m in enumerate(meshes)])
    return World(config, truths, scene, owner.astype(np.int64))
