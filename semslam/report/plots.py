"""Figures of the report. Every function draws into a given matplotlib ``ax`` from plain arrays and never
calls ``show()`` (scikit-learn Display / evo ``plot.traj`` style), so it works headless and in tests.

Units: metres and seconds on every axis; positions in the world NED frame (x north, y east).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

MODE_COLOURS = {
    "truth": "black",
    "dr": "tab:blue",
    "position": "tab:orange",
    "pose": "tab:red",
    "pose+heading": "tab:green",
}
MODE_NAMES = {
    "truth": "ground truth",
    "dr": "dead reckoning",
    "position": "SLAM, position-only",
    "pose": "SLAM, full pose",
    "pose+heading": "SLAM, full pose + heading bias",
}


def pyplot_agg():
    """``matplotlib.pyplot`` on the Agg backend (no display), imported on first use."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_confusion_matrix(ax, matrix: np.ndarray, labels: Sequence[str], *, title: str) -> None:
    """Confusion matrix (rows actual, columns predicted) as an annotated heat map of row percentages."""
    m = np.asarray(matrix, dtype=float)
    row = m.sum(axis=1, keepdims=True)
    pct = np.divide(100.0 * m, row, out=np.zeros_like(m), where=row > 0)
    ax.imshow(pct, cmap="Blues", vmin=0, vmax=100)
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            ax.text(j, i, f"{int(m[i, j])}\n{pct[i, j]:.0f}%", ha="center", va="center",
                    color="white" if pct[i, j] > 60 else "black", fontsize=8)
    ax.set_xticks(range(len(labels)), labels=list(labels), rotation=30, ha="right")
    ax.set_yticks(range(len(labels)), labels=list(labels))
    ax.set_xlabel("predicted class")
    ax.set_ylabel("actual class")
    ax.set_title(title)


def covariance_ellipse_xy(mean_xy: np.ndarray, cov_xy: np.ndarray, n_sigma: float = 3.0,
                          n_points: int = 60) -> np.ndarray:
    """Points ``(n_points, 2)`` of the n-sigma ellipse of a 2-D Gaussian."""
    vals, vecs = np.linalg.eigh(0.5 * (cov_xy + cov_xy.T))
    vals = np.clip(vals, 0.0, None)
    t = np.linspace(0, 2 * np.pi, n_points)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    return mean_xy + n_sigma * (circle * np.sqrt(vals)) @ vecs.T


def plot_trajectories(ax, runs: dict, *, landmarks: dict | None = None, objects_xy: dict | None = None,
                      ellipse_every_s: float = 30.0, title: str = "") -> None:
    """Trajectories in the horizontal plane (east on the horizontal axis, north up, as a map).

    ``runs`` maps a mode (``"truth"``, ``"dr"``, ``"pose"`` ...) to a dict with ``stamp_s`` (N,),
    ``position_ned_m`` (N, 3) and, for estimates, ``position_cov`` (N, 3, 3); 3-sigma ellipses are drawn every
    ``ellipse_every_s``. ``landmarks`` maps a mode to a list of dicts (``label``, ``position_ned_m``, ``cov``);
    ``objects_xy`` maps object names to their true (north, east).
    """
    for mode, run in runs.items():
        p = np.asarray(run["position_ned_m"])
        colour = MODE_COLOURS.get(mode, None)
        ax.plot(p[:, 1], p[:, 0], color=colour, lw=1.4 if mode == "truth" else 1.0,
                ls="--" if mode == "truth" else "-", label=MODE_NAMES.get(mode, mode))
        cov = run.get("position_cov")
        if cov is not None and len(p):
            t = np.asarray(run["stamp_s"])
            marks = np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, ellipse_every_s))
            for k in np.unique(np.clip(marks, 0, len(t) - 1)):
                c = np.asarray(cov[k])[:2, :2]
                e = covariance_ellipse_xy(p[k, :2], c)
                ax.plot(e[:, 1], e[:, 0], color=colour, lw=0.6, alpha=0.8)
    if objects_xy:
        for name, (n, e) in objects_xy.items():
            ax.plot(e, n, marker="*", ms=11, color="gold", mec="black", ls="none")
            ax.annotate(name, (e, n), textcoords="offset points", xytext=(5, 5), fontsize=7)
    if landmarks:
        for mode, lms in landmarks.items():
            colour = MODE_COLOURS.get(mode, None)
            for lm in lms:
                pos = np.asarray(lm["position_ned_m"])
                ax.plot(pos[1], pos[0], marker="x", color=colour, ms=7)
                if lm.get("cov") is not None:
                    e = covariance_ellipse_xy(pos[:2], np.asarray(lm["cov"])[:2, :2])
                    ax.plot(e[:, 1], e[:, 0], color=colour, lw=0.6, ls=":")
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    ax.set_title(title or "Trajectories with 3-sigma ellipses (horizontal plane, NED)")


