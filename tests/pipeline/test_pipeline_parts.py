"""Part-based hypotheses (``PipelineConfig(parts=PartsConfig())``, semslam.pipeline.parts): unknown clusters near
each other tried as one object, kept only when the union is recognised, verifies and every part fits."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from semslam.cloud import PointCloud
from semslam.errors import ConfigError, InputError, SemslamError
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.parts import PartsConfig, _part_fitness
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT, KinectConfig, kinect_view
from semslam.simulation.objects import _box, _cyl, _solid, make_object
from semslam.symmetry import Symmetry

VERIFY = {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "keep"}
AZIMUTHS = (0.3, 2.5)


@pytest.fixture(scope="module")
def world():
    """A 'dumbbell' (a box and a cylinder 4 cm apart, joined by a 6 mm bar) and a tube, in one database."""
    from semslam.recognition import build_database

    mesh = _solid([_box((0.08, 0.08, 0.06), (-0.06, 0, 0)), _cyl(0.04, (0.06, 0, -0.03), (0.06, 0, 0.05)),
                   _cyl(0.003, (-0.03, 0, 0), (0.03, 0, 0))])
    dumbbell = make_object("dumbbell", mesh, Symmetry("none"))
    tube = _solid([_cyl(0.045, (-0.1, 0, 0), (0.1, 0, 0))], [_cyl(0.04, (-0.11, 0, 0), (0.11, 0, 0))])
    tube = make_object("tube", tube, Symmetry("none"))
    models = {"dumbbell": dumbbell, "tube": tube}
    views, classes = models_view_clouds(models, seed=0, config=SURVEY_KINECT, n_views=8)
    model_views, _ = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    return dumbbell, build_database(views, classes, seed=0, model_views=model_views)


def _scene(dumbbell, azimuth: float, rock_radius_m: float | None = None) -> tuple[PointCloud, int]:
    """A depth view of the dumbbell (object frame: the true pose is the identity) without its bar, so the box and
    the cylinder are separate clusters 4 cm apart, on a floor; optionally a rough rock on the floor 3.5 cm from
    the box. Returns the scan and the number of rock points (they come after the object's)."""
    view = kinect_view(dumbbell, azimuth, config=KinectConfig(distance_m=1.2, elevation_rad=float(np.radians(65))),
                       seed=1)
    p = view.points_xyz_m
    p = p[np.abs(p[:, 0]) >= 0.0195]  # the bar is not seen
    T = dumbbell.resting_poses[0]
    Ti = np.linalg.inv(T)
    box_rest = T[:3, :3] @ np.array([-0.06, 0.0, 0.0]) + T[:3, 3]
    rng = np.random.default_rng(2)
    rock_pts = np.zeros((0, 3))
    if rock_radius_m is not None:
        rock = trimesh.creation.icosphere(subdivisions=4, radius=rock_radius_m)
        rock.vertices *= 1 + 0.15 * rng.uniform(-1, 1, size=(len(rock.vertices), 1))
        samples, faces = trimesh.sample.sample_surface_even(rock, 6000, seed=3)
        p_rest = p @ T[:3, :3].T + T[:3, 3]
        for dy in np.arange(0.05, 0.3, 0.005):  # beside the box, 3.5 cm from the object's points
            centre = box_rest + [0.0, -dy, 0.0]
            centre[2] = 0.8 * rock_radius_m
            if np.linalg.norm(p_rest - centre, axis=1).min() > rock_radius_m + 0.035:
                break
        q = samples + centre
        eye_rest = T[:3, :3] @ view.viewpoint_xyz_m + T[:3, 3]
        q = q[(np.einsum("ij,ij->i", rock.face_normals[faces], eye_rest - q) > 0) & (q[:, 2] > 0.002)]
        rock_pts = q @ Ti[:3, :3].T + Ti[:3, 3]
    g = np.arange(-0.4, 0.4, 0.005)
    fx, fy = np.meshgrid(g, g)
    floor = np.column_stack([fx.ravel() + box_rest[0], fy.ravel() + box_rest[1], np.zeros(fx.size)])
    floor = floor @ Ti[:3, :3].T + Ti[:3, 3] + rng.normal(scale=0.0005, size=floor.shape)
    return PointCloud(np.vstack([p, rock_pts, floor]), viewpoint_xyz_m=view.viewpoint_xyz_m), len(rock_pts)


@pytest.mark.parametrize("azimuth", AZIMUTHS)
def test_two_part_object_is_recognised_only_as_a_union(world, azimuth):
    dumbbell, db = world
    scan, _ = _scene(dumbbell, azimuth)
    alone = ScanRecognizer(db, PipelineConfig(**VERIFY)).recognize(scan, seed=0)
    assert len(alone.clusters) == 2 and not alone.detections  # each part alone: unknown
    result = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig())).recognize(scan, seed=0)
    assert [c.label for c in result.clusters] == ["dumbbell", "dumbbell"]
    assert len(result.detections) == 1  # one object, one detection for both clusters
    det = result.detections[0]
    assert det.extras["parts"] == [0, 1] and min(det.extras["part_fitness"]) >= 0.95 and det.fitness >= 0.95
    assert all(c.detection is det and "union of clusters [0, 1]" in c.reason for c in result.clusters)
    assert np.linalg.norm(det.T_sensor_object.translation_m) < 0.01  # the truth is the identity
    assert np.degrees(np.arccos(np.clip((np.trace(det.T_sensor_object.rotation) - 1) / 2, -1, 1))) < 5.0
    assert result.timings_ms["parts"] > 0


