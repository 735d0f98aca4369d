"""A loud health verdict on every run, from the run's own statistics (no ground truth needed).

Per navigation sensor (DVL, depth, position fixes): the fraction of updates the filter's gate rejected and the
mean NIS of the accepted ones against its chi-square band. The map: landmarks per class, same-class landmarks
closer than ``duplicate_radius_m`` (one object mapped twice), landmark updates (a pose run whose map never
corrected the navigation is dead reckoning in disguise). The covariance: finite, positive definite, bounded.
The source: messages dropped as late, damaged or unusable.

Each check is ``ok``, ``warning`` or ``bad``; the verdict is the worst. ``semslam run`` prints it, writes it into
``metrics.json`` and the report's first screen, and ``--strict`` turns a bad verdict into a non-zero exit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LEVELS = ("ok", "warning", "bad")


@dataclass(frozen=True)
class HealthLimits:
    """Thresholds of the verdict. Chosen on the simulator's default mission (seed 0) and checked on others."""

    #: a sensor whose gate rejects more than this fraction of its samples is not modelled right (warning above
    #: the first, bad above the second)
    rejected_warning: float = 0.05
    rejected_bad: float = 0.10
    #: mean NIS above ``factor`` times its band's upper end: the noise figures are too confident, or a frame wrong
    nis_factor_warning: float = 1.5
    nis_factor_bad: float = 3.0
    #: two landmarks of one class closer than this are one object mapped twice (m)
    duplicate_radius_m: float = 1.0
    #: position 3-sigma beyond this at the end: the estimate has lost its way (m)
    max_3sigma_m: float = 100.0
    #: fixes rejected beyond this fraction (a wrong origin, a jumping receiver)
    fix_rejected_bad: float = 0.5


@dataclass
class Verdict:
    level: str = "ok"
    checks: list = field(default_factory=list)

    def add(self, name: str, level: str, message: str, **values) -> None:
        self.checks.append({"check": name, "level": level, "message": message, **values})
        if LEVELS.index(level) > LEVELS.index(self.level):
            self.level = level

    def as_dict(self) -> dict:
        return {"verdict": self.level, "checks": list(self.checks)}

    def lines(self, only_problems: bool = True) -> list[str]:
        return [f"{c['level'].upper()}: {c['check']}: {c['message']}" for c in self.checks
                if not only_problems or c["level"] != "ok"]


def _sensor(v: Verdict, name: str, n: int, rejected: int, nis: dict | None, lim: HealthLimits, *, bad_frac: float):
    if n == 0:
        return
    frac = rejected / n
    lvl = "bad" if frac > bad_frac else "warning" if frac > lim.rejected_warning else "ok"
    v.add(f"{name} gate", lvl, f"{rejected} of {n} samples rejected ({100 * frac:.1f} %)", rejected=rejected, n=n,
          fraction=frac)
    if nis:
        hi = float(nis["band"][1])
        ratio = nis["mean"] / hi if hi > 0 else float("inf")
        lvl = "bad" if ratio > lim.nis_factor_bad else "warning" if ratio > lim.nis_factor_warning else "ok"
        v.add(f"{name} NIS", lvl, f"mean {nis['mean']:.2f} (dof {nis['dof']}, 95 % band of the mean up to {hi:.2f})",
              mean=nis["mean"], band=list(nis["band"]))


