"""The README and docs/ stay true to the code: their links lead somewhere, their Python examples import, the
plausibility rows quoted in the README are the generated table's, and the README's architecture names every package.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from semslam.limits import limits_markdown

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [ROOT / "README.md", *DOCS]


def _ids(paths):
    return [str(p.relative_to(ROOT)) for p in paths]


def _import_statements(text: str) -> list[str]:
    """The import statements of the ```python blocks of a page (parenthesised ones joined onto one line)."""
    out = []
    for block in re.findall(r"```python\n(.*?)```", text, re.S):
        pending = ""
        for line in block.splitlines():
            code = re.sub(r"\s+#.*$", "", line).strip()
            if pending:
                pending += " " + code
                if ")" in code:
                    out.append(pending)
                    pending = ""
            elif re.match(r"(from \S+ import |import )", code):
                if "(" in code and ")" not in code:
                    pending = code
                else:
                    out.append(code)
    return out


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_relative_links_lead_to_existing_files(page):
    text = page.read_text(encoding="utf-8")
    targets = [t for t in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text) if not re.match(r"[a-z]+://", t)]
    broken = [t for t in targets if not (page.parent / t).exists()]
    assert not broken, f"{page.name}: links to missing files {broken}"


@pytest.mark.parametrize("page", [p for p in PAGES if "```python" in p.read_text(encoding="utf-8")],
                         ids=_ids([p for p in PAGES if "```python" in p.read_text(encoding="utf-8")]))
def test_python_examples_import(page):
    statements = _import_statements(page.read_text(encoding="utf-8"))
    assert statements, f"{page.name} has Python examples but no import in them"
    failed = []
    for stmt in statements:
        try:
            exec(stmt, {})
        except ImportError as exc:
            failed.append(f"{stmt!r}: {exc}")
    assert not failed, f"{page.name}: imports that fail: {failed}"


def test_import_statements_are_found_in_a_parenthesised_example():
    text = "```python\nfrom a.b import (c,\n    d)   # comment\nimport e\nx = 1\n```\n"
    assert _import_statements(text) == ["from a.b import (c, d)", "import e"]


def _section(text: str, title: str) -> str:
    start = text.index(f"\n## {title}")
    end = text.find("\n## ", start + 1)
    return text[start:] if end < 0 else text[start:end]


def test_readme_plausibility_rows_are_rows_of_the_generated_table():
    limits = _section((ROOT / "README.md").read_text(encoding="utf-8"), "Limits")
    rows = [line for line in limits.splitlines() if line.startswith("| `")]
    generated = set(limits_markdown().splitlines())
    assert len(rows) >= 5
    stale = [row for row in rows if row not in generated]
    assert not stale, f"README Limits rows that differ from semslam.limits (copy them from docs/limits.md): {stale}"


def test_readme_architecture_names_every_package():
    arch = _section((ROOT / "README.md").read_text(encoding="utf-8"), "Architecture")
    packages = sorted(p.name for p in (ROOT / "semslam").iterdir() if (p / "__init__.py").is_file())
    assert "run" in packages and "slam" in packages
    missing = [name for name in packages if f"`{name}`" not in arch]
    assert not missing, f"packages missing from the README's Architecture section: {missing}"


FILE_SUFFIXES = (".json", ".jsonl", ".mcap", ".csv", ".ply", ".toml", ".md", ".py", ".html", ".npz", ".pcd", ".tum",
                 ".kitti", ".txt")


def _resolves(dotted: str) -> bool:
    """``semslam.a.b.C.d`` names a module, or an attribute reached from the longest importable module prefix."""
    import importlib

    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


def _named_objects(page: Path) -> list[str]:
    """Backticked dotted names of semslam objects on a page: ``semslam.x.y`` anywhere, and in the README's
    Architecture section also ``x.y`` relative to ``semslam`` (the path of a message through the packages)."""
    text = page.read_text(encoding="utf-8")
    tops = {p.stem for p in (ROOT / "semslam").iterdir() if not p.name.startswith(("_", "."))}
    names = [t for t in re.findall(r"`(semslam(?:\.\w+)+)", text)]
    if page.name == "README.md":
        arch = _section(text, "Architecture")
        names += ["semslam." + t for t in re.findall(r"`(\w+(?:\.\w+)+)", arch)
                  if t.split(".")[0] in tops and not t.endswith(FILE_SUFFIXES)]
    return sorted(set(n for n in names if not n.endswith(FILE_SUFFIXES)))


def test_named_objects_are_found_by_the_resolver():
    assert _resolves("semslam.run.sources.open_dive") and _resolves("semslam.slam.SlamSession.add_dvl")
    assert not _resolves("semslam.slam.run_slam") and not _resolves("semslam.no_such_package.thing")


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_named_semslam_objects_exist(page):
    missing = [name for name in _named_objects(page) if not _resolves(name)]
    assert not missing, f"{page.name} names semslam objects that do not exist (moved or renamed?): {missing}"
