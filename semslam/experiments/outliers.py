"""Outlier detections for robustness studies (issue 17): corrupt a seeded fraction of a run's detections with a wrong
class label or a displaced pose, and count how many of them the filter / graph actually used.

:func:`corrupt_detections` post-processes the ``{scan_id: [Detection]}`` dict that :func:`semslam.run.run_slam`
takes (from :func:`semslam.simulation.detections.simulate_detections` or a recogniser): exactly
``round(fraction * n)`` of the mission's ``n`` detections, drawn without replacement, are corrupted. The corrupted
detection keeps its nominal covariance (the recogniser does not know it is wrong: that is what makes it an
outlier) and carries ``extras["outlier"]`` (``"wrong_class"`` or ``"displaced"``). :func:`outlier_usage` counts,
from a run's update log, how many of them the gate let through (accepted landmark updates, by test) and how many went
to the consensus as landmark candidates.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._validation import as_rng
from ..detection import Detection
from ..errors import InputError
from ..geometry import RigidTransform
from ..slam import _ekf_kernels as kern

OUTLIER_KINDS = ("displaced", "wrong_class", "mixed")


def _range(name: str, v) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise InputError(f"The {name!r} argument of corrupt_detections must be a pair (low, high). Got {v!r} instead.")
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi):
        raise InputError(
            f"The {name!r} argument of corrupt_detections must satisfy 0 <= low <= high. Got {v!r} instead."
        )
    return lo, hi


def corrupt_detections(detections: dict[int, list[Detection]], *, fraction: float = 0.1, kind: str = "mixed",
                       seed=0, translation_m=(0.3, 0.5), rotation_deg=(20.0, 40.0),
                       labels=None) -> tuple[dict[int, list[Detection]], list[tuple[int, int, str]]]:
    """A copy of ``detections`` with ``round(fraction * n)`` of its ``n`` detections corrupted. Seeded.

    ``kind``: ``"displaced"`` (the pose in the sensor frame moved by a translation of uniform length in
    ``translation_m`` along a uniform random direction and rotated by a uniform angle in ``rotation_deg`` about a
    uniform random axis), ``"wrong_class"`` (another label, uniform over ``labels``, default the labels present in
    ``detections``; falls back to a displacement when there is only one label) or ``"mixed"`` (each outlier either,
    with probability 1/2). Returns the new dict and the list of ``(scan_id, index in the scan's list, kind)`` of the
    corrupted detections. The input is not modified.
    """
    if kind not in OUTLIER_KINDS:
        raise InputError(
            f"The 'kind' argument of corrupt_detections must be one of {OUTLIER_KINDS}. Got {kind!r} instead."
        )
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0.0 <= fraction <= 1.0:
        raise InputError(
            f"The 'fraction' argument of corrupt_detections must be a number in [0, 1]. Got {fraction!r} instead."
        )
    t_lo, t_hi = _range("translation_m", translation_m)
    r_lo, r_hi = np.radians(_range("rotation_deg", rotation_deg))
    rng = as_rng(seed, caller="corrupt_detections")
    keys = [(sid, k) for sid in sorted(detections) for k in range(len(detections[sid]))]
    labels = sorted({d.label for dets in detections.values() for d in dets} if labels is None else set(labels))
    n_out = int(round(fraction * len(keys)))
    chosen = sorted(rng.choice(len(keys), size=n_out, replace=False).tolist()) if n_out else []
    out = {sid: list(dets) for sid, dets in detections.items()}
    record = []
    for c in chosen:
        sid, k = keys[c]
        d = out[sid][k]
        what = kind if kind != "mixed" else ("displaced" if rng.random() < 0.5 else "wrong_class")
        others = [lb for lb in labels if lb != d.label]
        if what == "wrong_class" and others:
            new = replace(d, label=str(others[rng.integers(len(others))]), extras={**d.extras, "outlier": what})
        else:
            what = "displaced"
            u = rng.normal(size=3)
            a = rng.normal(size=3)
            dt = rng.uniform(t_lo, t_hi) * u / np.linalg.norm(u)
            dR = kern.so3_exp(rng.uniform(r_lo, r_hi) * a / np.linalg.norm(a))
            T = d.T_sensor_object
            new = replace(
                d,
                T_sensor_object=RigidTransform.from_rotation_translation(dR @ T.rotation, T.translation_m + dt),
                extras={**d.extras, "outlier": what},
            )
        out[sid][k] = new
        record.append((sid, k, what))
    return out, record


def outlier_usage(result, detections: dict[int, list[Detection]]) -> dict:
    """How a run (:class:`~semslam.slam.results.SlamResult` with its ``update_log``) used the detections marked
    ``extras["outlier"]`` in ``detections``: ``n_outliers``, ``accepted_pose`` / ``accepted_position`` (landmark
    updates the gate accepted, hence factors of the graph), ``rejected`` (gated out or ambiguous), ``candidates``
    (sent to the consensus) and ``accepted_fraction`` (accepted / n_outliers); also ``inlier_accepted`` for scale."""
    marked = {}
    for dets in detections.values():
        for k, d in enumerate(dets):
            if "outlier" in d.extras:
                marked[(round(float(d.stamp_s), 9), k)] = d.extras["outlier"]
    c = {"n_outliers": len(marked), "accepted_pose": 0, "accepted_position": 0, "rejected": 0, "candidates": 0,
         "inlier_accepted": 0}
    for r in result.update_log:
        if r.get("kind") not in ("landmark", "candidate") or "detection" not in r:
            continue
        out = (round(float(r["stamp_s"]), 9), int(r["detection"])) in marked
        if r["kind"] == "candidate":
            c["candidates"] += out
        elif r.get("accepted"):
            if out:
                c[f"accepted_{r['test']}"] += 1
            else:
                c["inlier_accepted"] += 1
        else:
            c["rejected"] += out
    c["accepted"] = c["accepted_pose"] + c["accepted_position"]
    c["accepted_fraction"] = c["accepted"] / c["n_outliers"] if c["n_outliers"] else 0.0
    return c
