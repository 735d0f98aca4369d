"""Synthetic partial views for tests and benchmarks: simple known shapes and unknown clutter.

A partial view keeps the surface samples whose outward normal faces the sensor (no self-occlusion test:
these shapes are convex or nearly so), plus Gaussian range noise. Everything is seeded.
"""

from __future__ import annotations

import types

import numpy as np

from .._validation import as_rng
from ..cloud import PointCloud
from ..symmetry import Symmetry


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _surface(kind: str, n: int, rng: np.random.Generator, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points (n, 3), outward normals (n, 3)) sampled on a shape centred at the origin."""
    if kind in ("sphere", "ellipsoid", "rock"):
        d = _unit(rng.normal(size=(n, 3)))
        if kind == "rock":  # lumpy ellipsoid: radius modulated by a few random harmonics of the direction
            lumps = _unit(rng.normal(size=(6, 3)))
            r = 1.0 + 0.25 * np.tanh(3 * (d @ lumps.T)).mean(axis=1) + 0.05 * rng.normal(size=n)
            d = d * r[:, None]
        pts = d * size / 2
        nrm = _unit(pts / (size / 2) ** 2)
        return pts, nrm
    if kind in ("box", "wall"):
        half = size / 2
        area = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
        axis = rng.choice(3, size=n, p=area / area.sum())
        sign = rng.choice([-1.0, 1.0], size=n)
        pts = rng.uniform(-half, half, size=(n, 3))
        pts[np.arange(n), axis] = sign * half[axis]
        nrm = np.zeros((n, 3))
        nrm[np.arange(n), axis] = sign
        return pts, nrm
    if kind in ("cylinder", "pipe"):  # axis z; a pipe is an open tube (no caps), a cylinder has caps
        r, h = size[0] / 2, size[2]
        caps = np.zeros(n, bool) if kind == "pipe" else rng.uniform(size=n) < (r / (r + h))
        t = rng.uniform(0, 2 * np.pi, size=n)
        z = rng.uniform(-h / 2, h / 2, size=n)
        rho = np.where(caps, r * np.sqrt(rng.uniform(size=n)), r)
        zc = np.where(caps, np.sign(z) * h / 2, z)
        pts = np.stack([rho * np.cos(t), rho * np.sin(t), zc], axis=1)
        nrm = np.where(caps[:, None], np.stack([0 * t, 0 * t, np.sign(z)], axis=1),
                       np.stack([np.cos(t), np.sin(t), 0 * t], axis=1))
        if kind == "pipe":  # the inside of the tube is visible too
            inner = rng.uniform(size=n) < 0.4
            nrm[inner] *= -1
            pts[inner, :2] *= 0.85
        return pts, nrm
    raise ValueError(kind)


def partial_view(kind: str, size_xyz_m, viewpoint_xyz_m, *, n_points: int = 600, noise_m: float = 0.0005,
                 seed=0, frame_id: str = "object") -> PointCloud:
    """A partial view of a synthetic shape seen from ``viewpoint_xyz_m`` (shape frame), ~``n_points`` points."""
    rng = as_rng(seed)
    size = np.asarray(size_xyz_m, float)
    vp = np.asarray(viewpoint_xyz_m, float)
    pts, nrm = _surface(kind, 6 * n_points, rng, size)
    visible = np.einsum("ij,ij->i", vp - pts, nrm) > 0
    pts = pts[visible][:n_points]
    ray = _unit(pts - vp)
    pts = pts + ray * rng.normal(scale=noise_m, size=(len(pts), 1))
    return PointCloud(pts, viewpoint_xyz_m=vp, frame_id=frame_id)


SHAPES = {  # label: (kind, size_xyz_m, symmetry)
    "sphere": ("sphere", (0.08, 0.08, 0.08), Symmetry()),
    "box": ("box", (0.10, 0.06, 0.03), Symmetry()),
    "cylinder": ("cylinder", (0.04, 0.04, 0.12), Symmetry("continuous", (0, 0, 1))),
}


def ring_viewpoints(n: int, *, radius_m: float = 0.5, elevation_rad: float = 0.6, phase_rad: float = 0.0) -> np.ndarray:
    """``n`` sensor origins (n, 3) on a ring around the origin, ``elevation_rad`` above the x-y plane."""
    az = phase_rad + 2 * np.pi * np.arange(n) / n
    return radius_m * np.stack([np.cos(az) * np.cos(elevation_rad), np.sin(az) * np.cos(elevation_rad),
                                np.full(n, np.sin(elevation_rad))], axis=1)


def synthetic_shape_views(n_views: int = 8, *, n_points: int = 600, seed=0, phase_rad: float = 0.0,
                          shapes: dict | None = None):
    """(views, classes) in the form :func:`~semslam.recognition.build_database` takes, for ``SHAPES``."""
    rng = as_rng(seed)
    shapes = SHAPES if shapes is None else shapes
    views, classes = [], {}
    for label, (kind, size, sym) in shapes.items():
        classes[label] = {"symmetry": sym, "size_xyz_m": np.asarray(size, float)}
        for k, vp in enumerate(ring_viewpoints(n_views, phase_rad=phase_rad)):
            views.append((label, f"view_{k:02d}", partial_view(kind, size, vp, n_points=n_points, seed=rng)))
    return views, classes


def clutter_clouds(n: int = 30, *, n_points: int = 600, seed=0) -> list[tuple[str, PointCloud]]:
    """``n`` views of objects that are in no database: rocks, pipe offcuts and pieces of wall (cycled),
    with random sizes of 4-30 cm and random viewpoints, as (kind, cloud)."""
    rng = as_rng(seed)
    out = []
    kinds = ("rock", "pipe", "wall")
    for i in range(n):
        kind = kinds[i % 3]
        if kind == "rock":
            size = rng.uniform(0.04, 0.2, size=3)
        elif kind == "pipe":
            d = rng.uniform(0.03, 0.08)
            size = np.array([d, d, rng.uniform(0.1, 0.3)])
        else:
            size = np.array([rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.3), rng.uniform(0.01, 0.04)])
        vp = _unit(rng.normal(size=3)) * rng.uniform(0.4, 1.0)
        vp[2] = abs(vp[2]) + 0.1
        out.append((kind, partial_view(kind, size, vp, n_points=n_points, seed=rng)))
    return out


class StandInDescriptors:
    """Cheap deterministic stand-ins for semslam.descriptors (tests only): a D2 shape-distribution
    histogram as "ESF", a centroid-distance histogram as "VFH", normals facing the viewpoint (point 0
    without a normal). Same signatures as the real functions."""

    def __init__(self):
        self.vfh_inputs: list[int] = []

    def compute_esf(self, points_xyz_m, *, n_samples=20000, seed=None, sampler="numpy"):
        rng = np.random.default_rng(seed)
        p = points_xyz_m[rng.integers(len(points_xyz_m), size=min(n_samples, 400))]
        d = np.linalg.norm(p[:, None] - p[None], axis=2).ravel()
        return np.histogram(d, bins=640, range=(0, 0.2))[0] / len(d)

    def estimate_normals(self, points_xyz_m, *, k=None, radius_m=None, viewpoint_xyz_m=(0, 0, 0)):
        n = np.asarray(viewpoint_xyz_m) - points_xyz_m
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        n[0] = np.nan  # one point without a normal: must not reach the VFH
        return types.SimpleNamespace(normals_xyz=n, curvature=np.zeros(len(n)))

    def compute_vfh(self, points_xyz_m, normals_xyz, *, viewpoint_xyz_m=(0, 0, 0), variant="standin-default"):
        assert np.isfinite(normals_xyz).all()
        self.vfh_inputs.append(len(points_xyz_m))
        r = np.linalg.norm(points_xyz_m - points_xyz_m.mean(axis=0), axis=1)
        return 100 * np.histogram(r, bins=308, range=(0, 0.1))[0] / len(r)
