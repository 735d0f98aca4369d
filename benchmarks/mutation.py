"""Mutation score of the SLAM core (``semslam/slam/``, ``slam/graph/``) and of the numba descriptor kernels.

The SLAM part also covers the modules that moved out of ``slam/`` in issue 30 (run directory and exports to
``run/``, detections to ``io/``, evaluation against truth to ``evaluation/``): the same set of code as before.

Not run in CI: a benchmark (issue 20, item 2). The tool is **cosmic-ray** (``pip install -e .[mutation]``):
it rewrites one module on disk per mutant and runs a test command, so it mutates numba ``@njit`` kernels like any
other code (mutmut 3 skips every decorated function, i.e. every kernel, and its trampolines cannot run inside
nopython code). Everything happens on a snapshot of the work tree (``--workdir``, default
``/tmp/semslam-mutation``): the repository itself is never rewritten.

For each module, the test command runs only a targeted subset of tests, with ``pytest -x``: first the tests
laid out beside the module (for ``semslam/P/M.py``: ``tests/P/test_M*.py``, with ``M`` without its leading
underscore; a kernel module ``_X_kernels.py`` also ``tests/P/test_X*.py``; the graph subpackage's are under
``tests/slam/``, with ``tests/slam/test_graph*.py`` for every module of it; a module at the package root:
``tests/core/``), then, for a module split out of another (``SPLIT_FROM``), that module's tests, then
``MODULE_TESTS`` below (file names, found anywhere under ``tests/``), under a per-mutant timeout of
``max(20 s, 3 x baseline + 10 s)`` where the baseline is the same command on the unmutated snapshot (which must
pass, or the module is refused). Numba: every test process gets ``NUMBA_CACHE_DIR`` = a cache warmed on the
unmutated snapshot; when the mutated module is a kernel module (it contains ``@njit``), the test process gets a
private copy of that cache with the mutated module's entries deleted, so the mutant is really compiled by numba
(the JIT is kept: the kernels' tests are 10-100x too slow under ``NUMBA_DISABLE_JIT=1``, and pure Python is not
the code that ships: integer wrap-around, typing and bounds differ).

Operators (one replacement per site, as mutmut does, to keep the count tractable): ``+ -> -``, ``- -> +``,
``* -> /``, ``/ -> *``, ``// -> /``, ``% -> /``, ``** -> *``, ``<< -> >>``, ``>> -> <<``, ``& -> |``, ``| -> &``,
``^ -> &``; comparisons ``== <-> !=``, ``is <-> is not``, ``< -> <=``, ``<= -> <``, ``> -> >=``, ``>= -> >``;
``-x -> +x``, ``not x -> x``, ``x -> not x`` (conditions), ``True <-> False``, ``and <-> or``, ``break <->
continue``, ``for`` loops iterating zero times, number ``n -> n + 1``, ``except E -> except <never raised>``.
Mutants inside annotations are not run: every module has ``from __future__ import annotations``, so annotations
are never evaluated (they are reported in the ``annot.`` column, not in the score).

Equivalent mutants are listed by hand in ``benchmarks/mutation_equivalents.toml`` (module, line, operator,
optional column, reason) and excluded from the denominator. Score = (killed + timeout) / (mutants - equivalent).

Usage (2 cores shared: one test process at a time, niced)::

    nice -n 10 .venv/bin/python benchmarks/mutation.py --part slam        # semslam/slam/ and slam/graph/
    nice -n 10 .venv/bin/python benchmarks/mutation.py --part kernels     # descriptor kernels
    nice -n 10 .venv/bin/python benchmarks/mutation.py --modules semslam/slam/ekf.py --max-per-module 80
    .venv/bin/python benchmarks/mutation.py --report                      # table of what has been run so far
    .venv/bin/python benchmarks/mutation.py --survivors semslam/slam/ekf.py   # diffs of the survivors

Sessions are resumable (``cosmic-ray exec`` runs only pending mutants); ``--fresh`` starts over. With
``--max-per-module N``, a module with more mutants runs a seeded random sample of N (``--seed``), and the table
says so (``sampled/total``): the score is then an estimate, given with its 95 % Wilson interval. A larger
``--max-per-module`` on an existing session *extends* its sample: the mutants already run are kept and the new
ones are the first of a seeded shuffle (``--seed``) of the rest, so the union is again a uniform random sample of
the module's mutants (a simple random sample plus a simple random sample of the remainder); it is the sample a
fresh session would draw only when the earlier sample size was the same.
``--trim-pending`` ends an interrupted session: its pending mutants are put out of the sample. cosmic-ray runs
pending mutants in random order, so those that were run are a random subsample of the seeded sample (a uniform
random sample still, though not reproducible from the seed).

Stale sessions: each session records the sha256 of the module it mutated. ``--refresh`` copies the current
``semslam/`` (and tests) into the snapshot; a session whose module has changed since is then moved to
``sessions/stale/`` when that module is run again (and started afresh on the new code), and the report marks a
row whose results are from an older version of the module (``older code``). An existing session's baseline
(its test command on the unmutated snapshot) is re-checked before pending mutants are run: the tests may have
changed since the session was made.

The report ends with an estimate for all of ``slam/`` that accounts for the stratified sample (the modules are
the strata): each module's score weighted by its estimated number of non-equivalent mutants
(``N_h (n_h - e_h) / n_h``: ``N_h`` mutants, ``n_h`` run, ``e_h`` of them equivalent), with a 95 % interval from
MOVER (Zou & Donner 2008) on the per-module Wilson intervals (a module run in full has no sampling error; a
sampled one a finite-population correction ``sqrt((N_h - n_h) / (N_h - 1))``).
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import math
import os
import random
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EQUIVALENTS = ROOT / "benchmarks" / "mutation_equivalents.toml"

# moved out of semslam/slam/ (issue 30): still part of the SLAM score
MOVED_FROM_SLAM = ["semslam/evaluation/metrics.py", "semslam/evaluation/motion_noise.py",
                   "semslam/evaluation/slam_run.py", "semslam/io/detections.py", "semslam/run/dataset_loop.py",
                   "semslam/run/export.py", "semslam/run/export_mcap.py", "semslam/run/rundir.py"]
SLAM_MODULES = sorted([str(p.relative_to(ROOT)) for p in (ROOT / "semslam" / "slam").rglob("*.py")
                       if p.name != "__init__.py"] + [m for m in MOVED_FROM_SLAM if (ROOT / m).exists()])
KERNEL_MODULES = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "semslam" / "descriptors").glob("_*.py")
                        if p.name != "__init__.py")

_EKF = ["test_oracle_ekf.py", "test_ekf.py", "test_oracle_smoother.py", "test_oracle_association.py",
        "test_oracle_symmetry.py", "test_oracle_metrics.py"]
# module -> the tests that exercise it directly (fast: seconds, not the whole suite), by file name: each is found
# wherever it is under tests/ (a name found twice must be given with its folder, e.g. "slam/test_config.py")
MODULE_TESTS: dict[str, list[str]] = {
    "semslam/slam/_ekf_kernels.py": _EKF,
    "semslam/slam/ekf.py": _EKF + ["test_bad_inputs_slam.py"],
    "semslam/slam/compressed.py": ["test_oracle_ekf.py", "test_ekf.py", "test_oracle_smoother.py"],
    "semslam/slam/association.py": ["test_oracle_association.py", "test_oracle_symmetry.py",
                                    "test_oracle_metrics.py", "test_ekf.py", "test_bad_inputs_slam.py"],
    "semslam/slam/consensus.py": ["test_oracle_symmetry.py", "test_bad_inputs_slam.py"],
    "semslam/evaluation/metrics.py": ["test_oracle_metrics.py", "test_bad_inputs_slam.py"],
    "semslam/slam/smoother.py": ["test_oracle_smoother.py", "test_smoother.py"],
    "semslam/evaluation/slam_run.py": ["test_evaluation.py", "test_bad_inputs_slam.py"],
    "semslam/slam/config.py": ["test_bad_inputs_slam.py", "test_slam_runner.py"],
    "semslam/io/detections.py": ["test_bad_inputs_slam.py", "test_slam_runner.py"],
    "semslam/evaluation/motion_noise.py": ["test_dvl_outage.py", "test_slam_realism.py"],
    "semslam/slam/sensors.py": ["test_slam_realism.py", "test_dvl_outage.py", "test_slam_runner.py"],
    "semslam/slam/session.py": ["test_slam_runner.py", "test_bad_inputs_slam.py", "test_dvl_outage.py"],
    "semslam/run/dataset_loop.py": ["test_slam_runner.py", "test_bad_inputs_slam.py"],   # was slam/runner.py
    "semslam/slam/initial.py": ["test_slam_start.py", "test_dataset.py"],
    "semslam/slam/survey.py": ["test_bad_inputs_slam.py"],
    "semslam/slam/mapping.py": ["test_slam_runner.py", "test_export.py"],
    "semslam/slam/results.py": ["test_slam_runner.py", "test_export.py"],
    "semslam/run/rundir.py": ["test_slam_runner.py", "test_export.py", "test_bag_dataset.py"],
    "semslam/run/export.py": ["test_export.py"],
    "semslam/run/export_mcap.py": ["test_export.py"],
    "semslam/slam/graph/backend.py": ["test_graph_backend.py", "test_graph_factors.py", "test_graph_robust.py"],
    "semslam/slam/graph/factors.py": ["test_graph_factors.py", "test_graph_robust.py"],
    "semslam/slam/graph/frontend.py": ["test_graph_backend.py", "test_graph_robust.py"],
    "semslam/slam/graph/segment.py": ["test_graph_backend.py", "test_graph_robust.py"],
    "semslam/slam/graph/session.py": ["test_graph_backend.py", "test_graph_robust.py"],
    "semslam/descriptors/_esf_kernels.py": ["test_esf.py"],
    "semslam/descriptors/_fpfh_kernels.py": ["test_fpfh.py", "test_fpfh_bounded.py"],
    "semslam/descriptors/_neighbors_kernels.py": ["test_neighbors.py", "test_fpfh_bounded.py"],
    "semslam/descriptors/_normals_kernels.py": ["test_normals.py"],
    "semslam/descriptors/_pair_kernels.py": ["test_fpfh.py", "test_vfh.py"],
}

# a module split out of another (issue 30) also runs the tests of the module it came from
SPLIT_FROM: dict[str, str] = {
    "semslam/descriptors/_glibc_rand_kernels.py": "semslam/descriptors/_esf_kernels.py",
    "semslam/descriptors/_vfh_kernels.py": "semslam/descriptors/_pair_kernels.py",
    "semslam/slam/association_search.py": "semslam/slam/association.py",
    "semslam/slam/consistency.py": "semslam/evaluation/metrics.py",
    "semslam/slam/session_inputs.py": "semslam/slam/session.py",
    "semslam/slam/session_result.py": "semslam/slam/session.py",
}

OPERATORS = {
    "core/ReplaceBinaryOperator_Add_Sub", "core/ReplaceBinaryOperator_Sub_Add",
    "core/ReplaceBinaryOperator_Mul_Div", "core/ReplaceBinaryOperator_Div_Mul",
    "core/ReplaceBinaryOperator_FloorDiv_Div", "core/ReplaceBinaryOperator_Mod_Div",
    "core/ReplaceBinaryOperator_Pow_Mul", "core/ReplaceBinaryOperator_LShift_RShift",
    "core/ReplaceBinaryOperator_RShift_LShift", "core/ReplaceBinaryOperator_BitAnd_BitOr",
    "core/ReplaceBinaryOperator_BitOr_BitAnd", "core/ReplaceBinaryOperator_BitXor_BitAnd",
    "core/ReplaceComparisonOperator_Eq_NotEq", "core/ReplaceComparisonOperator_NotEq_Eq",
    "core/ReplaceComparisonOperator_Is_IsNot", "core/ReplaceComparisonOperator_IsNot_Is",
    "core/ReplaceComparisonOperator_Lt_LtE", "core/ReplaceComparisonOperator_LtE_Lt",
    "core/ReplaceComparisonOperator_Gt_GtE", "core/ReplaceComparisonOperator_GtE_Gt",
    "core/ReplaceUnaryOperator_USub_UAdd", "core/ReplaceUnaryOperator_Delete_Not", "core/AddNot",
    "core/ReplaceTrueWithFalse", "core/ReplaceFalseWithTrue", "core/ReplaceAndWithOr", "core/ReplaceOrWithAnd",
    "core/ReplaceBreakWithContinue", "core/ReplaceContinueWithBreak", "core/ZeroIterationForLoop",
    "core/NumberReplacer", "core/ExceptionReplacer",
}

SKIP_OPERATOR = "operator not in the set"
SKIP_ANNOTATION = "inside an annotation (never evaluated)"
SKIP_NUMBER_MINUS = "NumberReplacer n - 1 (only n + 1 is run)"
SKIP_SAMPLE = "not in the sample"


def _short(module: str) -> str:
    return module.removeprefix("semslam/")


def _stem(module: str) -> str:
    return Path(module).stem.lstrip("_")


def _tests_dir(module: str) -> str:
    """The tests folder of a module, laid out like the code: ``semslam/P/M.py`` -> ``P``, ``semslam/M.py`` ->
    ``core``; a subpackage's tests are with its package's (``semslam/slam/graph/M.py`` -> ``slam``)."""
    parts = Path(module).parts[1:-1]
    return parts[0] if parts else "core"


def _beside(module: str, tree: Path) -> list[str]:
    """The tests laid out beside ``module`` (see the module docstring), as paths relative to ``tree``."""
    folder = tree / "tests" / _tests_dir(module)
    stem = _stem(module)
    patterns = [f"test_{stem}*.py"]
    if stem.endswith("_kernels"):   # _esf_kernels.py: its tests are those of the module it serves, test_esf*.py
        patterns.append(f"test_{stem.removesuffix('_kernels')}*.py")
    if Path(module).parent.name == "graph":   # tests/slam/test_graph*.py: the graph subpackage's
        patterns.append("test_graph*.py")
    found = [p for pat in patterns for p in sorted(folder.glob(pat))]
    return [str(p.relative_to(tree)) for p in found]


def _find_test(name: str, tree: Path) -> str:
    """A ``MODULE_TESTS`` entry (a file name, or a path under ``tests/``) as a path relative to ``tree``."""
    tests = tree / "tests"
    hits = [tests / name] if "/" in name else sorted(tests.rglob(name))
    hits = [p for p in hits if p.is_file() and "data" not in p.relative_to(tests).parts[:-1]]
    if len(hits) != 1:
        what = "not found" if not hits else f"found {len(hits)} times ({', '.join(str(p) for p in hits)})"
        raise SystemExit(f"mutation: MODULE_TESTS: tests/**/{name} {what} (give its folder, e.g. slam/{name})")
    return str(hits[0].relative_to(tree))


def _tests_for(module: str, tree: Path) -> list[str]:
    # the targeted tests first: a mutant that survived the module's other tests before they were written is then
    # killed in seconds (``pytest -x``); the set of tests, hence killed or not, does not depend on the order
    files = _beside(module, tree)
    parent = SPLIT_FROM.get(module)
    if parent is not None:
        files += _beside(parent, tree) + [_find_test(f, tree) for f in MODULE_TESTS.get(parent, [])]
    files += [_find_test(f, tree) for f in MODULE_TESTS.get(module, [])]
    if not files:
        raise SystemExit(f"mutation: no tests for {module} (none in tests/{_tests_dir(module)}/test_"
                         f"{_stem(module)}*.py; add it to MODULE_TESTS)")
    return list(dict.fromkeys(files))


def _is_kernel(path: Path) -> bool:
    return "@njit" in path.read_text()


# -------------------------------------------------------------------------------------------- snapshot
def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else ""


def _session_sha(cfg: Path) -> str | None:
    for line in cfg.read_text().splitlines() if cfg.exists() else []:
        if line.startswith("# module sha256 "):
            return line.split()[-1]
    return None


def snapshot(workdir: Path, fresh: bool, refresh: bool = False) -> Path:
    """Copy semslam/, tests/ and pyproject.toml to ``workdir/tree`` (once; ``--fresh`` redoes it; ``--refresh``
    copies the current code over the snapshot, after recording in each session the hash of the code it ran on)."""
    tree = workdir / "tree"
    if fresh and workdir.exists():
        shutil.rmtree(workdir)
    if refresh and tree.exists():
        for cfg in sorted((workdir / "sessions").glob("*.toml")):
            if _session_sha(cfg) is None:   # a session made before hashes were recorded: the snapshot's code
                module = _module_of(cfg)
                if module is not None:
                    cfg.write_text(cfg.read_text() + f"# module sha256 {_sha(tree / module)}\n")
        shutil.rmtree(tree / "semslam")
    if refresh or not tree.exists():
        ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.pyc")
        tree.mkdir(parents=True, exist_ok=True)
        shutil.copytree(ROOT / "semslam", tree / "semslam", ignore=ignore)
        shutil.copytree(ROOT / "tests", tree / "tests", ignore=ignore, dirs_exist_ok=True)
        shutil.copy2(ROOT / "pyproject.toml", tree / "pyproject.toml")
    else:  # new, moved or strengthened tests (and helpers) are picked up; the code under test stays the snapshot
        for p in (ROOT / "tests").rglob("*.py"):
            rel = p.relative_to(ROOT)
            if "__pycache__" in rel.parts or "data" in rel.parts:
                continue
            dst = tree / rel
            if not dst.exists() or p.read_bytes() != dst.read_bytes():
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(p, dst)
        if (ROOT / "pyproject.toml").read_bytes() != (tree / "pyproject.toml").read_bytes():   # pytest's options
            shutil.copy2(ROOT / "pyproject.toml", tree / "pyproject.toml")
    return tree


# ------------------------------------------------------------------------------------ the test command
def run_tests(module: str, tree: Path, workdir: Path, warm: bool = False) -> int:
    """The per-mutant test command (``mutation.py _test``): a fresh numba cache for a mutated kernel module.
    ``warm``: on the unmutated snapshot, fill the shared cache instead (every kernel compiled once)."""
    env = dict(os.environ)
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env.setdefault("SEMSLAM_SHARED", str(ROOT.parent / "shared"))
    base = workdir / "numba-cache"
    private = None
    if _is_kernel(tree / module) and not warm:
        private = Path(tempfile.mkdtemp(prefix="numba-", dir=workdir))
        if base.exists():
            shutil.copytree(base, private, dirs_exist_ok=True)
        prefix = Path(module).stem + "."
        for p in private.rglob(prefix + "*"):
            p.unlink()
        env["NUMBA_CACHE_DIR"] = str(private)
    else:
        env["NUMBA_CACHE_DIR"] = str(base)
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "--no-header",
           *_tests_for(module, tree)]
    try:
        return subprocess.call(cmd, cwd=tree, env=env)
    finally:
        if private is not None:
            shutil.rmtree(private, ignore_errors=True)


# ---------------------------------------------------------------------------------------- one session
def _annotation_spans(path: Path) -> list[tuple[int, int, int, int]]:
    tree = ast.parse(path.read_text())
    if not any(isinstance(n, ast.ImportFrom) and n.module == "__future__"
               and any(a.name == "annotations" for a in n.names) for n in tree.body):
        return []
    spans = []
    for node in ast.walk(tree):
        anns = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            anns.append(node.returns)
            a = node.args
            for arg in a.posonlyargs + a.args + a.kwonlyargs + [a.vararg, a.kwarg]:
                if arg is not None:
                    anns.append(arg.annotation)
        elif isinstance(node, ast.AnnAssign):
            anns.append(node.annotation)
        for ann in anns:
            if ann is not None:
                spans.append((ann.lineno, ann.col_offset, ann.end_lineno, ann.end_col_offset))
    return spans


def _inside(row: int, col: int, spans) -> bool:
    return any((r0, c0) <= (row, col) < (r1, c1) for r0, c0, r1, c1 in spans)


def _session_paths(workdir: Path, module: str) -> tuple[Path, Path]:
    name = module.replace("/", "__").removesuffix(".py")
    return workdir / "sessions" / f"{name}.toml", workdir / "sessions" / f"{name}.sqlite"


def _module_of(cfg: Path) -> str | None:
    for m in SLAM_MODULES + KERNEL_MODULES:
        if _session_paths(cfg.parent.parent, m)[0].name == cfg.name:
            return m
    return None


def _baseline(module: str, workdir: Path, warm: bool = True) -> tuple[int, float]:
    """The module's test command on the unmutated snapshot (after a warm-up that fills the numba cache; not when
    re-checking an existing session, whose module's kernels are in the cache already)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "_test", module, "--workdir", str(workdir)]
    if warm:
        subprocess.call(cmd + ["--warm"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)   # warm-up
    t0 = time.monotonic()
    rc = subprocess.call(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return rc, time.monotonic() - t0


def _sample_order(jobs: list[str], seed: int, module: str) -> list[str]:
    """The order in which an existing session's sample is extended (seeded shuffle of the sorted jobs)."""
    return random.Random(f"{seed}:{module}:extend").sample(jobs, len(jobs))


def _eligible(db: Path) -> tuple[list[str], dict[str, tuple]]:
    """Jobs that are not skipped for a reason other than the sample, sorted by position; their result rows."""
    con = sqlite3.connect(db)
    rows = con.execute("SELECT s.job_id, s.operator_name, s.occurrence, s.start_pos_row, s.start_pos_col, "
                       "r.worker_outcome, r.output FROM mutation_specs s LEFT JOIN work_results r "
                       "ON r.job_id = s.job_id").fetchall()
    con.close()
    keep = [(row, col, op, occ, job) for job, op, occ, row, col, wo, out in rows
            if not (wo == "SKIPPED" and out != SKIP_SAMPLE)]
    return [job for *_, job in sorted(keep)], {job: (wo, out) for job, _, _, _, _, wo, out in rows}


def extend_sample(module: str, db: Path, max_per_module: int | None, seed: int) -> int:
    """Grow an existing session's sample to ``max_per_module`` (None: every mutant): the mutants already in the
    sample stay; new ones are drawn in :func:`_sample_order`. Returns how many were added (now pending)."""
    eligible, res = _eligible(db)
    out = [j for j in eligible if res[j] == ("SKIPPED", SKIP_SAMPLE)]
    n_in = len(eligible) - len(out)
    want = len(eligible) if max_per_module is None else min(max_per_module, len(eligible))
    if want <= n_in:
        return 0
    add = [j for j in _sample_order(out, seed, module)][:want - n_in]
    con = sqlite3.connect(db)
    con.executemany("DELETE FROM work_results WHERE job_id = ?", [(j,) for j in add])
    con.commit()
    con.close()
    return len(add)


def _pending(db: Path) -> int:
    con = sqlite3.connect(db)
    n = con.execute("SELECT COUNT(*) FROM work_items w LEFT JOIN work_results r ON r.job_id = w.job_id "
                    "WHERE r.job_id IS NULL").fetchone()[0]
    con.close()
    return n


def _cosmic_ray() -> list[str]:
    exe = Path(sys.executable).with_name("cosmic-ray")
    if not exe.exists():
        raise SystemExit("mutation: cosmic-ray is not installed (pip install -e '.[mutation]')")
    return [str(exe)]


def prepare(module: str, tree: Path, workdir: Path, max_per_module: int | None, seed: int) -> tuple[Path, Path]:
    """Baseline, config and session (``cosmic-ray init``) for one module, with the skip marks."""
    cfg, db = _session_paths(workdir, module)
    cfg.parent.mkdir(parents=True, exist_ok=True)
    sha = _session_sha(cfg)
    if db.exists() and sha is not None and sha != _sha(tree / module):   # the module changed (--refresh)
        stale = workdir / "sessions" / "stale"
        stale.mkdir(exist_ok=True)
        for p in (cfg, db):
            p.rename(stale / f"{p.stem}-{sha[:8]}{p.suffix}")
        print(f"mutation: {module} changed since its session: old session moved to {stale}, new session",
              flush=True)
    if db.exists():
        added = extend_sample(module, db, max_per_module, seed) if max_per_module is not None else 0
        if added:
            print(f"mutation: {module}: sample extended by {added}", flush=True)
        return cfg, db
    # baseline on the unmutated snapshot: must pass; warms the shared numba cache
    rc, baseline = _baseline(module, workdir)
    if rc != 0:
        raise SystemExit(f"mutation: the tests of {module} fail on the unmutated code (rc {rc})")
    timeout = max(20.0, 3.0 * baseline + 10.0)
    cfg.write_text(
        "[cosmic-ray]\n"
        f"module-path = \"{tree / module}\"\n"
        f"timeout = {timeout:.1f}\n"
        "excluded-modules = []\n"
        f"test-command = \"{sys.executable} {Path(__file__).resolve()} _test {module} --workdir {workdir}\"\n"
        f"# baseline {baseline:.1f} s\n"
        f"# module sha256 {_sha(tree / module)}\n"
        "[cosmic-ray.distributor]\nname = \"local\"\n")
    subprocess.run(_cosmic_ray() + ["init", str(cfg), str(db)], check=True, stdout=subprocess.DEVNULL)
    spans = _annotation_spans(tree / module)
    con = sqlite3.connect(db)
    rows = con.execute("SELECT job_id, operator_name, occurrence, start_pos_row, start_pos_col "
                       "FROM mutation_specs").fetchall()
    con.close()
    skip: dict[str, str] = {}
    for job, op, occ, row, col in rows:
        if op not in OPERATORS:
            skip[job] = SKIP_OPERATOR
        elif _inside(row, col, spans):
            skip[job] = SKIP_ANNOTATION
        elif op == "core/NumberReplacer" and occ % 2 == 1:
            skip[job] = SKIP_NUMBER_MINUS
    # job ids are random UUIDs: order by position and operator, so that a seed picks the same mutants every time
    eligible = [job for *_, job in sorted((row, col, op, occ, job) for job, op, occ, row, col in rows
                                          if job not in skip)]
    if max_per_module is not None and len(eligible) > max_per_module:
        keep = set(random.Random(f"{seed}:{module}").sample(eligible, max_per_module))
        for job in eligible:
            if job not in keep:
                skip[job] = SKIP_SAMPLE
    from cosmic_ray.work_db import use_db
    from cosmic_ray.work_item import WorkerOutcome, WorkResult
    with use_db(str(db)) as wdb:
        for why in set(skip.values()):
            wdb.set_multiple_results([j for j, w in skip.items() if w == why],
                                     WorkResult(worker_outcome=WorkerOutcome.SKIPPED, output=why))
    return cfg, db


def execute(module: str, tree: Path, workdir: Path, max_per_module: int | None, seed: int,
            rerun_survivors: bool = False, rerun_timeouts: bool = False) -> None:
    cfg0, db0 = _session_paths(workdir, module)
    existed = db0.exists() and _session_sha(cfg0) in (None, _sha(tree / module))   # and not re-made as stale
    cfg, db = prepare(module, tree, workdir, max_per_module, seed)
    jobs: list[str] = []
    if rerun_survivors or rerun_timeouts:
        c = classify(module, workdir, load_equivalents())   # hand-checked equivalents are not run again
        if rerun_survivors:   # after new tests: run the survivors again (the snapshot's tests were refreshed)
            jobs += [job for job, *_ in c["survivor_jobs"]]
        if rerun_timeouts:   # a timeout on a loaded machine may be the load, not the mutant: run those again
            jobs += [job for job, *_ in c["timeout_jobs"]]
        con = sqlite3.connect(db)
        con.executemany("DELETE FROM work_results WHERE job_id = ?", [(j,) for j in jobs])
        con.commit()
        con.close()
    if existed and _pending(db):   # the tests may have changed since the session was made: they must still pass
        rc, baseline = _baseline(module, workdir, warm=False)
        if rc != 0:
            raise SystemExit(f"mutation: the tests of {module} fail on the unmutated code (rc {rc})")
        # the machine may be more loaded than when the session was made: the timeout follows the new baseline
        text = cfg.read_text()
        old_t = float(next(ln.split("=")[1] for ln in text.splitlines() if ln.startswith("timeout =")))
        new_t = max(old_t, 3.0 * baseline + 10.0)
        if new_t > old_t:
            cfg.write_text(text.replace(f"timeout = {old_t:.1f}\n", f"timeout = {new_t:.1f}\n"))
        print(f"mutation: {module}: baseline re-checked ({baseline:.1f} s), {_pending(db)} pending, "
              f"timeout {new_t:.0f} s", flush=True)
    t0 = time.monotonic()
    subprocess.run(_cosmic_ray() + ["exec", str(cfg), str(db)], check=True, cwd=tree)
    print(f"mutation: {module} done in {time.monotonic() - t0:.0f} s", flush=True)


# ---------------------------------------------------------------------------------------------- report
def load_equivalents() -> list[dict]:
    if not EQUIVALENTS.exists():
        return []
    items = tomllib.loads(EQUIVALENTS.read_text()).get("equivalent", [])
    for e in items:
        if not e.get("reason"):
            raise SystemExit(f"mutation: equivalent without a reason: {e}")
    return items


def _is_equivalent(module, op, row, col, equivalents) -> dict | None:
    for e in equivalents:
        if (e["module"] == module and e["line"] == row and e["operator"] == op
                and e.get("col", col) == col):
            return e
    return None


def classify(module: str, workdir: Path, equivalents: list[dict]) -> dict | None:
    _, db = _session_paths(workdir, module)
    if not db.exists():
        return None
    from cosmic_ray.work_db import WorkDB, use_db
    with use_db(str(db), WorkDB.Mode.open) as wdb:
        results = dict(wdb.results)
        rows = []
        for item in wdb.work_items:
            (spec,) = item.mutations
            r = results.get(item.job_id)
            rows.append((item.job_id, spec.operator_name, spec.start_pos[0], spec.start_pos[1],
                         None if r is None else r.worker_outcome.value,
                         None if r is None or r.test_outcome is None else r.test_outcome.value,
                         None if r is None else r.output, None if r is None else r.diff))
    out = {"module": module, "total": 0, "killed": 0, "survived": 0, "timeout": 0, "equivalent": 0,
           "pending": 0, "annotation": 0, "sampled_out": 0, "incompetent": 0, "survivors": [], "unused_eq": [],
           "survivor_jobs": [], "wrong_eq": [], "timeout_jobs": []}
    used = set()
    for job, op, row, col, wo, to, output, diff in rows:
        if wo == "skipped":
            if output == SKIP_ANNOTATION:
                out["annotation"] += 1
            elif output == SKIP_SAMPLE:
                out["sampled_out"] += 1
                eq = _is_equivalent(module, op, row, col, equivalents)
                if eq is not None:   # an entry for a mutant not in the sample: not stale, just not counted
                    used.add(id(eq))
            continue
        out["total"] += 1
        eq = _is_equivalent(module, op, row, col, equivalents)
        if eq is not None:
            used.add(id(eq))
        if eq is not None and to == "killed":   # a test tells it apart: not equivalent, the entry is wrong
            out["killed"] += 1
            out["wrong_eq"].append(eq)
        elif eq is not None:
            out["equivalent"] += 1
        elif wo is None:
            out["pending"] += 1
        elif wo == "no-test":
            out["killed"] += 1     # not applicable: should not happen with a fresh session
        elif to == "killed" and (output or "").strip() == "timeout":
            out["timeout"] += 1
            out["timeout_jobs"].append((job, row, col, op))
        elif to == "killed":
            out["killed"] += 1
        elif to == "incompetent" or wo == "exception":
            out["incompetent"] += 1
        else:
            out["survived"] += 1
            out["survivors"].append((row, col, op, diff))
            out["survivor_jobs"].append((job, row, col, op))
    out["unused_eq"] = [e for e in equivalents if e["module"] == module and id(e) not in used]
    return out


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (c - h, c + h)


def stratified(strata: list[tuple[int, int, int, int]], z: float = 1.96) -> tuple[float, float, float]:
    """Score of a population from a stratified sample, with its 95 % interval.

    ``strata``: per module ``(N, n, e, k)``: mutants in the module, run, equivalent among those run, killed
    among those run. Weight of a module: its estimated number of non-equivalent mutants ``N (n - e) / n``;
    estimate ``p = sum W_h p_h`` with ``p_h = k_h / (n_h - e_h)``. Interval: MOVER (Zou & Donner 2008) for a linear
    combination of proportions on the per-module Wilson intervals ``(l_h, u_h)``:
    ``p - sqrt(sum W_h^2 (p_h - l_h)^2 f_h)``, ``p + sqrt(sum W_h^2 (u_h - p_h)^2 f_h)``, with the
    finite-population correction ``f_h = (N_h - n_h) / (N_h - 1)`` (0 for a module run in full: no sampling error)."""
    rows = [(N * (n - e) / n, n - e, k, N, n) for N, n, e, k in strata if n > e]
    tot = sum(w for w, *_ in rows)
    if not tot:
        return (float("nan"),) * 3
    est = v_lo = v_hi = 0.0
    for w, m, k, N, n in rows:
        w /= tot
        lo, hi = _wilson(k, m, z)
        f = (N - n) / (N - 1) if N > 1 else 0.0
        est += w * k / m
        v_lo += w * w * (k / m - lo) ** 2 * f
        v_hi += w * w * (hi - k / m) ** 2 * f
    return est, max(0.0, est - math.sqrt(v_lo)), min(1.0, est + math.sqrt(v_hi))


def _group(module: str) -> str:
    """The report's group of a module: the SLAM core (with the modules moved out of ``slam/``) or the kernels."""
    return "slam/" if module in SLAM_MODULES or module.startswith("semslam/slam/") else "descriptor kernels"


def report(modules: list[str], workdir: Path) -> str:
    equivalents = load_equivalents()
    strata: dict[str, list] = {}
    head = ("| module | mutants | killed | survived | timeout | equiv. excluded | score | annot. | sample |\n"
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    lines = [head]
    keys = ("total", "killed", "survived", "timeout", "equivalent", "pending", "annotation", "incompetent")
    groups: dict[str, dict] = {}
    for m in modules:
        c = classify(m, workdir, equivalents)
        if c is None:
            lines.append(f"| {_short(m)} | not run | | | | | | | |")
            continue
        tot = groups.setdefault(_group(m),
                                dict.fromkeys(keys, 0))
        for k in keys:
            tot[k] += c[k]
        den = c["total"] - c["equivalent"] - c["pending"]
        hit = c["killed"] + c["timeout"] + c["incompetent"]
        score = f"{100 * hit / den:.1f} %" if den else "-"
        sample = "all"
        if c["sampled_out"]:
            lo, hi = _wilson(hit, den)
            sample = f"{c['total']}/{c['total'] + c['sampled_out']} ({100 * lo:.0f}-{100 * hi:.0f} %)"
        if c["pending"] == 0:
            strata.setdefault(_group(m), []).append(
                (c["total"] + c["sampled_out"], c["total"], c["equivalent"], hit))
        cfg = _session_paths(workdir, m)[0]
        sha = _session_sha(cfg)
        if sha is not None and sha != _sha(workdir / "tree" / m):
            sample += ", older code"
        if sha is not None and sha != _sha(ROOT / m):
            sample += ", work tree changed since"
        pend = f" (+{c['pending']} pending)" if c["pending"] else ""
        lines.append(f"| {_short(m)} | {c['total']}{pend} | {hit} | {c['survived']} | {c['timeout']} | "
                     f"{c['equivalent']} | {score} | {c['annotation']} | {sample} |")
        for e in c["unused_eq"]:
            lines.append(f"|   (stale equivalent entry: line {e['line']} {e['operator']}) | | | | | | | | |")
        for e in c["wrong_eq"]:
            lines.append(f"|   (equivalent entry of a killed mutant: line {e['line']} {e['operator']}) "
                         "| | | | | | | | |")
    for name, t in groups.items():
        den = t["total"] - t["equivalent"] - t["pending"]
        hit = t["killed"] + t["timeout"] + t["incompetent"]
        score = f"{100 * hit / den:.1f} %" if den else "-"
        lines.append(f"| **{name}, all run** | {t['total']} | {hit} | {t['survived']} | {t['timeout']} | "
                     f"{t['equivalent']} | **{score}** | {t['annotation']} | |")
    for name, st in strata.items():
        est, lo, hi = stratified(st)
        N = sum(x[0] for x in st)
        n = sum(x[1] for x in st)
        lines.append(f"| **{name}, stratified estimate** | {n} of {N} | | | | | **{100 * est:.1f} %** | | "
                     f"95 %: {100 * lo:.1f}-{100 * hi:.1f} % |")
    lines.append("")
    lines.append("Stratified estimate: the modules are the strata; each module's score is weighted by its estimated "
                 "number of non-equivalent mutants N_h (n_h - e_h) / n_h (N_h mutants, n_h run, e_h equivalent); "
                 "95 % interval: MOVER (Zou & Donner 2008) on the per-module Wilson intervals, each scaled by the "
                 "finite-population correction sqrt((N_h - n_h) / (N_h - 1)) (no sampling error in a module run in "
                 "full). Modules with pending mutants are left out of it.")
    return "\n".join(lines)


def survivors(module: str, workdir: Path) -> str:
    c = classify(module, workdir, load_equivalents())
    if c is None:
        return f"{module}: not run"
    parts = []
    for row, col, op, diff in sorted(c["survivors"]):
        parts.append(f"### {module}:{row}:{col} {op}\n{diff}")
    return "\n".join(parts) or f"{module}: no survivor"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["_test"]:
        p = argparse.ArgumentParser(prog="mutation.py _test")
        p.add_argument("module")
        p.add_argument("--workdir", type=Path, required=True)
        p.add_argument("--warm", action="store_true")
        a = p.parse_args(argv[1:])
        return run_tests(a.module, a.workdir / "tree", a.workdir, a.warm)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=["slam", "kernels", "all"], default=None)
    p.add_argument("--modules", nargs="*", default=None, help="module paths, e.g. semslam/slam/ekf.py")
    p.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "semslam-mutation")
    p.add_argument("--max-per-module", type=int, default=None, help="seeded random sample per module")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--fresh", action="store_true", help="new snapshot and sessions")
    p.add_argument("--refresh", action="store_true",
                   help="copy the current code into the snapshot (sessions of changed modules are redone)")
    p.add_argument("--report", action="store_true", help="only print the table")
    p.add_argument("--rerun-survivors", action="store_true", help="run the surviving mutants again")
    p.add_argument("--rerun-timeouts", action="store_true", help="run the timed-out mutants again")
    p.add_argument("--trim-pending", action="store_true",
                   help="put the pending mutants of an interrupted session out of the sample (no test is run)")
    p.add_argument("--survivors", metavar="MODULE", help="print the surviving mutants' diffs")
    a = p.parse_args(argv)
    if a.survivors:
        print(survivors(a.survivors, a.workdir))
        return 0
    part = a.part or ("all" if a.modules is None else None)
    modules = list(a.modules or [])
    if part in ("slam", "all"):
        modules += SLAM_MODULES
    if part in ("kernels", "all"):
        modules += KERNEL_MODULES
    modules = list(dict.fromkeys(modules))
    if a.trim_pending:   # cosmic-ray runs pending mutants in random order: what was run is a random subsample
        for m in modules:
            db = _session_paths(a.workdir, m)[1]
            if db.exists() and _pending(db):
                con = sqlite3.connect(db)
                jobs = [r[0] for r in con.execute("SELECT w.job_id FROM work_items w LEFT JOIN work_results r ON "
                                                  "r.job_id = w.job_id WHERE r.job_id IS NULL")]
                con.executemany("INSERT INTO work_results (worker_outcome, output, test_outcome, diff, job_id) "
                                "VALUES ('SKIPPED', ?, NULL, NULL, ?)", [(SKIP_SAMPLE, j) for j in jobs])
                con.commit()
                con.close()
                print(f"mutation: {m}: {len(jobs)} pending mutants put out of the sample", flush=True)
        a.report = True
    if not a.report:
        import cosmic_ray  # noqa: F401  (fail early when the extra is missing)
        from importlib.metadata import version
        print(f"mutation: cosmic-ray {version('cosmic-ray')}, python {sys.version.split()[0]}, "
              f"{len(modules)} module(s), workdir {a.workdir}", flush=True)
        tree = snapshot(a.workdir, a.fresh, a.refresh)
        for m in modules:
            execute(m, tree, a.workdir, a.max_per_module, a.seed, a.rerun_survivors, a.rerun_timeouts)
    print(report(modules, a.workdir))
    return 0


if __name__ == "__main__":
    sys.exit(main())
