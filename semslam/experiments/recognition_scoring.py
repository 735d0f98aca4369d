"""Scoring recognition against the simulator's ground truth: per cluster, the true object it mostly covers,
whether it was recognised with the right class, and the pose error of its detection at its own stamp."""

from __future__ import annotations

import numpy as np

from ..simulation.truth import cluster_truth, pose_error, true_T_scanner_object


def score_scan(mission, rec, cloud, result, db) -> list[dict]:
    """One row per cluster of ``result`` (a scan of ``mission`` recognised against ``db``)."""
    rows = []
    for k, outcome in enumerate(result.clusters):
        truth = cluster_truth(mission, cloud, result.segmentation.input_indices(k))
        row = {"scan_id": rec.scan_id, **outcome.to_dict(), "truth_label": truth.label,
               "truth_object": truth.object_index, "truth_purity": truth.purity}
        det = outcome.detection
        if det is not None:
            row["reliable"] = bool(det.reliable)
            row["fitness"] = det.fitness
            row["rmse_m"] = det.rmse_m
            if truth.object_index >= 0 and truth.label == det.label:
                err = pose_error(det, true_T_scanner_object(mission, truth.object_index, det.stamp_s),
                                 db.class_info(det.label).symmetry)
                row.update(rotation_error_deg=float(np.degrees(err.rotation_error_rad)),
                           translation_error_m=err.translation_error_m, pose_nees=err.nees, pose_nees_dof=err.dof)
        rows.append(row)
    return rows


def recognition_summary(records: list[dict], timings: list[dict]) -> dict:
    dets = [r for r in records if r["detected"]]
    correct = [r for r in dets if r["label"] == r["truth_label"]]
    objects = [r for r in records if r["truth_object"] >= 0 and r["truth_label"] != "background"]
    found = [r for r in objects if r["detected"] and r["label"] == r["truth_label"]]
    background = [r for r in records if r["truth_label"] == "background"]
    false_accepts = [r for r in background if r["detected"]]
    rot = np.array([r["rotation_error_deg"] for r in correct if "rotation_error_deg" in r])
    trans = np.array([r["translation_error_m"] for r in correct if "translation_error_m" in r])
    nees6 = np.array([r["pose_nees"] for r in correct if r.get("pose_nees_dof") == 6])
    success = np.array([(r.get("rotation_error_deg", 1e9) < 10 and r.get("translation_error_m", 1e9) < 0.01)
                        for r in correct]) if correct else np.zeros(0, bool)
    total_ms = np.array([t["total"] for t in timings]) if timings else np.zeros(0)
    per_class = {}
    for lab in sorted({r["truth_label"] for r in objects}):
        obj = [r for r in objects if r["truth_label"] == lab]
        per_class[lab] = {"clusters": len(obj), "recognised": sum(r["detected"] and r["label"] == lab for r in obj)}
    return {
        "n_scans": len(timings), "n_clusters": len(records), "n_detections": len(dets),
        "precision": len(correct) / len(dets) if dets else float("nan"),
        "recall": len(found) / len(objects) if objects else float("nan"),
        "background_clusters": len(background), "background_false_accepts": len(false_accepts),
        "per_class": per_class,
        "pose_median_rotation_error_deg": float(np.median(rot)) if rot.size else float("nan"),
        "pose_median_translation_error_m": float(np.median(trans)) if trans.size else float("nan"),
        "pose_success_rate": float(success.mean()) if success.size else float("nan"),
        "pose_mean_nees_6dof": float(np.mean(nees6)) if nees6.size else float("nan"),
        "n_reliable": sum(bool(r.get("reliable")) for r in dets),
        "scan_latency_ms_median": float(np.median(total_ms)) if total_ms.size else float("nan"),
        "scan_latency_ms_p90": float(np.percentile(total_ms, 90)) if total_ms.size else float("nan"),
        "stage_ms_median": {k: float(np.median([t.get(k, 0.0) for t in timings])) for k in
                            ("segmentation", "descriptors", "matching", "pose")} if timings else {},
    }


