"""View-database benchmarks: file load time at scale, chi-square query time, leave-one-out accuracy on the
built-in database, and unknown-object rejection (false accepts on clutter, true accepts on new views).

Run from the repository root::

    .venv/bin/python benchmarks/database.py                      # everything
    .venv/bin/python benchmarks/database.py --only io            # load time of a 10,000-view file
    .venv/bin/python benchmarks/database.py --only loo --only reject --db builtin.npz
    .venv/bin/python benchmarks/database.py --only dense-model --faces 1000000   # db build of one dense CAD mesh

Prints markdown tables. Timings are wall-clock on the current machine (best of ``--repeat``).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def best_of(fn, repeat: int) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def synthetic_big_db(n_views: int, points_per_view: int, seed: int = 0):
    """A database of random views and histograms (no descriptor computation): sizes as real ones."""
    from semslam.recognition import ViewDatabase
    from semslam.symmetry import Symmetry

    rng = np.random.default_rng(seed)
    n_classes = 20
    labels = np.array([f"class_{i % n_classes:02d}" for i in range(n_views)])
    counts = rng.integers(points_per_view // 2, 3 * points_per_view // 2, size=n_views)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    esf = rng.dirichlet(np.ones(640), size=n_views).astype(np.float32)
    vfh = (100 * rng.dirichlet(np.ones(308), size=n_views)).astype(np.float32)
    classes = {f"class_{i:02d}": {"symmetry": Symmetry(), "size_xyz_m": np.full(3, 0.1)} for i in range(n_classes)}
    return ViewDatabase(labels, np.array([f"view_{i:05d}" for i in range(n_views)]), offsets,
                        rng.normal(scale=0.05, size=(offsets[-1], 3)).astype(np.float32),
                        rng.normal(size=(n_views, 3)), esf, vfh, classes, {"vfh_variant": "synthetic"})


def bench_io(args) -> None:
    from semslam.recognition import Chi2NearestNeighbor, load_database, save_database

    print(f"\n### Database file I/O ({args.n_views} views, ~{args.points_per_view} points each)\n")
    db = synthetic_big_db(args.n_views, args.points_per_view)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.npz"
        t_save, _ = best_of(lambda: save_database(db, path), 1)
        size_mb = path.stat().st_size / 1e6
        t_load, loaded = best_of(lambda: load_database(path), args.repeat)
        t_load_nv, _ = best_of(lambda: load_database(path, verify=False), args.repeat)
        assert np.array_equal(loaded.esf, db.esf)
    clf = Chi2NearestNeighbor().fit(db.features("esf"), db.labels)
    q = db.features("esf")[:10]
    clf.kneighbors(q[:1])  # compile / warm up
    t_q, _ = best_of(lambda: clf.kneighbors(q), args.repeat)
    print("| operation | value |")
    print("|---|---:|")
    print(f"| file size | {size_mb:.1f} MB |")
    print(f"| save (atomic, checksums) | {t_save:.3f} s |")
    print(f"| load with checksum verification | {t_load:.3f} s |")
    print(f"| load without verification | {t_load_nv:.3f} s |")
    print(f"| chi-square 1-NN query, ESF vs {args.n_views} views | {1000 * t_q / len(q):.2f} ms/query |")


def get_builtin_db(args):
    from semslam.recognition import build_database, load_database, save_database
    from semslam.simulation import builtin_view_clouds

    if args.db and Path(args.db).exists():
        return load_database(args.db)
    t0 = time.perf_counter()
    views, classes = builtin_view_clouds(seed=args.seed, n_views=8)
    db = build_database(views, classes, seed=args.seed)
    print(f"\n(built-in database built in {time.perf_counter() - t0:.1f} s)")
    if args.db:
        save_database(db, args.db)
    return db


def bench_loo(args, db) -> None:
    from semslam.evaluation.classifier import leave_one_out

    print(f"\n### Leave-one-out on the built-in database ({db.n_views} views, seed {args.seed})\n")
    print("| descriptor | classifier | accuracy | per-class recall | time |")
    print("|---|---|---:|---|---:|")
    for descriptor in ("esf", "vfh", "esf+vfh"):
        for classifier in ("chi2", "svm"):
            t0 = time.perf_counter()
            res = leave_one_out(db, descriptor=descriptor, classifier=classifier, seed=args.seed)
            dt = time.perf_counter() - t0
            recall = ", ".join(f"{k} {100 * v:.0f}%" for k, v in res.recall.items())
            print(f"| {descriptor} | {classifier} | {100 * res.accuracy:.2f}% ({res.n_correct}/{res.n_views}) "
                  f"| {recall} | {dt:.1f} s |")


def novel_views(args):
    """Views of the built-in objects from azimuths between the database's (odd views of 16), new noise."""
    from semslam.simulation import builtin_view_clouds

    views, _ = builtin_view_clouds(seed=args.seed + 1000, n_views=16)
    per_label: dict[str, int] = {}
    out = []
    for label, view_id, cloud in views:
        k = per_label.get(label, 0)
        per_label[label] = k + 1
        if k % 2 == 1:
            out.append((label, cloud))
    return out


