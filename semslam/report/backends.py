"""The backends report (issue 17): position error over time per estimator, from Monte-Carlo outputs.

Each estimate is one *series*, named ``<backend>_<estimate>``: ``ekf_online`` (the EKF's filtered estimate, each
epoch as estimated at that epoch), ``ekf-rts_end`` (the EKF's offline RTS smoother), ``isam2_online`` (iSAM2's
current-time estimate), ``isam2_end`` (the whole trajectory as iSAM2 holds it at the end of the dive), ``batch_end``
(Levenberg-Marquardt over the whole dive) and ``batch_online`` (batch's front-end filter, i.e. the EKF's online
estimate). A scenario's curves are the mean over its runs of the position error norm at each epoch.

Files (written by :func:`semslam.experiments.montecarlo.write_montecarlo` and ``benchmarks/backends.py --csv``):
``error_over_time_<name>.csv`` (``t_s`` and one ``<series>_m`` column per series) and ``error_over_time_<name>.json``
(``scenario``: what defines the missions; ``stats``: per series its mean ATE and the fraction of epochs whose ANEES
is in the 95 % band). :func:`build_backends_report` reads every such pair in a directory and in its
sub-directories (one Monte Carlo per backend, e.g. ``MC/ekf``, ``MC/isam2``, ``MC/batch``), puts the series of the
same scenario (same name and same ``scenario``) into one figure, and writes ``report.html`` with the figures
embedded. :func:`section_graph_run`: the same figure for one run of a graph backend (``semslam slam --backend
isam2|batch``, in its run report).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from .._atomic import atomic_write_text
from ..errors import ReportError
from .html import Figure, Section, figure_to_png, write_report

#: series -> (legend label, colour, line style), in the order drawn
SERIES = {
    "ekf_online": ("EKF online (filter)", "tab:blue", "-"),
    "ekf-rts_end": ("EKF + RTS smoother (offline)", "tab:blue", ":"),
    "isam2_online": ("iSAM2 current-time", "tab:red", "-"),
    "isam2_end": ("iSAM2 held at the end of the dive", "tab:red", ":"),
    "batch_end": ("batch LM (whole dive)", "tab:green", "--"),
    "batch_online": ("batch's front-end filter", "tab:green", "-"),
    "ekf_end": ("EKF history held at the end", "tab:blue", "-."),
}
#: a series that repeats another (the EKF's history is its online estimate; batch's front end is the EKF)
SAME_AS = {"ekf_end": "ekf_online", "batch_online": "ekf_online"}
_NAME = re.compile(r"^[a-z0-9][a-z0-9+\-]*_(online|end)$")
_FILE = re.compile(r"^error_over_time_(.+)\.csv$")


def write_error_over_time(directory: str | Path, name: str, stamps_s, curves: dict, *, scenario: dict,
                          stats: dict | None = None) -> Path:
    """Write ``error_over_time_<name>.csv`` (+ ``.json``) into ``directory``; ``curves``: series -> mean error (m)
    at ``stamps_s`` (the shortest length is kept); ``stats``: series -> ``{"ate_rmse_mean_m", "fraction_in_band"}``.
    Returns the CSV's path."""
    if not re.fullmatch(r"[A-Za-z0-9_\-]+", str(name)):
        raise ReportError(f"The 'name' of an error-over-time file must be letters, digits, '_' or '-'. Got {name!r}.")
    bad = [k for k in curves if not _NAME.match(k)]
    if bad or not curves:
        raise ReportError(f"Error-over-time series must be named '<backend>_online' or '<backend>_end'. "
                          f"Got {bad or 'none'}.")
    cols = [np.asarray(c, dtype=float).ravel() for c in curves.values()]
    t = np.asarray(stamps_s, dtype=float).ravel()
    K = min([len(t)] + [len(c) for c in cols])
    lines = ["t_s," + ",".join(f"{k}_m" for k in curves)]
    lines += [",".join(f"{v:.6f}" for v in row) for row in np.column_stack([t[:K]] + [c[:K] for c in cols])]
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"error_over_time_{name}.csv"
    atomic_write_text(path, "\n".join(lines) + "\n")
    from .._jsonable import to_jsonable

    kept = {k: v for k, v in (stats or {}).items() if k in curves}
    side = {"scenario": to_jsonable(scenario), "stats": to_jsonable(kept)}
    atomic_write_text(path.with_suffix(".json"), json.dumps(side, indent=2, sort_keys=True) + "\n")
    return path