def plot_error_bounds(axes, runs: dict, truth: dict, *, detection_stamps_s: Sequence[float] = (),
                      title: str = "") -> None:
    """Per-axis position error with +-3-sigma bounds over time (the papers' Fig. 6).

    ``axes`` is a sequence of three axes (x, y, z); ``runs`` maps a mode to ``stamp_s``, ``position_ned_m``,
    ``position_cov``; ``truth`` has ``stamp_s`` and ``position_ned_m`` (interpolated at the run's stamps).
    """
    names = ("x (north)", "y (east)", "z (down)")
    for mode, run in runs.items():
        t = np.asarray(run["stamp_s"])
        p = np.asarray(run["position_ned_m"])
        cov = np.asarray(run["position_cov"])
        ref = np.stack([np.interp(t, truth["stamp_s"], np.asarray(truth["position_ned_m"])[:, i]) for i in range(3)], 1)
        err = p - ref
        colour = MODE_COLOURS.get(mode, None)
        for i, ax in enumerate(axes):
            sigma3 = 3.0 * np.sqrt(np.clip(cov[:, i, i], 0, None))
            ax.plot(t, err[:, i], color=colour, lw=0.8, label=f"{MODE_NAMES.get(mode, mode)} error")
            ax.plot(t, sigma3, color=colour, lw=0.8, ls="--")
            ax.plot(t, -sigma3, color=colour, lw=0.8, ls="--")
    for i, ax in enumerate(axes):
        for s in detection_stamps_s:
            ax.axvline(s, color="green", lw=0.3, alpha=0.25)
        ax.set_ylabel(f"{names[i]} error [m]")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    axes[0].legend(fontsize=7, loc="upper left")
    if title:
        axes[0].set_title(title)


def plot_smoothed_errors(ax, filtered: dict, smoothed: dict, truth: dict, *, title: str = "",
                         names: tuple[str, str] = ("online", "smoothed")) -> None:
    """Position error norm over time of each mode's online estimate (solid) and of its RTS-smoothed
    trajectory (dotted). ``filtered`` and ``smoothed`` map a mode to ``stamp_s`` and ``position_ned_m``;
    ``truth`` has ``stamp_s`` and ``position_ned_m``; ``names``: the two estimates' names in the legend."""
    for mode, run in filtered.items():
        colour = MODE_COLOURS.get(mode, None)
        for style, r, what in (("-", run, names[0]), (":", smoothed.get(mode), names[1])):
            if r is None:
                continue
            t = np.asarray(r["stamp_s"])
            ref = np.stack([np.interp(t, truth["stamp_s"], np.asarray(truth["position_ned_m"])[:, i])
                            for i in range(3)], 1)
            err = np.linalg.norm(np.asarray(r["position_ned_m"]) - ref, axis=1)
            ax.plot(t, err, color=colour, ls=style, lw=0.9, label=f"{MODE_NAMES.get(mode, mode)} {what}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", ncol=2)
    if title:
        ax.set_title(title)


def plot_backend_errors(ax, series: dict, *, styles: dict, title: str = "") -> None:
    """Mean position error over time, one line per estimate: ``series`` maps a name to ``(t_s, error_m)``;
    ``styles`` a name to ``(label, colour, line style)`` (a name not there: its own label, default style)."""
    order = list(styles)
    for i, name in enumerate(sorted(series, key=lambda s: order.index(s) if s in order else len(order))):
        t, e = series[name]
        label, colour, ls = styles.get(name, (name, None, "-"))
        # lines drawn first are wider: estimates that coincide (iSAM2's current-time and the EKF's) stay visible
        ax.plot(np.asarray(t), np.asarray(e), color=colour, ls=ls, lw=max(2.4 - 0.35 * i, 0.9), label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("mean position error [m]")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", ncol=2)
    if title:
        ax.set_title(title, fontsize=9)


def plot_nees(ax, stamp_s: np.ndarray, nees: np.ndarray, band: tuple[float, float], *, dof: int,
              label: str = "NEES", title: str = "") -> None:
    """NEES (or ANEES) over time with its chi-square 95% band."""
    ax.plot(stamp_s, nees, lw=0.8, label=label)
    ax.axhspan(band[0], band[1], color="green", alpha=0.15, label=f"95% chi-square band (dof {dof})")
    ax.axhline(dof, color="green", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("NEES [-]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(title or "Position NEES over time")


def plot_histogram(ax, values: np.ndarray, *, xlabel: str, title: str, bins: int = 30) -> None:
    """A plain histogram with its median marked."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v):
        ax.hist(v, bins=bins, color="tab:blue", alpha=0.8)
        ax.axvline(np.median(v), color="black", ls="--", label=f"median {np.median(v):.3g}")
        ax.legend(fontsize=7)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("count")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
