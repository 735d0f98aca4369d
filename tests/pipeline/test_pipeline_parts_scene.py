"""``PartsConfig(scene_visibility=True)``: a part-based union's visibility cost verified against the whole scan.

A union is a partial segmentation by construction: a part of its object can have gone to another cluster (the
catalogue's gate valve on a flange: its handwheel joins the floor's leftovers). Against the union's own points the
model's surface there is a contradiction although the scan has points there; against the scene it is not.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import trimesh

from semslam.cloud import PointCloud
from semslam.errors import ConfigError, InputError
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.parts import PartsConfig
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT, KinectConfig, kinect_view
from semslam.simulation.objects import _box, _cyl, _solid, make_object
from semslam.symmetry import Symmetry

VERIFY = {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "keep"}
AZIMUTHS = (2.5, 4.0, 5.0)


@pytest.fixture(scope="module")
def world():
    """A 'trident' of three disjoint parts 4 cm apart (a box, a cylinder, a smaller box), and a tube, in one
    database."""
    from semslam.recognition import build_database

    mesh = _solid([_box((0.08, 0.08, 0.06), (-0.06, 0, 0)), _cyl(0.04, (0.06, 0, -0.03), (0.06, 0, 0.05)),
                   _box((0.06, 0.04, 0.06), (0.0, 0.10, 0.0))])
    trident = make_object("trident", mesh, Symmetry("none"))
    tube = _solid([_cyl(0.045, (-0.1, 0, 0), (0.1, 0, 0))], [_cyl(0.04, (-0.11, 0, 0), (0.11, 0, 0))])
    models = {"trident": trident, "tube": make_object("tube", tube, Symmetry("none"))}
    views, classes = models_view_clouds(models, seed=0, config=SURVEY_KINECT, n_views=8)
    model_views, _ = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    return trident, build_database(views, classes, seed=0, model_views=model_views)


def _scene(trident, azimuth: float, pipe: bool = True) -> tuple[PointCloud, int]:
    """A depth view of the trident (object frame: the true pose is the identity) on a floor, with an 80 cm pipe
    lying against its small box: the small box's points join the pipe's cluster (too long for any class), so the
    union of the other two parts is all the parts stage can try. Without ``pipe`` the small box is taken away
    (neither the pipe nor it in the scan: the scanner sees the floor where the box would be). Returns the scan and
    the number of object points (first; the pipe's come next)."""
    view = kinect_view(trident, azimuth, config=KinectConfig(distance_m=1.2, elevation_rad=float(np.radians(65))),
                       seed=1)
    p = view.points_xyz_m
    T = trident.resting_poses[0]
    Ti = np.linalg.inv(T)
    small_box = T[:3, :3] @ np.array([0.0, trident.mesh.bounds[1, 1] - 0.02, 0.0]) + T[:3, 3]  # its centre, rest
    eye = T[:3, :3] @ view.viewpoint_xyz_m + T[:3, 3]
    y = small_box[1] + 0.05  # the pipe's side 5 mm into the box's back face
    tube = trimesh.creation.cylinder(radius=0.035, segment=np.array([[-0.4, y, 0.035], [0.4, y, 0.035]]), sections=64)
    samples, faces = trimesh.sample.sample_surface_even(tube, 40000, seed=3)
    inside = (np.abs(samples[:, 0] - small_box[0]) < 0.03) & (samples[:, 1] < small_box[1] + 0.02)
    keep = (np.einsum("ij,ij->i", tube.face_normals[faces], eye - samples) > 0) & (samples[:, 2] > 0.002) & ~inside
    if not pipe:
        keep[:] = False
        p = p[(np.abs(p[:, 0]) > 0.035) | (p[:, 1] < trident.mesh.bounds[1, 1] - 0.045)]
    rng = np.random.default_rng(2)
    g = np.arange(-0.4, 0.4, 0.005)
    fx, fy = np.meshgrid(g, g)
    floor = np.column_stack([fx.ravel(), fy.ravel(), np.zeros(fx.size)]) + rng.normal(scale=0.0005, size=(fx.size, 3))
    rest = np.vstack([samples[keep], floor])
    return PointCloud(np.vstack([p, rest @ Ti[:3, :3].T + Ti[:3, 3]]), viewpoint_xyz_m=view.viewpoint_xyz_m), len(p)


@pytest.mark.parametrize("azimuth", AZIMUTHS)
def test_a_union_missing_a_part_verifies_against_the_scene(world, azimuth, caplog):
    trident, db = world
    scan, n_obj = _scene(trident, azimuth)
    with caplog.at_level(logging.DEBUG, logger="semslam.pipeline"):
        off = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig())).recognize(scan, seed=0)
    assert len(off.clusters) == 3 and not off.detections
    big = [k for k in range(3) if off.segmentation.input_indices(k).max() >= n_obj]  # the pipe + the small box
    assert len(big) == 1 and "too big for any class" in off.clusters[big[0]].reason
    assert (off.segmentation.input_indices(big[0]) < n_obj).sum() >= 100  # the small box went to the pipe
    parts = [k for k in range(3) if k != big[0]]
    assert all(off.clusters[k].detection is None for k in parts)
    # The union of the two parts is recognised and fits, but fails on its own visibility (the small box's surface,
    # which the union has no points of).
    assert any(f"union {parts}: trident pose verification: visibility cost" in r.getMessage() for r in caplog.records)

    result = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig(scene_visibility=True))).recognize(
        scan, seed=0)
    assert len(result.detections) == 1
    det = result.detections[0]
    assert det.label == "trident" and det.extras["parts"] == parts and det.fitness >= 0.95
    assert det.extras["pose_visibility"] > 0.15 >= det.extras["pose_visibility_scene"]
    assert [c.label for c in result.clusters] == ["unknown" if k == big[0] else "trident" for k in range(3)]
    assert np.linalg.norm(det.T_sensor_object.translation_m) < 0.01  # the truth is the identity
    assert np.degrees(np.arccos(np.clip((np.trace(det.T_sensor_object.rotation) - 1) / 2, -1, 1))) < 5.0


