"""Issue #18, item 5 (a cold ``semslam recognize`` within 1 s): the command must import only what recognising a
scan needs. A fresh interpreter runs ``semslam recognize`` to the end (segmentation, descriptors, matching and a
pose) on a small synthetic scene and reports which of the heavy packages it loaded: none may be. Not a timing
test: an import that comes back (plotting, machine learning, meshes, factor graphs, Dask, bags, progress bars,
the mission reader) fails here whatever the machine's load.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

# packages `semslam recognize SCAN --db FILE` must not import, with what each one costs or drags in
NOT_NEEDED = (
    "matplotlib",  # the report's figures
    "sklearn",  # SVM classifier and LOO evaluation only (1-2 s of start-up)
    "trimesh", "embreex", "manifold3d",  # the simulator's meshes
    "gtsam",  # the factor-graph back-ends
    "dask", "distributed", "pandas",  # batch runs
    "rosbags",  # bag input
    "tqdm",  # progress bars
    "scipy.stats", "scipy.optimize",
    "semslam.simulation", "semslam.slam", "semslam.experiments", "semslam.report", "semslam.demo",
    "semslam.dataset",  # missions: semslam.pipeline imports its mission-level names on first use
)

_CHILD = """
import contextlib, io, json, sys
from semslam.cli.main import main
with contextlib.redirect_stdout(io.StringIO()) as out:
    rc = main(sys.argv[1:])
names = json.loads(sys.stdin.read())
loaded = sorted(n for n in names if n in sys.modules)
print(json.dumps({"rc": rc, "payload": json.loads(out.getvalue()), "loaded": loaded}))
"""


@pytest.fixture(scope="module")
def scene_and_db(tmp_path_factory):
    """A database of three synthetic shapes and a scan of one box view on a floor (scanner at the origin)."""
    from semslam.cloud import PointCloud
    from semslam.simulation.synthetic_views import synthetic_shape_views
    from semslam.io import write_point_cloud
    from semslam.recognition import build_database, save_database

    d = tmp_path_factory.mktemp("import_budget")
    views, classes = synthetic_shape_views(4, n_points=400, seed=1)
    db = save_database(build_database(views, classes, seed=0), d / "db.npz")
    view = next(cloud for label, _, cloud in views if label == "box")
    obj = view.points_xyz_m - view.viewpoint_xyz_m
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, size=(6000, 2)) + obj[:, :2].mean(axis=0)
    floor = np.column_stack([xy, obj[:, 2].min() - 0.002 + rng.normal(scale=0.0005, size=len(xy))])
    scan = d / "scan.pcd"
    write_point_cloud(scan, PointCloud(np.vstack([obj, floor])))
    return scan, db


def test_recognize_imports_none_of_the_heavy_packages(scene_and_db):
    scan, db = scene_and_db
    argv = ["recognize", str(scan), "--db", str(db), "--border", "keep", "--reject-margin", "1e6", "--json"]
    proc = subprocess.run([sys.executable, "-c", _CHILD, *argv], input=json.dumps(NOT_NEEDED),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["rc"] == 0
    # the whole path ran: a detection with its pose
    assert [d["label"] for d in report["payload"]["detections"]] == ["box"]
    assert report["payload"]["detections"][0]["fitness"] is not None
    assert report["loaded"] == []


def test_the_check_sees_a_heavy_import():
    """The child's report is not vacuous: a module it was told to look for and that is loaded is named."""
    code = "import json, sys, tqdm; names = json.loads(sys.stdin.read()); print([n for n in names if n in sys.modules])"
    proc = subprocess.run([sys.executable, "-c", code], input=json.dumps(NOT_NEEDED), capture_output=True,
                          text=True, timeout=120)
    assert proc.stdout.strip() == "['tqdm']", proc.stderr[-2000:]


def test_recognize_builds_only_its_own_parser():
    """`semslam recognize` imports the recognize command's module (and the helpers it shares), not the others'."""
    code = ("import sys; from semslam.cli.main import build_parser, _command_module; "
            "build_parser(_command_module(['--json', 'recognize', 'x.pcd'])); "
            "print(sorted(m for m in sys.modules if m.startswith('semslam.cli.cmd_')))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() == "['semslam.cli.cmd_recognize', 'semslam.cli.cmd_segment']", proc.stderr[-2000:]


@pytest.mark.parametrize("argv", [["--help"], ["no-such-command"], ["montecarlo", "--help"], []])
def test_without_a_command_module_every_command_is_registered(argv):
    from semslam.cli.main import _command_module, build_parser

    assert _command_module(argv) is None
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert {"recognize", "slam", "montecarlo", "db"} <= set(sub.choices)


def test_recognising_one_scan_does_not_load_the_dataset_layer():
    """semslam.pipeline serves the scan-level names only; the mission-level ones are imported from
    semslam.pipeline.dataset_detection, so `semslam recognize` never loads semslam.dataset."""
    code = ("import sys, semslam.pipeline as p; assert not hasattr(p, 'detect_dataset'); "
            "print('semslam.dataset' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"

