"""Real CAD models written by others through the user's path (issue 29, items 3 and 7).

Builds a models folder (``models.toml``, see ``semslam db build --models``) for the shared real models
(``../shared/data/models/``: handwheel valves, a wet-mate receptacle, ASME flanges, a valve panel's front plate and
base), then runs the simulated mission with these objects exactly as ``semslam demo --models DIR --quick`` does
(:func:`semslam.demo.run_demo`) on several seeds, and prints per class: precision, recall, median pose error
(degrees / millimetres), the share of the detections flagged with an ambiguous orientation, and the mean pose NEES
(6-DoF with the detection's covariance against the truth; 3-DoF position NEES for the axisymmetric classes, whose
rotation about the axis is unobservable: the demo's ``pose_error`` leaves their rotation rows out).

The STL/OBJ files are in metres (the shared README). The COLLADA original (``wheel_valve_original.dae``, the same
part as ``wheel_valve.stl``) and the STEP flange (``blind_flange_4in_cl150_mm.step``, the same part as
``blind_flange_4in_cl150.stl``) are read only when :func:`semslam.simulation.cad_models.read_models` accepts them
here (they need pycollada / cascadio and a reader in semslam); otherwise they are listed as skipped.

Symmetries are those of the meshes (measured by turning 4000 surface samples about the axis: the 95th percentile
of the nearest-point distance returns to the sampling noise at that order): blind flange 8 bolt holes about z,
slip-on flange 12 about z, small handwheel 8 about y, valve-panel front 4 about x, valve base and wet-mate
receptacle axisymmetric, large wheel valve none.

Usage::

    python benchmarks/real_models.py --quick --seeds 0 1 2 [--classes wheel_valve blind_flange ...]
    python benchmarks/real_models.py --quick --seeds 1 2 --preset seabed          # the preset chosen on seed 0
    python benchmarks/real_models.py --builtin --quick --seeds 0      # the papers' four fittings, same table
    python benchmarks/real_models.py --builtin --quick --seeds 1 2 --db-sensor laser --preset seabed
    python benchmarks/real_models.py --folder MODELS_DIR --quick --seeds 0 1 2 --db-sensor laser --preset seabed

``--db-sensor`` / ``--preset`` / ``--config`` are the demo's (``semslam demo --db-sensor / --preset / --config``):
the shared models' database is rendered by the mission's laser by default, the fittings' by the Kinect. Recall is
per cluster; a class of the mission that never made a cluster (the blind flange lying against the tank's slope,
one cluster with it, before the ``seabed`` preset's second plane) is named below the table, as it cannot be
counted in it. ``rel6`` is the mean 6-DoF NEES of the reliable poses only (those the filter uses); ``rel`` and
``relprec`` the reliable detections and their precision (a pose cut by the scan border is never reliable).

Each run writes ``OUT/seed_<s>/`` (a demo run directory) and ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED_MODELS = ROOT.parent / "shared" / "data" / "models"

#: class -> (file, unit, symmetry); same part in another format: (class, file, unit) tried as a separate class.
#: The symmetries are the meshes' own (semslam.simulation.model_symmetry measures every one as declared here); until
#: 2026-12-07 the wheel valve was declared "none" (its handwheel has five spokes) and the panel base "continuous:x"
#: (it is also the same end for end, which could not be declared before).
MODELS = {
    "wheel_valve": ("wheel_valve.stl", "m", "discrete:5:x"),
    "hand_wheel_valve": ("hand_wheel_valve.stl", "m", "discrete:8:y"),
    "wetmate_receptacle": ("wetmate_receptacle.stl", "m", "continuous:z"),
    "blind_flange": ("blind_flange_4in_cl150.stl", "m", "discrete:8:z"),
    "slipon_flange": ("slipon_flange_6in_cl300.stl", "m", "discrete:12:z"),
    "tac_valve_front": ("tac_valve_front.obj", "m", "discrete:4:x"),
    "tac_valve_base": ("tac_valve_base.obj", "m", "continuous:x:flip"),
}
#: other formats of parts above (used instead of the STL when they load here)
ALTERNATIVE_FORMATS = {
    "wheel_valve": ("wheel_valve_original.dae", "inch"),
    "blind_flange": ("blind_flange_4in_cl150_mm.step", "mm"),
}


def write_models_folder(dest: Path, classes: list[str] | None = None, *, models_dir: Path = SHARED_MODELS,
                        try_other_formats: bool = True) -> tuple[Path, dict]:
    """``dest/models.toml`` for ``classes`` (default all) with the meshes linked from ``models_dir``. Returns the
    folder and ``{class: file used}``; a format this installation cannot read falls back to the STL/OBJ."""
    from semslam.simulation.cad_models import read_models

    dest.mkdir(parents=True, exist_ok=True)
    used, lines = {}, ["# written by benchmarks/real_models.py from ../shared/data/models (see its README)\n"]
    for label in classes or list(MODELS):
        fname, unit, sym = MODELS[label]
        if try_other_formats and label in ALTERNATIVE_FORMATS:
            alt, alt_unit = ALTERNATIVE_FORMATS[label]
            if _readable(models_dir / alt, alt_unit, sym, read_models):
                fname, unit = alt, alt_unit
        copy = dest / fname
        if not copy.exists():  # a copy: semslam reads no model through a link leading out of the models folder
            shutil.copyfile(models_dir / fname, copy)
        lines.append(f'[{label}]\nfile = "{fname}"\nunit = "{unit}"\nsymmetry = "{sym}"\n')
        used[label] = fname
    (dest / "models.toml").write_text("\n".join(lines))
    return dest, used


def _readable(path: Path, unit: str, sym: str, read_models) -> bool:
    """Whether semslam reads ``path`` here (an optional reader may be missing)."""
    from semslam.errors import SemslamError

    if not path.is_file():
        return False
    with tempfile.TemporaryDirectory(prefix="semslam_probe_") as tmp:
        probe = Path(tmp)
        shutil.copyfile(path, probe / path.name)
        (probe / "models.toml").write_text(f'[probe]\nfile = "{path.name}"\nunit = "{unit}"\nsymmetry = "{sym}"\n')
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                read_models(probe)
            return True
        except SemslamError as exc:
            msg = str(exc).splitlines()[0]
            print(f"# {path.name}: not read here, the STL/OBJ is used ({msg[-160:]})", file=sys.stderr)
            return False


def run_seed(models_dir: Path | None, seed: int, out: Path, *, quick: bool, db_sensor: str | None = None,
             preset: str | None = None, config_file: str | None = None) -> list[dict]:
    """One demo run (the user's path); the clusters of its ``recognition.json``. ``db_sensor`` / ``preset``: the
    demo's (``semslam demo --db-sensor / --preset``), default the demo's defaults."""
    from semslam.demo import DemoConfig, run_demo

    over = {k: v for k, v in (("db_sensor", db_sensor), ("preset", preset), ("config_file", config_file)) if v is not None}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_demo(out, DemoConfig(seed=seed, quick=quick, models_dir=None if models_dir is None else str(models_dir),
                                 **over), progress=False, log=lambda s: None, overwrite=True)
    rows = json.loads((out / "recognition.json").read_text())["clusters"]
    for r in rows:
        r["seed"] = seed
    return rows


def run_seeds(models_dir: Path | None, seeds: list[int], out: Path, **kw) -> tuple[dict, dict]:
    """:func:`run_seed` for each of ``seeds`` (``OUT/seed_<s>``), each seed's table printed, then the pooled one:
    ``({seed: table}, pooled table)``."""
    all_rows, per_seed = [], {}
    for s in seeds:
        t0 = time.perf_counter()
        rows = run_seed(models_dir, s, out / f"seed_{s}", **kw)
        all_rows += rows
        per_seed[s] = per_class_table(rows)
        print_table(per_seed[s], f"seed {s} ({time.perf_counter() - t0:.0f} s)")
    total = per_class_table(all_rows)
    print_table(total, f"seeds {seeds} pooled")
    return per_seed, total


def per_class_table(rows: list[dict]) -> dict:
    """Per class (and ``all``): precision, recall, median pose errors, mean NEES (6-DoF and 3-DoF rows apart)."""
    labels = sorted({r["truth_label"] for r in rows if r["truth_object"] >= 0 and r["truth_label"] != "background"}
                    | {r["label"] for r in rows if r["detected"]})
    out = {}
    for lab in labels + ["all"]:
        sel = (lambda r: True) if lab == "all" else (lambda r, lab=lab: r["label"] == lab)
        dets = [r for r in rows if r["detected"] and sel(r)]
        correct = [r for r in dets if r["label"] == r["truth_label"]]
        objs = [r for r in rows if r["truth_object"] >= 0 and r["truth_label"] != "background"
                and (lab == "all" or r["truth_label"] == lab)]
        found = [r for r in objs if r["detected"] and r["label"] == r["truth_label"]]
        rot = [r["rotation_error_deg"] for r in correct if "rotation_error_deg" in r]
        tr = [1e3 * r["translation_error_m"] for r in correct if "translation_error_m" in r]
        n6 = [r["pose_nees"] for r in correct if r.get("pose_nees_dof") == 6]
        n3 = [r["pose_nees"] for r in correct if r.get("pose_nees_dof") == 3]
        # the poses the filter uses (unreliable ones, e.g. cut by the scan border, are skipped by default)
        n6r = [r["pose_nees"] for r in correct if r.get("pose_nees_dof") == 6 and r.get("reliable")]
        reliable = [r for r in dets if r.get("reliable")]  # what SLAM takes (unreliable ones are skipped by default)
        out[lab] = {
            "detections": len(dets), "objects": len(objs),
            "precision": len(correct) / len(dets) if dets else float("nan"),
            "reliable": len(reliable),
            "precision_reliable": (sum(r["label"] == r["truth_label"] for r in reliable) / len(reliable)
                                   if reliable else float("nan")),
            "recall": len(found) / len(objs) if objs else float("nan"),
            "median_rot_deg": float(np.median(rot)) if rot else float("nan"),
            "median_trans_mm": float(np.median(tr)) if tr else float("nan"),
            "wrong_poses": int(sum(x > 10 for x in rot)),
            "mean_nees6": float(np.mean(n6)) if n6 else float("nan"), "n_nees6": len(n6),
            "median_nees6": float(np.median(n6)) if n6 else float("nan"),
            "mean_nees3": float(np.mean(n3)) if n3 else float("nan"), "n_nees3": len(n3),
            "mean_nees6_reliable": float(np.mean(n6r)) if n6r else float("nan"), "n_nees6_reliable": len(n6r),
        }
    return out


def print_table(table: dict, title: str) -> None:
    print(f"\n{title}")
    print(f"{'class':20s} {'dets':>5s} {'objs':>5s} {'prec':>6s} {'recall':>6s} {'rot°':>6s} {'mm':>6s} {'>10°':>4s} "
          f"{'NEES6':>8s} {'(n)':>4s} {'med6':>6s} {'NEES3':>7s} {'(n)':>4s} {'rel6':>7s} {'(n)':>4s} {'rel':>4s} "
          f"{'relprec':>7s}")
    for lab, s in table.items():
        print(f"{lab:20s} {s['detections']:5d} {s['objects']:5d} {100 * s['precision']:5.1f}% "
              f"{100 * s['recall']:5.1f}% "
              f"{s['median_rot_deg']:6.2f} {s['median_trans_mm']:6.2f} {s['wrong_poses']:4d} {s['mean_nees6']:8.2f} "
              f"{s['n_nees6']:4d} {s['median_nees6']:6.2f} {s['mean_nees3']:7.2f} {s['n_nees3']:4d} "
              f"{s['mean_nees6_reliable']:7.2f} {s['n_nees6_reliable']:4d} {s['reliable']:4d} "
              f"{100 * s['precision_reliable']:6.1f}%")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--quick", action="store_true", help="the demo's --quick (two loops)")
    ap.add_argument("--classes", nargs="+", choices=sorted(MODELS), help="a subset of the shared models")
    ap.add_argument("--builtin", action="store_true", help="the papers' four built-in fittings instead")
    ap.add_argument("--models-dir", type=Path, default=SHARED_MODELS)
    ap.add_argument("--folder", type=Path, default=None,
                    help="any models folder as it is (its models.toml, as for 'semslam demo --models'): e.g. models "
                         "nobody on the team chose settings on")
    ap.add_argument("--out", type=Path, default=None, help="where the runs go (default: a temporary folder)")
    ap.add_argument("--db-sensor", choices=("laser", "kinect", "kinect+laser"), default=None,
                    help="the database's sensor (default: the demo's)")
    ap.add_argument("--preset", default=None, help="the scan pipeline's preset (default: the demo's)")
    ap.add_argument("--config", default=None, help="a run configuration file on top of the preset")
    args = ap.parse_args(argv)
    if args.folder is not None and (args.builtin or args.classes):
        print("real_models: --folder runs the folder's own classes (not with --builtin or --classes)", file=sys.stderr)
        return 1
    if args.folder is None and not args.builtin and not args.models_dir.is_dir():
        print(f"real_models: no models folder {args.models_dir} (../shared/data/models)", file=sys.stderr)
        return 1
    out = args.out or Path(tempfile.mkdtemp(prefix="semslam_real_models_"))
    if args.folder is not None:
        folder, used = args.folder, {}
    else:
        folder, used = (None, {}) if args.builtin else write_models_folder(out / "models", args.classes,
                                                                           models_dir=args.models_dir)
    if used:
        print("models: " + ", ".join(f"{k}={v}" for k, v in used.items()))
    per_seed, total = run_seeds(folder, args.seeds, out, quick=args.quick, db_sensor=args.db_sensor,
                                preset=args.preset, config_file=args.config)
    never = sorted(set(used) - set(total))
    if never:  # in the mission, but no scan ever made a cluster of them: misses the per-cluster recall cannot count
        print(f"never a cluster (not counted above): {', '.join(never)}")
    (out / "summary.json").write_text(json.dumps({"seeds": args.seeds, "models": used, "per_seed": per_seed,
                                                  "pooled": total}, indent=2, default=float))
    print(f"\nrun directories and summary.json in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
