"""Users' model files beyond STL/OBJ/PLY (``semslam.simulation.cad_models``): COLLADA ``.dae``, glTF
``.gltf``/``.glb`` and STEP ``.step``/``.stp``, their units from the file (a models.toml ``unit`` wins), and
one-line errors on bad files.

Oracles: the shared real models (``../shared/data/models``) hold the same part twice, written independently:
``wheel_valve_original.dae`` (SketchUp, inches) and ``wheel_valve.stl`` (metres, scaled 1.6 by the Gazebo
model.sdf, as its README says); ``blind_flange_4in_cl150_mm.step`` (millimetres) and ``blind_flange_4in_cl150.stl``
(metres, tessellated by another program)."""

from __future__ import annotations

import shutil

import sys
import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from tests._support.shared import require_shared
from semslam.cli.main import main
from semslam.errors import DatabaseError
from semslam.simulation.cad_models import (
    ModelUnitWarning,
    MultiMeshSceneWarning,
    NonWatertightMeshWarning,
    read_models,
    step_length_unit_m,
)

#: COLLADA x SDF scale of the wheel valve STL (the README: "COLLADA in inches converted with the model.sdf scale").
WHEEL_SDF_SCALE = 1.6


@pytest.fixture(scope="module")
def shared_models(shared_dir):
    return require_shared(shared_dir / "data" / "models", "shared real models")


def _folder(tmp_path, toml: str, files: dict[str, object] | None = None):
    """A models folder: ``files`` (name -> trimesh object, bytes, str or a path to copy: a link leading out of the
    folder is refused) and models.toml."""
    d = tmp_path / "models"
    d.mkdir(exist_ok=True)
    for name, content in (files or {}).items():
        target = d / name
        if isinstance(content, (trimesh.Trimesh, trimesh.Scene)):
            content.export(target)
        elif isinstance(content, bytes):
            target.write_bytes(content)
        elif isinstance(content, str):
            target.write_text(content, encoding="utf-8")
        else:
            shutil.copyfile(content, target)
    (d / "models.toml").write_text(toml, encoding="utf-8")
    return d