def clutter(args):
    """Unknown objects: the simulator's rocks and pipe offcuts (its private mesh makers, seen by the same
    Kinect-like camera as the database) when it has them, plus synthetic rocks, pipes and wall pieces."""
    from semslam.simulation.synthetic_views import clutter_clouds

    out = [(f"synthetic {kind}", cloud) for kind, cloud in clutter_clouds(args.n_clutter, n_points=2000, seed=args.seed)]
    try:
        from semslam.simulation import kinect_view, make_object
        from semslam.simulation.world import _offcut, _rock
    except ImportError:
        return out
    rng = np.random.default_rng(args.seed + 7)
    for k in range(args.n_clutter):
        kind, make = ("simulator rock", _rock) if k % 2 == 0 else ("simulator pipe offcut", _offcut)
        model = make_object(f"clutter_{k}", make(rng))
        out.append((kind, kinect_view(model, rng.uniform(0, 2 * np.pi), seed=rng)))
    return out


def bench_reject(args, db) -> None:
    from scipy.spatial.transform import Rotation

    from semslam.geometry import RigidTransform
    from semslam.recognition import Chi2NearestNeighbor

    rng = np.random.default_rng(args.seed)

    def to_sensor_frame(cloud):  # queries arrive in the scanner frame, not the object frame
        T = RigidTransform.from_rotation_translation(Rotation.random(random_state=rng).as_matrix(),
                                                     rng.uniform(-1, 1, 3))
        return cloud.transformed(T, frame_id="sensor")

    known = [(lab, to_sensor_frame(c)) for lab, c in novel_views(args)]
    unknown = [(kind, to_sensor_frame(c)) for kind, c in clutter(args)]
    desc = {}
    for name, items in (("known", known), ("unknown", unknown)):
        d = [db.describe(c, seed=args.seed + i) for i, (_, c) in enumerate(items)]
        desc[name] = (np.array([x.esf for x in d]), np.array([x.vfh for x in d]))
    print(f"\n### Unknown-object rejection ({len(known)} new views of known objects, {len(unknown)} clutter "
          f"clouds: {', '.join(sorted({k for k, _ in unknown}))})\n")
    print("| descriptor | mode | quantile | margin | known accepted & correct | known rejected | "
          "clutter falsely accepted |")
    print("|---|---|---:|---:|---:|---:|---:|")
    from semslam.recognition import combine_descriptors

    y_known = np.array([lab for lab, _ in known])
    for descriptor in ("esf", "vfh", "esf+vfh"):
        for mode in ("global", "per_class"):
            for q, m in ((0.95, 1.0), (0.95, 1.5), (1.0, 1.0), (1.0, 1.5)):
                clf = Chi2NearestNeighbor(rejection=mode, reject_quantile=q, reject_margin=m).fit(
                    db.features(descriptor), db.labels)
                pk = clf.predict(combine_descriptors(descriptor, *desc["known"]))
                pu = clf.predict(combine_descriptors(descriptor, *desc["unknown"]))
                ok = np.mean(pk == y_known)
                rej = np.mean(pk == "unknown")
                far = np.mean(pu != "unknown")
                print(f"| {descriptor} | {mode} | {q} | {m} | {100 * ok:.1f}% | {100 * rej:.1f}% | {100 * far:.1f}% |")
                if (descriptor, mode, q, m) == ("esf", "global", 0.95, 1.0):
                    kinds = np.array([k for k, _ in unknown])
                    default_far = {k: float(np.mean(pu[kinds == k] != "unknown")) for k in sorted(set(kinds))}
    print("\nDefault (esf, global, 0.95, 1.0) false accepts by clutter kind: "
          + ", ".join(f"{k} {100 * v:.0f}%" for k, v in default_far.items()))