def health_verdict(result, *, counts: dict | None = None, limits: HealthLimits | None = None) -> Verdict:
    """The verdict of one mode's :class:`~semslam.slam.SlamResult` (see the module docstring); ``counts``: the
    runner's and the source's counts (late, damaged, unusable messages)."""
    lim = HealthLimits() if limits is None else limits
    m, v = result.metrics, Verdict()
    nis = m.get("nis", {})
    _sensor(v, "DVL", m.get("dvl_updates", 0), m.get("dvl_rejected", 0), nis.get("dvl"), lim, bad_frac=lim.rejected_bad)
    _sensor(v, "depth", m.get("depth_updates", 0), m.get("depth_rejected", 0), nis.get("depth"), lim,
            bad_frac=lim.rejected_bad)
    _sensor(v, "position fix", m.get("fix_updates", 0), m.get("fix_rejected", 0), nis.get("fix"), lim,
            bad_frac=lim.fix_rejected_bad)
    if m.get("fix_unusable", 0):
        v.add("position fix data", "warning", f"{m['fix_unusable']} fixes without a usable position or covariance")
    _map(v, result, lim)
    _covariance(v, result, lim)
    for key, what in (("late_dropped", "messages later than the processed time, dropped"),
                      ("non_finite_stamp", "messages with a non-finite stamp, dropped")):
        d = {k: n for k, n in ((counts or {}).get(key) or {}).items() if n}
        src = {k: n for k, n in (((counts or {}).get("source") or {}).get(key) or {}).items() if n}
        for k, n in src.items():
            d[k] = d.get(k, 0) + n
        if d:
            v.add("stream", "warning", f"{sum(d.values())} {what}: {d}", **{key: d})
    from .damage import add_damage_checks

    add_damage_checks(v, counts)  # damaged recordings and stamps out of order, per topic (semslam.run.damage)
    not_deskewed = int((counts or {}).get("scans_not_deskewed", 0) or 0)
    if not_deskewed:
        v.add("scans", "warning", f"{not_deskewed} scans recognised without motion compensation (no attitude or "
              f"valid DVL velocity within 1 s of their span): their objects are stretched by the vehicle's motion",
              scans_not_deskewed=not_deskewed)
    skipped = m.get("skipped_beyond_attitude", 0)
    if skipped:
        v.add("stream", "warning", f"{skipped} messages beyond the last attitude sample, skipped")
    return v


def _map(v: Verdict, result, lim: HealthLimits) -> None:
    if result.mode == "dr":
        return
    lms = result.landmarks
    ups = m_ups = result.metrics.get("landmark_updates", {})
    n_up = int(ups.get("pose", 0) + ups.get("position", 0)) if m_ups else 0
    by: dict = {}
    for lm in lms:
        by.setdefault(lm.label, []).append(np.asarray(lm.pose_xyzrpy[:3], dtype=float))
    dup = 0
    for pts in by.values():
        P = np.array(pts)
        if len(P) > 1:
            d = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=-1)
            dup += int(np.sum(np.triu(d < lim.duplicate_radius_m, 1)))
    per_class = {k: len(p) for k, p in by.items()}
    lvl = "bad" if dup else "ok"
    v.add("map", lvl, f"{len(lms)} landmarks {per_class}" + (f"; {dup} same-class pairs closer than "
                                                            f"{lim.duplicate_radius_m:g} m (an object mapped twice)"
                                                            if dup else ""), n_landmarks=len(lms),
          per_class=per_class, duplicate_pairs=dup)
    if not lms:
        v.add("landmark updates", "warning", "no object was mapped: the run is dead reckoning")
    elif n_up == 0:
        v.add("landmark updates", "warning", "no landmark was ever re-observed: the map did not correct the "
              "navigation")
    else:
        v.add("landmark updates", "ok", f"{n_up} landmark updates", n=n_up)


def _covariance(v: Verdict, result, lim: HealthLimits) -> None:
    P = np.asarray(result.position_cov_m2)
    if not len(P):
        v.add("covariance", "bad", "the run recorded no epoch")
        return
    finite = bool(np.isfinite(P).all())
    ev = np.linalg.eigvalsh(0.5 * (P + np.swapaxes(P, 1, 2))) if finite else np.full((len(P), 3), np.nan)
    pd = finite and bool((ev > 0).all())
    s3 = float(3.0 * np.sqrt(np.max(ev[-1]))) if finite else float("nan")
    if not pd:
        v.add("covariance", "bad", "the position covariance is not finite and positive definite at every epoch")
    elif s3 > lim.max_3sigma_m:
        v.add("covariance", "bad", f"position 3-sigma {s3:.1f} m at the end: the estimate has lost its way",
              final_3sigma_m=s3)
    else:
        v.add("covariance", "ok", f"position 3-sigma {s3:.3f} m at the end", final_3sigma_m=s3)
