"""Objects are placed wholly on the tank's flat floor, never reaching into its sloped sides."""

from __future__ import annotations

import numpy as np
import trimesh

from semslam.simulation import builtin_objects, make_object
from semslam.simulation.config import WorldConfig
from semslam.simulation.world import ROUTE_ORDER, _slope_excess, _T_world_rest, build_world, floor_depth_m


def _world_vertices(world, objects):
    for truth in world.objects:
        if truth.in_database:
            T = truth.T_world_object.matrix
            yield truth, objects[truth.label].mesh.vertices @ T[:3, :3].T + T[:3, 3]


def test_a_long_part_at_the_foot_of_the_slope_is_moved_onto_the_flat_floor():
    # the first corner of the route 0.3 m from the flat floor's east edge, a 0.8 m square plate: as placed before, it
    # reached at least 0.1 m into the slope whatever its yaw; now every vertex is on the flat floor, none inside it
    cfg = WorldConfig(objects_centre_ne_m=(0.0, 3.075), object_spacing_m=1.75, placement_jitter_m=0.0)
    plate = make_object("plate", trimesh.creation.box([0.8, 0.8, 0.06]))
    world = build_world(cfg, {"plate": plate}, seed=3)
    (truth, V), = list(_world_vertices(world, {"plate": plate}))
    assert _slope_excess(cfg, V[:, 0], V[:, 1]).max() == 0.0
    assert np.all(V[:, 2] <= floor_depth_m(cfg, V[:, 0], V[:, 1]) + 1e-9)  # nothing below the floor (NED: z down)
    assert abs(V[:, 2].max() - cfg.tank_depth_m) < 1e-6  # resting on it
    # moved only as far as needed: its east edge 5 mm inside the floor's
    edge = cfg.tank_width_m / 2 - cfg.slope_run_m
    assert abs(V[:, 1].max() - (edge - 0.005)) < 1e-9


def test_parts_already_on_the_flat_floor_are_not_moved():
    # the built-in fittings of the demo's world lie well inside the flat floor: each is placed exactly where the
    # corner plus its jitter puts it, at the yaw drawn after the jitter (the placement before the slope check)
    cfg = WorldConfig()
    objects = builtin_objects()
    world = build_world(cfg, objects, seed=0)
    rng = np.random.default_rng(0)
    h = cfg.object_spacing_m / 2
    cn, ce = cfg.objects_centre_ne_m
    corners = [(cn - h, ce - h), (cn + h, ce - h), (cn + h, ce + h), (cn - h, ce + h)]
    placed = list(_world_vertices(world, objects))
    assert [t.label for t, _ in placed] == list(ROUTE_ORDER)
    for (truth, V), corner in zip(placed, corners):
        assert _slope_excess(cfg, V[:, 0], V[:, 1]).max() == 0.0
        n, e = np.asarray(corner) + rng.uniform(-cfg.placement_jitter_m, cfg.placement_jitter_m, 2)
        yaw = rng.uniform(-np.pi, np.pi)
        expected = _T_world_rest(n, e, cfg.tank_depth_m, yaw) @ objects[truth.label].resting_poses[0]
        np.testing.assert_array_equal(truth.T_world_object.matrix, expected)