def write_montecarlo_curves(result, out_dir: str | Path) -> list[Path]:
    """The error-over-time files of a :class:`~semslam.experiments.montecarlo.MonteCarloResult`, one per mode:
    ``<backend>_online`` and, when the runs have one, the end-of-dive series (``ekf-rts_end`` for the EKF)."""
    b, paths = result.backend, []
    for mode in result.modes:
        s = result.summary[mode]
        curves = {f"{b}_online": result.error_runs[mode].mean(axis=0)}
        stats = {f"{b}_online": {"ate_rmse_mean_m": s["ate_rmse_mean_m"], "fraction_in_band": s["fraction_in_band"]}}
        end = result.end_error_runs.get(mode)
        if end is not None:
            key = "ekf-rts_end" if b == "ekf" else f"{b}_end"
            curves[key] = end.mean(axis=0)
            sm = s.get("smoothed") or {}
            stats[key] = {"ate_rmse_mean_m": sm.get("ate_rmse_mean_m"), "fraction_in_band": sm.get("fraction_in_band")}
        scenario = {"mode": mode, "n_runs": result.n_runs, **result.settings}
        paths.append(write_error_over_time(out_dir, mode.replace("+", "_"), result.stamps_s, curves,
                                           scenario=scenario, stats=stats))
    return paths


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
        head = lines[0].split(",")
        data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:] if ln.strip()], dtype=float)
    except (OSError, UnicodeDecodeError, IndexError, ValueError) as exc:
        raise ReportError(f"{path} is not an error-over-time CSV: {exc}") from None
    if head[0] != "t_s" or data.ndim != 2 or data.shape[0] == 0 or data.shape[1] != len(head):
        raise ReportError(f"{path} is not an error-over-time CSV (a 't_s' column, then one column per series, "
                          f"and at least one row)")
    return head, data


def find_curve_files(directory: str | Path) -> list[Path]:
    """The ``error_over_time_*.csv`` files of ``directory`` and of its immediate sub-directories."""
    d = Path(directory)
    if not d.is_dir():
        return []
    files = [p for p in sorted(d.glob("error_over_time_*.csv")) + sorted(d.glob("*/error_over_time_*.csv"))]
    return [p for p in files if _FILE.match(p.name)]


def load_curves(directory: str | Path) -> list[dict]:
    """Groups of series of the same scenario: ``{"name", "scenario", "series": {series: {"t", "e", "stats",
    "source"}}, "duplicates": [...]}`` (a series found twice for one scenario: the first file's is kept)."""
    groups: dict[tuple, dict] = {}
    for path in find_curve_files(directory):
        name = _FILE.match(path.name).group(1)
        side = {}
        if path.with_suffix(".json").is_file():
            try:
                side = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise ReportError(f"cannot read {path.with_suffix('.json')}: {exc}") from None
        scenario = side.get("scenario") or {}
        g = groups.setdefault((name, json.dumps(scenario, sort_keys=True)),
                              {"name": name, "scenario": scenario, "series": {}, "duplicates": []})
        head, data = _read_csv(path)
        for i, col in enumerate(head[1:], start=1):
            key = col[:-2] if col.endswith("_m") else col
            if key in g["series"]:
                g["duplicates"].append(f"{key} ({path})")
                continue
            g["series"][key] = {"t": data[:, 0], "e": data[:, i], "stats": (side.get("stats") or {}).get(key) or {},
                                "source": str(path)}
    return list(groups.values())


def _scenario_text(name: str, sc: dict) -> str:
    parts = [f"{k.replace('_', ' ')} {v}" for k, v in sc.items() if v not in (None, {}, [], (), "", False)
             and k not in ("source", "config_overrides")]
    over = sc.get("config_overrides") or {}
    parts += [f"{k.replace('_', ' ')} {v}" for k, v in over.items()]
    return f"{name}: " + ", ".join(parts) if parts else name


