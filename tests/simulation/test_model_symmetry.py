"""The declared symmetry of a user's model checked against its mesh (``model_symmetry``): analytic solids whose
symmetry is known, the shared real models (whose benchmark declarations it corrected), and the warning that
``read_models`` and ``semslam db build --models`` give."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import trimesh

from semslam.cli.main import main
from semslam.simulation.cad_models import ModelSymmetryWarning, parse_symmetry, read_models
from semslam.simulation.model_symmetry import (BROKEN_EXCESS, HOLDS_EXCESS, check_declared_symmetry,
                                               measured_symmetry, symmetry_text, turn_excess)
from semslam.symmetry import Symmetry
from tests._support.shared import SHARED, require_shared


def _rot(axis, angle):
    return trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]


SOLIDS = {
    # a plain cylinder: axisymmetric and the same end for end
    "cylinder": (lambda: trimesh.creation.cylinder(radius=0.05, height=0.3, sections=96), "continuous:z:flip"),
    # a cone: axisymmetric, its ends differ
    "cone": (lambda: trimesh.creation.cone(radius=0.05, height=0.2, sections=96).apply_translation([0, 0, -0.1]),
             "continuous:z"),
    # a pentagonal prism about x (the wheel valve's five spokes)
    "pentagon": (lambda: trimesh.creation.cylinder(radius=0.1, height=0.04, sections=5).apply_transform(
        trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])), "discrete:5:x"),
    # a square prism: 4-fold about its long axis
    "square": (lambda: trimesh.creation.box(extents=(0.1, 0.1, 0.3)), "discrete:4:z"),
    # a box of three different sides: half turns about each axis (x, the first, is named)
    "box": (lambda: trimesh.creation.box(extents=(0.3, 0.2, 0.1)), "discrete:2:x"),
    # a box with a knob off its axes: nothing
    "knob": (lambda: trimesh.util.concatenate([trimesh.creation.box(extents=(0.3, 0.2, 0.1)),
                                               trimesh.creation.icosphere(radius=0.03).apply_translation(
                                                   [0.1, 0.05, 0.06])]), "none"),
}


@pytest.mark.parametrize("name", list(SOLIDS))
def test_the_strongest_symmetry_of_an_analytic_solid_is_measured(name):
    build, expected = SOLIDS[name]
    found, excess = measured_symmetry(build())
    assert symmetry_text(found) == expected
    assert excess < HOLDS_EXCESS


def test_the_turn_excess_is_zero_for_a_symmetry_and_large_otherwise():
    square = trimesh.creation.box(extents=(0.1, 0.1, 0.3))
    e = turn_excess(square, np.stack([np.eye(3), _rot([0, 0, 1], np.pi / 2), _rot([0, 0, 1], np.pi / 4),
                                      _rot([1, 0, 0], np.pi / 2)]))
    assert e[0] == 0.0 and e[1] < HOLDS_EXCESS
    assert e[2] > BROKEN_EXCESS and e[3] > BROKEN_EXCESS


def test_a_declared_symmetry_the_mesh_lacks_is_named_with_the_one_it_has():
    square = trimesh.creation.box(extents=(0.1, 0.1, 0.3))
    msg = check_declared_symmetry(square, parse_symmetry("discrete:8:z"))
    assert "'discrete:8:z' does not hold" in msg and "'discrete:4:z'" in msg and " mm or more" in msg
    assert check_declared_symmetry(square, parse_symmetry("discrete:4:z")) is None
    assert check_declared_symmetry(square, parse_symmetry("discrete:2:z")) is not None  # 4 contains 2
    knob = SOLIDS["knob"][0]()
    assert "does not hold" in check_declared_symmetry(knob, parse_symmetry("continuous:y"))
    assert check_declared_symmetry(knob, Symmetry()) is None


def test_a_cylinder_declared_without_its_flip_is_told_to_declare_it():
    cylinder = SOLIDS["cylinder"][0]()
    msg = check_declared_symmetry(cylinder, parse_symmetry("continuous:z"))
    assert "'continuous:z:flip'" in msg and "'continuous:z' is declared" in msg
    assert "'continuous:z:flip'" in check_declared_symmetry(cylinder, Symmetry())
    assert check_declared_symmetry(cylinder, parse_symmetry("continuous:z:flip")) is None
    # a symmetry about another axis than the one it has is not a weaker declaration: it does not hold
    assert "does not hold" in check_declared_symmetry(cylinder, parse_symmetry("continuous:x"))


def _shared_models_folder(tmp_path, entries: dict[str, tuple[str, str, str]]):
    models = require_shared(SHARED / "data" / "models", "shared real models")
    d = tmp_path / "models"
    d.mkdir()
    lines = []
    for label, (fname, unit, sym) in entries.items():
        shutil.copy(models / fname, d / fname)
        lines.append(f'[{label}]\nfile = "{fname}"\nunit = "{unit}"\nsymmetry = "{sym}"\n')
    (d / "models.toml").write_text("\n".join(lines))
    return d


def test_the_shared_wheel_valve_is_five_fold_and_the_valve_base_a_plain_cylinder(tmp_path):
    """The real models benchmark declared the wheel valve 'none' and the valve base 'continuous:x' until this
    check measured them: five spokes (exact to 0.01 mm) and a base the same end for end."""
    d = _shared_models_folder(tmp_path, {"wheel_valve": ("wheel_valve.stl", "m", "none"),
                                         "tac_valve_base": ("tac_valve_base.obj", "m", "continuous:x"),
                                         "blind_flange": ("blind_flange_4in_cl150.stl", "m", "discrete:8:z")})
    with pytest.warns(ModelSymmetryWarning) as caught:
        models = read_models(d)
    texts = [str(w.message) for w in caught if issubclass(w.category, ModelSymmetryWarning)]
    assert len(texts) == 2
    assert "class 'wheel_valve'" in texts[0] and "'discrete:5:x'" in texts[0]
    assert "class 'tac_valve_base'" in texts[1] and "'continuous:x:flip'" in texts[1]
    assert symmetry_text(measured_symmetry(models["blind_flange"].mesh)[0]) == "discrete:8:z"


def test_db_build_prints_the_disagreement_as_one_warning_line(tmp_path, capsys):
    d = tmp_path / "models"
    d.mkdir()
    trimesh.creation.cylinder(radius=25.0, height=200.0, sections=64).export(d / "rod.stl")
    (d / "models.toml").write_text('[rod]\nfile = "rod.stl"\nunit = "mm"\nsymmetry = "continuous:z"\n')
    assert main(["db", "build", "--models", str(d), "--out", str(tmp_path / "db.npz"), "--n-views", "2",
                 "--model-views", "0", "--kinect-distance", "3"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "symmetry" in line or "turned" in line]
    assert len(err) == 1 and err[0].startswith("semslam: warning: The class 'rod'") and "'continuous:z:flip'" in err[0]


@pytest.mark.parametrize("text", ["none", "discrete:5:x", "discrete:12:z", "continuous:y", "continuous:z:flip"])
def test_the_warning_spells_symmetries_as_models_toml_reads_them(text):
    assert symmetry_text(parse_symmetry(text)) == text
