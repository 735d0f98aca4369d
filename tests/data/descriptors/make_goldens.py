"""Regenerate the PCL 1.13 golden files of the descriptor tests (needs ../shared and pcl_ref).

    .venv/bin/python tests/data/descriptors/make_goldens.py [fpfh|esf|vfh ...]

Inputs are float32 clouds (stored here, exactly as fed to pcl_ref); outputs are pcl_ref's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = Path(os.environ.get("SEMSLAM_SHARED", HERE.parents[2].parent / "shared"))
REAL = SHARED / "data" / "real"
PCL_REF = os.environ.get("PCL_REF", str(Path.home() / ".cache/pcl_oracle/pcl_ref"))
TMP = Path(tempfile.mkdtemp(prefix="semslam_goldens_"))


def run(*args: str, env: dict | None = None) -> list[dict]:
    out = subprocess.run([PCL_REF, *args], check=True, capture_output=True, text=True,
                         env={**os.environ, **(env or {})}).stdout
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def load_real(name: str) -> np.ndarray:
    """(N, K) float32 of a shared real scan (all fields), via pcl_ref's ASCII writer."""
    path = TMP / f"{name}.ascii.pcd"
    run("convert", str(REAL / f"{name}.pcd"), str(path), "0")
    lines = path.read_text().splitlines()
    start = next(i for i, l in enumerate(lines) if l.startswith("DATA")) + 1
    return np.array([[float(v) for v in l.split()] for l in lines[start:]], dtype=np.float32)


def write_pcd(path: Path, cols: np.ndarray, fields: str = "x y z") -> Path:
    cols = np.asarray(cols, dtype=np.float32)
    k = cols.shape[1]
    header = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {' '.join(['4'] * k)}\n"
              f"TYPE {' '.join(['F'] * k)}\nCOUNT {' '.join(['1'] * k)}\nWIDTH {len(cols)}\nHEIGHT 1\n"
              f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(cols)}\nDATA ascii\n")
    body = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in cols)
    path.write_text(header + body + "\n")
    return path


def fpfh_goldens() -> None:
    """pcl_ref fpfh (PCL normals by radius, then FPFH by radius) of the first point, for several
    first points (the cloud is rolled so that another point comes first)."""
    rng = np.random.default_rng(3)
    bun0 = load_real("bun0")[:, :3]
    chef = load_real("chef")[:, :3]
    milk = load_real("milk")[:, :3]
    clouds = {
        "bun0": (bun0, 0.01, 0.02),
        "chef_sub": (chef[rng.choice(len(chef), 1200, replace=False)], 0.012, 0.025),
        "milk_sub": (milk[rng.choice(len(milk), 1500, replace=False)], 0.01, 0.02),
    }
    out = {}
    for name, (pts, nr, fr) in clouds.items():
        firsts = rng.choice(len(pts), 3, replace=False)
        hists = []
        for f in firsts:
            rolled = np.roll(pts, -int(f), axis=0)
            path = write_pcd(TMP / f"{name}_{f}.pcd", rolled)
            hists.append(run("fpfh", str(path), str(nr), str(fr))[0]["first"])
        out[f"{name}_points"] = pts
        out[f"{name}_radii"] = np.array([nr, fr])
        out[f"{name}_first"] = firsts
        out[f"{name}_fpfh"] = np.array(hists, dtype=np.float32)
    np.savez_compressed(HERE / "fpfh_pcl.npz", **out)


def base_goldens() -> None:
    """bun0 (x y z normal_x normal_y normal_z curvature, float32) and PCL's golden vectors."""
    np.save(HERE / "bun0.npy", load_real("bun0"))
    golden = SHARED / "design" / "golden"
    (HERE / "pcl-1.13.txt").write_text((golden / "pcl-1.13.txt").read_text())
    (HERE / "vfh-bun0-legacy-f23.txt").write_text((golden / "vfh-bun0-legacy-f23.txt").read_text())



ESF_SEEDS = (1000, 2000, 3000)