def _read(d, *expected_warnings):
    """``read_models(d)``, asserting it warns exactly the ``expected_warnings`` categories (and returning them)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        models = read_models(d)
    got = [w for w in caught if issubclass(w.category, (ModelUnitWarning, MultiMeshSceneWarning,
                                                         NonWatertightMeshWarning))]
    assert sorted(w.category.__name__ for w in got) == sorted(c.__name__ for c in expected_warnings), \
        [str(w.message) for w in got]
    return models, [str(w.message) for w in got]


def _box_m() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(0.05, 0.03, 0.02))


# -- COLLADA -----------------------------------------------------------------------------------------------
def test_collada_is_read_in_its_stated_inches_and_matches_the_stl_of_the_same_part(tmp_path, shared_models):
    pytest.importorskip("collada", reason="pycollada not installed (pip install 'semslam[models]')")
    d = _folder(tmp_path, '[dae]\nfile = "wheel_valve_original.dae"\n\n[stl]\nfile = "wheel_valve.stl"\nunit = "m"\n',
                {"wheel_valve_original.dae": shared_models / "wheel_valve_original.dae",
                 "wheel_valve.stl": shared_models / "wheel_valve.stl"})
    models, messages = _read(d, MultiMeshSceneWarning, NonWatertightMeshWarning, NonWatertightMeshWarning)
    assert any("COLLADA file" in m and "holds 4 meshes: concatenated into one rigid object" in m for m in messages)
    dae, stl = models["dae"], models["stl"]
    # <unit meter="0.0254">: 2.04 x 9.84 x 9.84 inches (measured with the file's numbers)
    np.testing.assert_allclose(dae.size_xyz_m, np.array([2.04, 9.84, 9.84]) * 0.0254, rtol=1e-3)
    # the STL is the same mesh times the SDF scale: sizes to 1e-4, every vertex within 1 micrometre
    np.testing.assert_allclose(stl.size_xyz_m / dae.size_xyz_m, WHEEL_SDF_SCALE, rtol=1e-4)
    assert len(dae.mesh.faces) == len(stl.mesh.faces) == 10992
    distance, _ = cKDTree(WHEEL_SDF_SCALE * dae.mesh.vertices).query(stl.mesh.vertices)
    assert distance.max() < 1e-6

    # models.toml's unit wins: the same unit is silent, another one warns and scales
    (d / "models.toml").write_text('[dae]\nfile = "wheel_valve_original.dae"\nunit = "inch"\n')
    same, _ = _read(d, MultiMeshSceneWarning, NonWatertightMeshWarning)
    np.testing.assert_allclose(same["dae"].size_xyz_m, dae.size_xyz_m, rtol=1e-12)
    (d / "models.toml").write_text('[dae]\nfile = "wheel_valve_original.dae"\nunit = "cm"\n')
    cm, messages = _read(d, ModelUnitWarning, MultiMeshSceneWarning, NonWatertightMeshWarning)
    np.testing.assert_allclose(cm["dae"].size_xyz_m, dae.size_xyz_m * 0.01 / 0.0254, rtol=1e-12)
    assert any("'unit' = 'cm' (0.01 m) overrides the COLLADA <unit meter=\"0.0254\">" in m for m in messages)


# -- STEP --------------------------------------------------------------------------------------------------
def test_step_is_read_from_its_millimetres_and_matches_the_stl_of_the_same_part(tmp_path, shared_models):
    pytest.importorskip("cascadio", reason="cascadio not installed (pip install 'semslam[step]')")
    step = shared_models / "blind_flange_4in_cl150_mm.step"
    assert step_length_unit_m(step) == pytest.approx(1e-3)
    d = _folder(tmp_path, '[step]\nfile = "flange.step"\n\n[stl]\nfile = "flange.stl"\nunit = "m"\n',
                {"flange.step": step, "flange.stl": shared_models / "blind_flange_4in_cl150.stl"})
    models, _ = _read(d)  # one solid, watertight once its faces' vertices are merged: no warning
    a, b = models["step"].mesh, models["stl"].mesh
    assert a.is_watertight and b.is_watertight
    # 230 mm across, 24.3 mm thick (ASME B16.5 4 in class 150); two tessellations of the same circles:
    np.testing.assert_allclose(models["step"].size_xyz_m, [0.230, 0.230, 0.0243], atol=2e-4)
    np.testing.assert_allclose(models["step"].size_xyz_m, models["stl"].size_xyz_m, atol=2e-4)
    assert a.volume == pytest.approx(b.volume, rel=2e-3) and a.area == pytest.approx(b.area, rel=2e-3)
    # models.toml's unit wins: 'm' on a millimetre file makes it 1000 times larger, an absurd size
    (d / "models.toml").write_text('[step]\nfile = "flange.step"\nunit = "m"\n')
    with pytest.warns(ModelUnitWarning, match=r"'unit' = 'm' \(1 m\) overrides the STEP length unit 0\.001 m"):
        with pytest.raises(DatabaseError, match=r"flange\.step.* mm across .*unit 'm' \(from the models file\).*"
                                                r"check 'unit'"):
            read_models(d)


def test_step_length_unit_is_read_from_si_and_named_units(tmp_path):
    cases = {"#9=(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT($,.METRE.));": 1.0,
             "#9 = ( LENGTH_UNIT() NAMED_UNIT(*)\n SI_UNIT(.CENTI.,.METRE.) );": 0.01,
             "#9=(CONVERSION_BASED_UNIT('INCH',#8)LENGTH_UNIT()NAMED_UNIT(#7));": 0.0254,
             "#9=(NAMED_UNIT(*)PLANE_ANGLE_UNIT()SI_UNIT($,.RADIAN.));": None}
    for i, (entity, expected) in enumerate(cases.items()):
        path = tmp_path / f"u{i}.step"
        path.write_text(f"ISO-10303-21;\nDATA;\n{entity}\nENDSEC;\n", encoding="latin-1")
        assert step_length_unit_m(path) == expected, entity


# -- glTF --------------------------------------------------------------------------------------------------
def test_gltf_written_by_trimesh_is_read_in_metres(tmp_path):
    gltf = _box_m().export(file_type="gltf", embed_buffers=True)  # {"model.gltf": bytes}, buffers inside
    d = _folder(tmp_path, '[glb]\nfile = "box.glb"\n\n[gltf]\nfile = "box.gltf"\nsymmetry = "discrete:2:z"\n'
                          'T_mesh_object = [[1, 0, 0, 0.01], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n',
                {"box.glb": _box_m(), "box.gltf": next(iter(gltf.values()))})
    models, _ = _read(d)
    for label in ("glb", "gltf"):
        np.testing.assert_allclose(models[label].size_xyz_m, [0.05, 0.03, 0.02], atol=1e-9)
    # T_mesh_object's translation is in the file's unit, metres for glTF: the object origin 10 mm along x
    np.testing.assert_allclose(models["gltf"].mesh.bounds.mean(axis=0), [-0.01, 0.0, 0.0], atol=1e-9)
    # models.toml's unit wins: 'mm' reads the metre numbers as millimetres, 0.06 mm across: absurd
    (d / "models.toml").write_text('[glb]\nfile = "box.glb"\nunit = "mm"\n')
    with pytest.warns(ModelUnitWarning, match=r"'unit' = 'mm' \(0\.001 m\) overrides glTF's metres"):
        with pytest.raises(DatabaseError, match=r"class 'glb'.*box\.glb.*0\.06164 mm across .*unit 'mm' "
                                                r"\(from the models file\); expected 5 mm to 20 m: check 'unit'"):
            read_models(d)


def test_a_scene_of_several_meshes_is_one_object_with_a_warning(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(_box_m(), node_name="left")
    scene.add_geometry(_box_m(), node_name="right", transform=trimesh.transformations.translation_matrix([0.1, 0, 0]))
    d = _folder(tmp_path, '[pair]\nfile = "pair.glb"\n', {"pair.glb": scene})
    models, messages = _read(d, MultiMeshSceneWarning)
    np.testing.assert_allclose(models["pair"].size_xyz_m, [0.15, 0.03, 0.02], atol=1e-9)  # placed by the scene
    assert len(models["pair"].mesh.faces) == 24
    assert "class 'pair'" in messages[0] and "pair.glb' holds 2 meshes" in messages[0]


# -- bad input ---------------------------------------------------------------------------------------------
def _points_glb() -> trimesh.Scene:
    return trimesh.Scene(trimesh.PointCloud(np.random.default_rng(0).random((10, 3))))


BAD_FILES = [
    ("part.3ds", "3DS", None,
     ("class 'part'", "part.3ds", "format semslam does not read", "STL, OBJ, PLY, COLLADA, glTF, STEP", ".stp", "'.3ds'")),
    ("part.glb", _points_glb(), None, ("class 'part'", "part.glb", "must hold triangles", "empty mesh")),
    ("part.glb", b"garbage", None, ("class 'part'", "cannot read the glTF file", "part.glb")),
    ("part.dae", "<COLLADA", "collada", ("class 'part'", "cannot read the COLLADA file", "part.dae")),
    ("part.step", "ISO-10303-21;\n", "cascadio", ("class 'part'", "cannot read the STEP file", "part.step",
                                                  "OpenCASCADE")),
    ("part.glb", trimesh.creation.box(extents=(200.0, 1.0, 1.0)), None,
     ("part.glb", "2e+05 mm across", "glTF's metres (from the file)", "expected 5 mm to 20 m")),
    ("part.stl", _box_m(), None, ("class 'part'", "missing the key 'unit'", "STL, OBJ and PLY files state none")),
]


@pytest.mark.parametrize("name, content, module, words", BAD_FILES,
                         ids=["unread format", "no faces", "bad glb", "bad dae", "bad step", "absurd size", "stl no unit"])
def test_bad_model_file_raises_one_line_naming_the_file(tmp_path, name, content, module, words):
    if module:
        pytest.importorskip(module, reason=f"{module} not installed")
    d = _folder(tmp_path, f'[part]\nfile = "{name}"\n', {name: content})
    with pytest.raises(DatabaseError) as exc:
        read_models(d)
    message = str(exc.value)
    assert "\n" not in message
    for w in words:
        assert w in message, (w, message)


@pytest.mark.parametrize("name, module, install", [("part.dae", "collada", "pip install 'semslam[models]' (or pip "
                                                    "install pycollada)"),
                                                   ("part.stp", "cascadio", "pip install 'semslam[step]' (or pip "
                                                    "install cascadio)")])
def test_a_format_without_its_optional_reader_says_what_to_install(tmp_path, monkeypatch, capsys, name, module,
                                                                   install):
    monkeypatch.setitem(sys.modules, module, None)  # as if not installed: `import module` fails
    d = _folder(tmp_path, f'[part]\nfile = "{name}"\n', {name: "whatever"})
    with pytest.raises(DatabaseError, match=rf"class 'part'.*{name}.*needs the optional reader"):
        read_models(d)
    # the CLI: one line, exit 1
    assert main(["db", "build", "--models", str(d), "--out", str(tmp_path / "db.npz")]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error: The class 'part'") and install in lines[0], lines
    assert not (tmp_path / "db.npz").exists()
