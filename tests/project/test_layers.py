"""The package's layering (README, "Architecture"), enforced: no module imports a layer above its own, nothing
below ``simulation`` imports it, and the filter and the pipeline load without the simulator's mesh libraries.

Layers, bottom to top (a module may import its own layer and those below):

0. ``geometry``, ``cloud``, ``detection``, ``errors``, ``symmetry`` and the private helpers (``_validation``,
   ``_atomic``)
1. ``io``, ``dataset``
2. ``segmentation``, ``descriptors``
3. ``recognition`` (view databases, matching), ``registration`` (pairwise alignment of two clouds)
3.5 ``pose`` (an object's 6-DoF pose against its model; uses registration)
4. ``pipeline`` (scan -> detections)
5. ``slam`` (detections + navigation -> map: estimation only)
5.5 ``evaluation`` (a finished run against ground truth)
6. ``run`` (sources -> runner -> sinks; the ROS node sits on it)
7. ``simulation`` (produces datasets)
8. ``batch`` (many dives, the Dask engine), ``experiments``, ``report``, ``demo``
9. ``cli``

Within the layers, no import circle between two modules (imports inside functions count).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[2] / "semslam"

LAYERS = {
    "geometry": 0, "geodesy": 0, "cloud": 0, "detection": 0, "errors": 0, "symmetry": 0, "_validation": 0, "_atomic": 0,
    "_jsonable": 0, "modes": 0, "_tables": 0, "_progress": 0, "_outdir": 0, "_workers": 0, "_cache": 0, "_memory": 0,
    "_signals": 0, "limits": 0,
    "__init__": 0,
    "io": 1, "dataset": 1,
    "segmentation": 2, "descriptors": 2,
    "recognition": 3, "registration": 3,
    "pose": 3.5,
    "pipeline": 4,
    "slam": 5,
    "evaluation": 5.5,
    "run": 6,
    "simulation": 7,
    "batch": 8, "experiments": 8, "report": 8, "demo": 8,
    "cli": 9,
}


def _imported_tops(path: Path, root: Path) -> list[tuple[int, str]]:
    """``(line, top-level semslam package)`` of every semslam import in ``path`` (absolute or relative)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    rel_parts = path.relative_to(root).parts
    pkg_depth = len(rel_parts) - 1  # directories below semslam/
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0:
                mod = node.module or ""
                if mod == "semslam" or mod.startswith("semslam."):
                    parts = mod.split(".")[1:]
                    names = parts[:1] or [a.name for a in node.names]
                    out += [(node.lineno, n) for n in names]
                continue
            up = node.level - 1  # how many packages above the module's own
            base = list(rel_parts[:pkg_depth])[: max(pkg_depth - up, 0)] if up <= pkg_depth else None
            if base is None:
                continue
            parts = base + ((node.module or "").split(".") if node.module else [])
            if parts:
                out.append((node.lineno, parts[0]))
            else:  # "from .. import x" at the package root
                out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("semslam."):
                    out.append((node.lineno, a.name.split(".")[1]))
    return out


def layer_violations(root: Path = PKG) -> list[str]:
    bad = []
    for path in sorted(root.rglob("*.py")):
        top = path.relative_to(root).parts[0].removesuffix(".py")
        mine = LAYERS.get(top)
        if mine is None:
            bad.append(f"{path.relative_to(root.parent)}: package {top!r} has no layer (add it to LAYERS and the README)")
            continue
        for line, other in _imported_tops(path, root):
            theirs = LAYERS.get(other, 0 if other in ("__version__",) else None)
            if theirs is None:
                continue
            if theirs > mine or (other == "simulation" and mine < LAYERS["simulation"]):
                bad.append(f"{path.relative_to(root.parent)}:{line} imports {other!r} (layer {theirs}) from layer {mine}")
    return bad


def test_no_module_imports_a_higher_layer():
    """Catches an upward import such as ``semslam/slam/x.py: from ..simulation import ...``."""
    assert layer_violations() == []


def test_the_layer_test_fails_on_an_upward_import(tmp_path):
    """A copy of the package with one planted upward import (slam -> simulation) must be reported."""
    import shutil

    copy = tmp_path / "semslam"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    target = copy / "slam" / "config.py"
    target.write_text(target.read_text(encoding="utf-8") + "\nfrom ..simulation import simulate_dataset  # planted\n",
                      encoding="utf-8")
    bad = layer_violations(copy)
    assert len(bad) == 1 and "slam/config.py" in bad[0] and "'simulation'" in bad[0]
    target = copy / "dataset" / "logs.py"
    target.write_text(target.read_text(encoding="utf-8") + "\nimport semslam.pipeline  # planted\n", encoding="utf-8")
    assert len(layer_violations(copy)) == 2


@pytest.mark.parametrize("module", ["semslam.slam", "semslam.pipeline", "semslam.dataset"])
def test_library_layers_load_without_mesh_libraries(module):
    """The filter and the pipeline must not pull in the simulator's mesh stack (trimesh, embree, manifold)."""
    code = (f"import sys, {module}; bad = [m for m in ('trimesh', 'embreex', 'manifold3d', 'semslam.simulation') "
            "if m in sys.modules]; print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == ""


def _module_graph(root: Path = PKG) -> dict[str, set[str]]:
    """Module -> modules it imports (anywhere in the file, functions included), dotted names below ``semslam``."""
    modules = {".".join(p.relative_to(root).with_suffix("").parts) for p in root.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        name = ".".join(parts)
        pkg = parts[:-1]
        edges = graph.setdefault(name, set())
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom) or node.level == 0:
                continue
            base = pkg[: len(pkg) - (node.level - 1)] + ((node.module or "").split(".") if node.module else [])
            target = ".".join(base)
            for a in node.names:
                sub = f"{target}.{a.name}" if target else a.name
                if sub in modules:
                    edges.add(sub)
                elif target in modules:
                    edges.add(target)
                elif f"{target}.__init__" in modules:
                    edges.add(f"{target}.__init__")
    return graph


def import_circles(root: Path = PKG) -> list[list[str]]:
    """Strongly connected groups of two or more modules (Tarjan), a package's ``__init__`` aside (it re-exports)."""
    graph = {m: {e for e in es if not e.endswith("__init__")} for m, es in _module_graph(root).items()
             if not m.endswith("__init__")}
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_circle_between_modules():
    """Catches two modules importing each other, even lazily (``io/export`` <-> ``io/export_mcap`` once)."""
    assert import_circles() == []


def test_the_circle_test_finds_a_planted_circle(tmp_path):
    import shutil

    copy = tmp_path / "semslam"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    target = copy / "geometry.py"
    target.write_text(target.read_text(encoding="utf-8") + "\n\ndef _planted():\n    from .cloud import PointCloud\n",
                      encoding="utf-8")
    assert ["cloud", "geometry"] in import_circles(copy)
