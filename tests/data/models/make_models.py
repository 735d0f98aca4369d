"""Write the ``semslam db build --models`` fixture: three fittings of the procedural catalogue
(:mod:`semslam.simulation.objects`) as binary STL files in millimetres, and their ``models.toml``.

The meshes are the catalogue's builders at a coarser tessellation (32 facets around a cylinder instead of 48,
icospheres subdivided twice instead of three times) so that each file stays under 100 KB; their bounding boxes
are the built-in objects' to the micrometre. They are written as the builders make them, NOT centred: the
default canonical frame (origin at the bounding-box centre) must recover the built-in objects' frame; for the
ball valve, ``models.toml`` states that frame explicitly with ``T_mesh_object`` (the same frame).

Run from the repository root: ``.venv/bin/python tests/data/models/make_models.py``.
"""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import numpy as np
import trimesh

from semslam.simulation import objects

HERE = Path(__file__).resolve().parent
LABELS = ("ball_valve", "elbow", "reducing_tee")
SYMMETRY = {"ball_valve": "none", "elbow": "none", "reducing_tee": "discrete:2:y"}
MAX_BYTES = 100_000


def low_poly(label: str) -> trimesh.Trimesh:
    """The catalogue's builder of ``label`` at a coarser tessellation (metres, builder's frame)."""
    icosphere = trimesh.creation.icosphere

    def coarse_icosphere(subdivisions: int = 3, radius: float = 1.0, **kw):
        return icosphere(subdivisions=min(subdivisions, 2), radius=radius, **kw)

    with mock.patch.object(objects, "_SECTIONS", 32), mock.patch.object(trimesh.creation, "icosphere", coarse_icosphere):
        build, _ = objects._BUILDERS[label]
        return build()


def main() -> None:
    lines = ["# The fixture of tests/test_cad_models.py, written by make_models.py (three built-in fittings in mm).", ""]
    for label in LABELS:
        mesh = low_poly(label)
        assert mesh.is_watertight, label
        mesh.apply_scale(1000.0)  # metres -> millimetres
        path = HERE / f"{label}.stl"
        mesh.export(path, file_type="stl")
        assert path.stat().st_size < MAX_BYTES, (path, path.stat().st_size)
        lines += [f"[{label}]", f'file = "{label}.stl"', 'unit = "mm"', f'symmetry = "{SYMMETRY[label]}"']
        if label == "ball_valve":  # the default frame, stated explicitly: origin at the bounding-box centre (mm)
            c = mesh.bounds.mean(axis=0)
            rows = [[1, 0, 0, c[0]], [0, 1, 0, c[1]], [0, 0, 1, c[2]], [0, 0, 0, 1]]
            lines.append("T_mesh_object = [" + ", ".join("[" + ", ".join(f"{float(v):.6g}" for v in r) + "]" for r in rows) + "]")
        lines.append("")
        print(f"{path.name}: {len(mesh.faces)} faces, {path.stat().st_size} bytes, size mm {np.ptp(mesh.bounds, axis=0).round(3)}")
    (HERE / "models.toml").write_text("\n".join(lines), encoding="utf-8")


if __name__ == "__main__":
    main()