def _shape(kind: str, rng: np.random.Generator, n: int) -> np.ndarray:
    u, v = rng.random(n), rng.random(n)
    if kind == "sphere":
        x = rng.normal(size=(n, 3))
        return x / np.linalg.norm(x, axis=1, keepdims=True) * 0.1
    if kind == "hemisphere":
        x = rng.normal(size=(n, 3))
        x[:, 2] = np.abs(x[:, 2])
        return x / np.linalg.norm(x, axis=1, keepdims=True) * 0.2
    if kind == "ellipsoid":
        x = rng.normal(size=(n, 3))
        return x / np.linalg.norm(x, axis=1, keepdims=True) * [0.3, 0.1, 0.05]
    if kind == "box":
        x = rng.random((n, 3)) * 2 - 1
        ax = rng.integers(0, 3, n)
        x[np.arange(n), ax] = np.sign(x[np.arange(n), ax])
        return x * [0.2, 0.1, 0.05]
    if kind == "cylinder":
        a = 2 * np.pi * u
        return np.c_[0.05 * np.cos(a), 0.05 * np.sin(a), 0.3 * v]
    if kind == "cone":
        a, h = 2 * np.pi * u, np.sqrt(v)
        return np.c_[0.1 * h * np.cos(a), 0.1 * h * np.sin(a), 0.2 * (1 - h)]
    if kind == "torus":
        a, b = 2 * np.pi * u, 2 * np.pi * v
        return np.c_[(0.2 + 0.05 * np.cos(b)) * np.cos(a), (0.2 + 0.05 * np.cos(b)) * np.sin(a), 0.05 * np.sin(b)]
    if kind == "plane":
        return np.c_[u * 0.5, v * 0.3, rng.normal(0, 0.002, n)]
    if kind == "lshape":
        w = rng.random(n) < 0.5
        return np.where(w[:, None], np.c_[u * 0.4, v * 0.3, 0 * u], np.c_[u * 0.4, 0 * u, v * 0.2])
    if kind == "blob":
        return rng.normal(size=(n, 3)) * [0.1, 0.05, 0.02]
    if kind == "halfcyl_noisy":
        a = np.pi * u
        return np.c_[0.1 * np.cos(a), 0.1 * np.sin(a), 0.4 * v] + rng.normal(0, 0.003, (n, 3))
    if kind == "two_spheres":
        x = rng.normal(size=(n, 3))
        x = x / np.linalg.norm(x, axis=1, keepdims=True) * 0.05
        x[: n // 2, 0] += 0.3
        return x
    raise ValueError(kind)


def esf_goldens() -> None:
    """pcl_ref esf with PCL_REF_TIME = each of ESF_SEEDS, on 20 clouds stored int16-quantised
    (points = q * scale, computed in float32, exactly the values written for PCL)."""
    rng = np.random.default_rng(7)
    bun0 = load_real("bun0")[:, :3]
    bun4 = load_real("bun4")[:, :3]
    milk = load_real("milk")[:, :3]
    chef = load_real("chef")[:, :3]
    clouds = {"bun0": bun0, "bun4": bun4}
    clouds["milk_sub"] = milk[rng.choice(len(milk), 800, replace=False)]
    top = milk[milk[:, 1] < np.median(milk[:, 1])]
    clouds["milk_top"] = top[rng.choice(len(top), 700, replace=False)]
    side = milk[milk[:, 0] < np.median(milk[:, 0])]
    clouds["milk_side"] = side[rng.choice(len(side), 600, replace=False)]
    clouds["chef_sub"] = chef[rng.choice(len(chef), 800, replace=False)]
    half = chef[chef[:, 0] < np.median(chef[:, 0])]
    clouds["chef_half"] = half[rng.choice(len(half), 700, replace=False)]
    clouds["chef_sparse"] = chef[rng.choice(len(chef), 250, replace=False)]
    for kind in ["sphere", "hemisphere", "ellipsoid", "box", "cylinder", "cone", "torus", "plane",
                 "lshape", "blob", "halfcyl_noisy", "two_spheres"]:
        clouds[kind] = _shape(kind, rng, int(rng.integers(300, 900)))
    out = {}
    for name, pts in clouds.items():
        pts = np.asarray(pts, dtype=np.float64)
        scale = np.float32(np.abs(pts).max() / 32000.0)
        q = np.round(pts / scale).astype(np.int16)
        pts32 = q.astype(np.float32) * scale
        path = write_pcd(TMP / f"esf_{name}.pcd", pts32)
        runs = [run("esf", str(path), env={"PCL_REF_TIME": str(s)})[0]["bins"] for s in ESF_SEEDS]
        out[f"{name}_q"] = q
        out[f"{name}_scale"] = np.array(scale, dtype=np.float32)
        out[f"{name}_pcl"] = np.array(runs, dtype=np.float32)
    out["seeds"] = np.array(ESF_SEEDS)
    np.savez_compressed(HERE / "esf_pcl_runs.npz", **out)
    np.savez_compressed(HERE / "milk.npz", points=load_real("milk")[:, :3])



def vfh_goldens() -> None:
    """pcl_ref vfh_given (normals from the file) on clouds with normals, and pcl_ref vfh (PCL's
    radius normals) on one cloud; the f4 block is zero (PCL defaults)."""
    import sys as _sys

    _sys.path.insert(0, str(HERE.parents[2]))
    from semslam.descriptors import estimate_normals

    rng = np.random.default_rng(11)
    chef = load_real("chef")
    bun4 = load_real("bun4")[:, :3]
    a, z = 2 * np.pi * rng.random(500), rng.random(500) * 0.3
    cyl = np.c_[0.05 * np.cos(a) + 0.2, 0.05 * np.sin(a) - 0.1, z + 0.8]
    cyl_n = np.c_[np.cos(a), np.sin(a), 0 * a]
    clouds = {
        "chef_sub": chef[rng.choice(len(chef), 1000, replace=False)][:, :6],
        "bun4_k10": np.c_[bun4, estimate_normals(bun4.astype(float), k=10).normals_xyz],
        "cylinder": np.c_[cyl, cyl_n],
    }
    out = {}
    for name, cols in clouds.items():
        cols = cols.astype(np.float32)
        path = write_pcd(TMP / f"vfh_{name}.pcd", cols, "x y z normal_x normal_y normal_z")
        out[f"{name}_cloud"] = cols
        out[f"{name}_vfh"] = np.array(run("vfh_given", str(path))[0]["bins"], dtype=np.float32)
    sub = load_real("milk")[:, :3][rng.choice(13704, 3000, replace=False)]
    path = write_pcd(TMP / "vfh_milk3000.pcd", sub)
    out["milk3000_points"] = sub
    out["milk3000_vfh_r0.01"] = np.array(run("vfh", str(path), "0.01")[1]["bins"], dtype=np.float32)
    np.savez_compressed(HERE / "vfh_pcl.npz", **out)


if __name__ == "__main__":
    which = sys.argv[1:] or ["base", "fpfh", "esf", "vfh"]
    for w in which:
        globals()[f"{w}_goldens"]()
        print("wrote", w)

