"""Part gaps learnt from the database (``PartsConfig(view_gaps=True)``, semslam.pipeline.parts): a class whose own
views show two parts far apart may be unioned across that gap, other classes only across ``max_gap_factor`` times
the cluster tolerance."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.errors import InputError
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.parts import PartsConfig, _widest_gap, largest_part_gap, view_gap_limits
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT, kinect_view
from semslam.simulation.objects import _box, _cyl, _solid, make_object
from semslam.symmetry import Symmetry

VERIFY = {"verify_min_fitness": 0.95, "verify_max_visibility": 0.15, "border": "keep"}


def _blob(centre, n=200, seed=0):
    return np.asarray(centre) + np.random.default_rng(seed).uniform(-0.01, 0.01, size=(n, 3))


def _brute_force_gap(parts):
    """Longest edge of the minimum spanning tree between the parts, by trying every spanning order (Prim's)."""
    d = {(i, j): np.min(np.linalg.norm(parts[i][:, None] - parts[j][None], axis=2))
         for i, j in itertools.combinations(range(len(parts)), 2)}
    joined, widest = {0}, 0.0
    while len(joined) < len(parts):
        g, j = min((v, b if a in joined else a) for (a, b), v in d.items() if (a in joined) != (b in joined))
        widest, joined = max(widest, g), joined | {j}
    return widest


def test_largest_part_gap_is_the_widest_spanning_tree_edge_between_parts():
    parts = [_blob((0, 0, 0), seed=1), _blob((0.05, 0, 0), seed=2), _blob((0.05, 0.11, 0), seed=3)]
    gap = largest_part_gap(np.vstack(parts), 0.02)
    assert gap == pytest.approx(_brute_force_gap(parts), abs=1e-9)
    assert 0.085 < gap < 0.1  # the 11 cm between the centres of 2 cm blobs


def test_one_cluster_has_no_gap_and_stray_points_do_not_count():
    body = _blob((0, 0, 0), n=400, seed=4)
    assert largest_part_gap(body, 0.02) == 0.0
    stray = np.array([[0.3, 0.0, 0.0], [0.301, 0.0, 0.0]])  # 2 of 402 points: below the 5 % share
    assert largest_part_gap(np.vstack([body, stray]), 0.02) == 0.0
    far = _blob((0.3, 0, 0), n=100, seed=5)  # a real part 28 cm away
    assert largest_part_gap(np.vstack([body, far]), 0.02) == pytest.approx(_brute_force_gap([body, far]))


def test_widest_gap_of_a_union_joins_its_members_by_the_nearest_gaps():
    gaps = {(0, 1): 0.03, (1, 2): 0.05, (0, 2): 0.09, (2, 3): 0.2}
    assert _widest_gap((0, 1, 2), gaps) == pytest.approx(0.05)
    assert _widest_gap((0, 2), gaps) == pytest.approx(0.09)
    assert _widest_gap((0, 1), {(1, 2): 0.01}) == np.inf  # not joined


@pytest.fixture(scope="module")
def world():
    """A 'barbell' (a box and a cylinder with 7 cm of nothing between them: two parts in every view that sees
    both) and a tube, in one database."""
    from semslam.recognition import build_database

    barbell = make_object("barbell", _solid([_box((0.08, 0.08, 0.06), (-0.075, 0, 0)),
                                             _cyl(0.04, (0.075, 0, -0.03), (0.075, 0, 0.05))]), Symmetry("none"))
    tube = _solid([_cyl(0.045, (-0.1, 0, 0), (0.1, 0, 0))], [_cyl(0.04, (-0.11, 0, 0), (0.11, 0, 0))])
    models = {"barbell": barbell, "tube": make_object("tube", tube, Symmetry("none"))}
    views, classes = models_view_clouds(models, seed=0, config=SURVEY_KINECT, n_views=8)
    model_views, _ = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    return barbell, build_database(views, classes, seed=0, model_views=model_views)


def test_view_gap_limits_learn_the_far_parts_of_one_class_only(world):
    _, db = world
    limits = view_gap_limits(db, 0.02, 0.05)
    assert limits["tube"] == pytest.approx(0.05)  # one part in every view: the floor
    assert 0.07 < limits["barbell"] < 0.10  # the 7 cm between box and cylinder, with the margin


def _floor(model) -> np.ndarray:
    """The floor the model rests on (its most probable resting pose), in the model's frame, 5 mm grid."""
    Ti = np.linalg.inv(model.resting_poses[0])
    g = np.arange(-0.3, 0.3, 0.005)
    fx, fy = np.meshgrid(g, g)
    floor = np.column_stack([fx.ravel(), fy.ravel(), np.zeros(fx.size)])
    return floor @ Ti[:3, :3].T + Ti[:3, 3] + np.random.default_rng(2).normal(scale=0.0005, size=floor.shape)


@pytest.mark.parametrize("azimuth", (0.3, 2.5))
def test_parts_further_apart_than_the_factor_are_unioned_when_the_views_show_that_gap(world, azimuth):
    barbell, db = world
    view = kinect_view(barbell, azimuth, config=SURVEY_KINECT, seed=1)  # the views' sensor, at other azimuths
    scan = PointCloud(np.vstack([view.points_xyz_m, _floor(barbell)]), viewpoint_xyz_m=view.viewpoint_xyz_m)
    parts = PartsConfig(max_gap_factor=2.5)  # 5 cm at the 2 cm tolerance: the 7 cm gap is too wide
    narrow = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=parts)).recognize(scan, seed=0)
    assert len(narrow.clusters) == 2 and not narrow.detections
    learnt = PipelineConfig(**VERIFY, parts=PartsConfig(max_gap_factor=2.5, view_gaps=True))
    result = ScanRecognizer(db, learnt).recognize(scan, seed=0)
    assert [c.label for c in result.clusters] == ["barbell", "barbell"]
    (det,) = result.detections
    assert sorted(det.extras["parts"]) == [0, 1]
    R = det.T_sensor_object.matrix[:3, :3]  # the view is in the object's frame: the true pose is the identity
    assert np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))) < 5
    assert np.linalg.norm(det.T_sensor_object.matrix[:3, 3]) < 0.01


def test_view_gaps_must_be_a_bool():
    with pytest.raises(InputError, match="view_gaps"):
        PartsConfig(view_gaps=1)
    assert PartsConfig(view_gaps=True).to_dict()["view_gaps"] is True