@pytest.mark.parametrize("azimuth", AZIMUTHS[:2])
def test_a_missing_part_seen_through_still_fails_against_the_scene(world, azimuth, caplog):
    """The scene is no free pass: with the small box taken away, the scanner sees the floor where the union's pose
    puts it (free space), and the union fails on its scene visibility too."""
    trident, db = world
    scan, _ = _scene(trident, azimuth, pipe=False)
    cfg = PipelineConfig(**VERIFY, parts=PartsConfig(scene_visibility=True))
    with caplog.at_level(logging.DEBUG, logger="semslam.pipeline"):
        result = ScanRecognizer(db, cfg).recognize(scan, seed=0)
    assert len(result.clusters) == 2 and not result.detections
    assert all(c.label == "unknown" for c in result.clusters)
    assert any("union [0, 1]: trident pose verification: scene visibility cost" in r.getMessage()
               for r in caplog.records)


def test_scene_visibility_field_is_validated():
    assert PartsConfig().scene_visibility is False
    for bad in (1, 0, "yes", None, np.float64(1.0)):
        with pytest.raises(InputError, match="scene_visibility"):
            PartsConfig(scene_visibility=bad)
    cfg = PipelineConfig(verify_min_fitness=0.95, parts=PartsConfig(scene_visibility=True))
    assert PipelineConfig.from_dict(cfg.to_dict()) == cfg
    assert PipelineConfig.from_dict({"verify_min_fitness": 0.9, "parts": {"scene_visibility": True}}).parts == \
        PartsConfig(scene_visibility=True)
    with pytest.raises(ConfigError, match="'parts' table"):
        PipelineConfig.from_dict({"verify_min_fitness": 0.9, "parts": {"scene_visibility": "on"}})