def dense_model(faces: int, folder: Path) -> int:
    """A valve-like mesh of about ``faces`` triangles (a sphere body, a pipe through it, a stem and a handwheel
    torus) written as ``folder/dense_valve.stl`` with its ``models.toml``; returns the face count."""
    import trimesh

    k = max(faces / 937_280, 1e-3) ** 0.5  # the defaults below give 937,280 faces
    body = trimesh.creation.icosphere(subdivisions=max(1, min(8, round(7 + np.log2(k)))), radius=0.08)
    pipe = trimesh.creation.cylinder(radius=0.04, height=0.4, sections=max(16, int(2000 * k)))
    pipe.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    stem = trimesh.creation.cylinder(radius=0.012, height=0.2, sections=max(16, int(400 * k)))
    stem.apply_translation([0, 0, 0.1])
    wheel = trimesh.creation.torus(major_radius=0.08, minor_radius=0.01, major_sections=max(16, int(1500 * k)),
                                   minor_sections=max(8, int(200 * k)))
    wheel.apply_translation([0, 0, 0.2])
    mesh = trimesh.util.concatenate([body, pipe, stem, wheel])
    mesh.export(folder / "dense_valve.stl")
    (folder / "models.toml").write_text('[dense_valve]\nfile = "dense_valve.stl"\nunit = "m"\n')
    return len(mesh.faces)


def bench_dense_model(args) -> None:
    """``semslam db build --models DIR --sensor laser`` of one dense mesh in a fresh process: wall time and the
    child's peak resident memory (the user's path: a CAD export at full tessellation)."""
    import resource
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "models"
        folder.mkdir()
        n = dense_model(args.faces, folder)
        size_mb = (folder / "dense_valve.stl").stat().st_size / 1e6
        cmd = [sys.executable, "-m", "semslam.cli.main", "db", "build", "--models", str(folder), "--sensor", "laser",
               "--out", str(Path(tmp) / "db.npz")]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        wall = time.perf_counter() - t0
        rss_gb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20
    print("\n## `db build --models DIR --sensor laser` of one dense mesh (fresh process)\n")
    print("| faces | STL MB | wall s | peak RSS GB |\n|---:|---:|---:|---:|")
    print(f"| {n} | {size_mb:.1f} | {wall:.1f} | {rss_gb:.2f} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--only", action="append", choices=("io", "loo", "reject", "dense-model"))
    p.add_argument("--faces", type=int, default=1_000_000, help="faces of the dense-model mesh (about)")
    p.add_argument("--n-views", type=int, default=10000)
    p.add_argument("--points-per-view", type=int, default=1000)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-clutter", type=int, default=60)
    p.add_argument("--db", help="built-in database file: read if it exists, else built and written there")
    args = p.parse_args()
    parts = args.only or ["io", "loo", "reject", "dense-model"]
    if "io" in parts:
        bench_io(args)
    if "dense-model" in parts:
        bench_dense_model(args)
    if "loo" in parts or "reject" in parts:
        db = get_builtin_db(args)
        if "loo" in parts:
            bench_loo(args, db)
        if "reject" in parts:
            bench_reject(args, db)


if __name__ == "__main__":
    main()