def backends_sections(directory: str | Path, plt) -> list[Section]:
    """One section per scenario: the error-over-time figure per backend and its table."""
    from .plots import plot_backend_errors

    sections = []
    for k, g in enumerate(load_curves(directory)):
        series = {s: v for s, v in g["series"].items() if not (s in SAME_AS and SAME_AS[s] in g["series"])}
        ekf_ate = (g["series"].get("ekf_online") or {}).get("stats", {}).get("ate_rmse_mean_m")
        rows = []
        for s in sorted(series, key=lambda s: list(SERIES).index(s) if s in SERIES else len(SERIES)):
            v = series[s]
            ate, band = v["stats"].get("ate_rmse_mean_m"), v["stats"].get("fraction_in_band")
            rows.append([SERIES.get(s, (s,))[0], "-" if ate is None else float(ate),
                         "-" if ate is None or not ekf_ate else f"{ate / ekf_ate:.2f}x",
                         "-" if band is None else f"{100 * band:.0f} %",
                         float(np.sqrt(np.mean(v["e"] ** 2))), float(v["e"][-1])])
        title = _scenario_text(g["name"], g["scenario"])
        fig, ax = plt.subplots(figsize=(10, 4.2))
        plot_backend_errors(ax, {s: (v["t"], v["e"]) for s, v in series.items()},
                            styles=SERIES, title=f"Mean position error over time per backend ({title})")
        text = ("Current-time: each epoch as the backend estimated it at that epoch (what the vehicle knew then). "
                "Held at the end: the whole trajectory as the backend holds it once the dive is over (iSAM2 holds "
                "it online; the EKF needs its offline RTS smoother; batch optimises once at the end). For a "
                "linear-Gaussian problem iSAM2's current-time estimate equals the filter's: iSAM2 gains by "
                "relinearising and by holding the smoothed past.")
        if g["duplicates"]:
            text += "\n\nSeries found twice for this scenario (the first kept): " + "; ".join(g["duplicates"]) + "."
        sections.append(Section(
            f"Position error over time per backend: {title}", text,
            tables=[(f"Backends on {title} (ATE: mean over the runs; error curves: mean over the runs at each epoch)",
                     ["estimate", "ATE mean (m)", "ATE / EKF online", "epochs with ANEES in band",
                      "time-RMS of the mean error (m)", "mean error at the end (m)"], rows)],
            figures=[Figure(f"backends_error_over_time_{k}.png", figure_to_png(fig),
                            f"Position error over time per backend ({title}).")]))
    return sections


def section_graph_run(backend: str, trajs: dict, smoothed: dict, truth: dict, plt) -> Section:
    """A factor-graph run (``--backend isam2|batch``): its current-time and end-of-dive errors over time."""
    from .plots import plot_smoothed_errors

    now = "iSAM2 current-time" if backend == "isam2" else "front-end filter (online)"
    end = "iSAM2 held at the end of the dive" if backend == "isam2" else "batch LM (whole dive)"
    fig, ax = plt.subplots(figsize=(10, 3.8))
    plot_smoothed_errors(ax, trajs, smoothed, truth, names=(now, end),
                         title=f"Position error over time: {now} (solid) and {end} (dotted)")
    return Section(f"Position error over time: {backend} backend",
                   f"Backend {backend}. Current-time: each epoch as estimated at that epoch"
                   + (" (iSAM2's graph optimum given the measurements so far)" if backend == "isam2" else
                      " (batch has no online solution: its front-end filter's)")
                   + f". Dotted: the whole trajectory as the {backend} graph holds it at the end of the dive. "
                   "Monte-Carlo curves of every backend together: semslam montecarlo --backend B --out MC/B, then "
                   "semslam report MC.",
                   figures=[Figure("fig_backend_errors.png", figure_to_png(fig),
                                   f"Position error over time, {backend} backend: {now} (solid) and {end} (dotted).")])


def build_backends_report(directory: str | Path) -> Path:
    """``report.html`` in ``directory`` from its error-over-time files (figures embedded, no ``figures/``)."""
    from .plots import pyplot_agg

    sections = backends_sections(directory, pyplot_agg())
    if not sections:
        raise ReportError(f"nothing to report in {directory}: no error_over_time_*.csv there or one level below")
    summary = ("Monte-Carlo comparison of the estimators on the same seeded missions and detections (issue 17). "
               "Units: metres, seconds.")
    return write_report(directory, "semslam backends report", sections, summary=summary, figure_files=False)