@pytest.mark.parametrize("rock_radius_m", (0.012, 0.03))
def test_a_rock_beside_the_object_is_not_merged_into_an_accept(world, rock_radius_m):
    """Small (65 points) or as big as a part (630 points), the rock stays unknown; the union of the object's two
    parts is still found; under its pose the rock's points are off the model (the per-part test)."""
    dumbbell, db = world
    scan, n_rock = _scene(dumbbell, AZIMUTHS[0], rock_radius_m)
    rec = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig()))
    result = rec.recognize(scan, seed=0)
    assert len(result.clusters) == 3 and n_rock >= 50
    n_obj = scan.n_points - n_rock - 160 ** 2
    rock_k = [k for k in range(3) if result.segmentation.input_indices(k).min() >= n_obj]
    assert len(rock_k) == 1
    rock_k = rock_k[0]
    assert result.clusters[rock_k].label == "unknown" and result.clusters[rock_k].detection is None
    assert len(result.detections) == 1 and rock_k not in result.detections[0].extras["parts"]
    det = result.detections[0]
    rock = scan.points_xyz_m[result.segmentation.input_indices(rock_k)]
    part = scan.points_xyz_m[result.segmentation.input_indices(det.extras["parts"][0])]
    fits = _part_fitness(rec, det, det.label, det.extras["view_index"], [part, rock])
    assert fits[0] >= 0.95 and fits[1] < 0.5


def test_parts_config_is_validated():
    for bad in ({"max_gap_factor": 0.0}, {"max_gap_factor": -1.0}, {"max_candidates": 0}, {"max_parts": 1},
                {"max_parts": 5}, {"max_unions": 0}, {"min_part_fitness": 1.5}, {"min_part_fitness": -0.1},
                {"max_parts": 2.5}):
        with pytest.raises(InputError):
            PartsConfig(**bad)
    with pytest.raises(InputError, match="verify_min_fitness"):  # a union must verify: no parts without it
        PipelineConfig(parts=PartsConfig())
    with pytest.raises(InputError, match="PartsConfig"):
        PipelineConfig(verify_min_fitness=0.9, parts={"max_parts": 3})
    cfg = PipelineConfig(verify_min_fitness=0.95, parts=PartsConfig(max_parts=2, min_part_fitness=0.9))
    assert PipelineConfig.from_dict(cfg.to_dict()) == cfg
    assert PipelineConfig.from_dict(PipelineConfig().to_dict()).parts is None
    with pytest.raises(ConfigError, match="'parts' table"):
        PipelineConfig.from_dict({"verify_min_fitness": 0.9, "parts": {"max_parts": 7}})
    with pytest.raises(ConfigError, match="Unknown key"):
        PipelineConfig.from_dict({"verify_min_fitness": 0.9, "parts": {"gap": 3}})
    assert issubclass(InputError, SemslamError) and issubclass(ConfigError, SemslamError)
