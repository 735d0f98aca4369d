"""Many dives, one call: :func:`run_batch` processes every dive (bag or dataset directory) into its own run
directory ``RUNS/<dive name>/`` as Dask tasks (or serially), then writes the batch's tables and index::

    RUNS/
      .semslam-run       the ownership marker of the batch's folder (semslam._outdir)
      <dive>/            one complete run directory per dive that succeeded (its own marker .semslam-run)
      summary.csv        per dive: status, duration, detections, landmarks and ATE per mode, error
      summary.md         the same table in markdown
      index.html         the table, linking each dive's report
      timings.csv        per dive: what this call did (processed, skipped, failed) and its wall time

``summary.*`` and ``index.html`` hold data only, never times: the same dives and seed give the same bytes
whatever the engine (serial, 2 local workers, a cluster) and whether a dive was processed now or kept from an
earlier call. Times go to ``timings.csv``.

Each dive is one task: ``process(dive, out_dir, options)`` writes into a staged directory that becomes
``RUNS/<dive>/`` only when complete (:func:`semslam._outdir.staged_output_dir`), so a dive interrupted half-way
(a killed worker, a power cut) is never taken for a complete one; its task is re-run by the scheduler. A dive that
raises fails alone: its error is in the summary and the other dives finish. A dive whose run directory is already
complete is skipped (its row read back from the directory) unless ``overwrite``. ``RUNS`` itself must be new,
empty, or a folder an earlier batch made (its ownership marker, :mod:`semslam._outdir`): the tables are never
written into a foreign folder. A killed task's staging folder (``.<dive>.semslam-<pid>-*.tmp``) is left alone.
"""

from __future__ import annotations

import csv
import io
import json
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable, Sequence

from .._atomic import atomic_write_text
from .._outdir import claim_output_dir, is_owned, staged_output_dir
from .._progress import Progress
from ..errors import InputError

SUMMARY_CSV, SUMMARY_MD, INDEX, TIMINGS = "summary.csv", "summary.md", "index.html", "timings.csv"


@dataclass(frozen=True)
class BatchResult:
    """Per dive (in the order given): its summary row; ``timings``: per dive ``(action, wall seconds)``."""

    out: Path
    rows: list
    timings: list

    @property
    def n_failed(self) -> int:
        return sum(r["status"] != "ok" for r in self.rows)


def dive_name(dive: str | Path) -> str:
    """The run directory name of a dive: a dataset directory's name, a bag file's name without its extension."""
    p = Path(dive)
    name = p.name if p.is_dir() else p.stem
    return name or p.resolve().name


def run_batch(dives: Sequence[str | Path], out: str | Path, process: Callable[[Path, Path, dict], Any], *,
              options: dict | None = None, overwrite: bool = False, client: Any = None, scheduler: str | None = None,
              jobs: int = 1, retries: int = 2, progress: Progress = False,
              on_dive: Callable[[int, dict], None] | None = None) -> BatchResult:
    """Process ``dives`` into ``out`` (see the module docstring) and write the tables; ``process(dive, out_dir,
    options)``: a module-level function writing one dive's run into ``out_dir`` (it runs on a worker: the dives,
    ``out`` and what ``options`` names must be on a file system every worker sees). Engine: ``client`` /
    ``scheduler`` / ``jobs`` as :func:`semslam.batch.engine.map_tasks`. ``on_dive(i, row)`` as each dive ends."""
    from .engine import TaskFailed, map_tasks

    if isinstance(dives, (str, Path)) or not len(dives):
        raise InputError(f"The 'DIVES' argument of semslam batch must name at least one bag or dataset directory. "
                         f"Got {dives!r} instead.")
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise InputError(f"The '--out' option must name a directory for the run directories. "
                         f"Got the file {str(root)!r} instead.")
    names: dict[str, str] = {}
    for d in dives:
        n = dive_name(d)
        if n in names:
            raise InputError(f"The dives {names[n]!r} and {str(d)!r} would share the run directory {n!r}: "
                             "give dives with distinct names.")
        names[n] = str(d)
    # a new folder, or one an earlier batch made (its marker proves it): never a foreign one, never a dive's
    claim_output_dir(root, kind="batch", inputs=dives)
    items = [{"dive": str(d), "run": str(root / n), "overwrite": overwrite} for n, d in names.items()]
    task = partial(run_dive, process=process, options=dict(options or {}))

    def done(i: int, r: Any) -> None:
        if on_dive is not None:
            on_dive(i, r if isinstance(r, dict) else _failed_row(items[i], str(r), 0.0))

    results = map_tasks(task, items, client=client, scheduler=scheduler, jobs=jobs, retries=retries,
                        progress=progress, desc="dives", on_result=done, capture_errors=True)
    rows, timings = [], []
    for item, r in zip(items, results):
        if isinstance(r, TaskFailed):  # the engine gave up (e.g. the dive killed every worker it ran on)
            r = _failed_row(item, str(r), float("nan"))
        timings.append((r.pop("action"), r.pop("wall_s")))
        rows.append(r)
    result = BatchResult(root, rows, timings)
    write_tables(result)
    return result


def run_dive(item: dict, *, process: Callable, options: dict) -> dict:
    """One dive (a Dask task): skip it if complete, else process it into a staged run directory; its summary row
    with ``action`` and ``wall_s``. Never raises for a dive's own error: the row carries it."""
    t0 = time.perf_counter()
    run = Path(item["run"])
    if is_owned(run, "run") and not item["overwrite"]:
        return {**row_from_run_dir(run, item["dive"]), "action": "skipped", "wall_s": time.perf_counter() - t0}
    try:
        with staged_output_dir(run, overwrite=item["overwrite"], option="--out") as tmp:
            process(Path(item["dive"]), tmp, options)
    except Exception as exc:  # the dive fails alone
        msg = " ".join(str(exc).split()) or type(exc).__name__
        return _failed_row(item, f"{type(exc).__name__}: {msg}", time.perf_counter() - t0)
    return {**row_from_run_dir(run, item["dive"]), "action": "processed", "wall_s": time.perf_counter() - t0}


def _failed_row(item: dict, error: str, wall_s: float) -> dict:
    return {"dive": Path(item["run"]).name, "source": item["dive"], "status": "failed", "error": error,
            "duration_s": None, "detections": None, "modes": {}, "report": None, "action": "failed", "wall_s": wall_s}


def row_from_run_dir(run: Path, source: str) -> dict:
    """The summary row of a complete run directory (``semslam run``'s layout), from its files only."""
    from ..run.rundir import DETECTIONS, METRICS, MODES_DIR

    modes = {}
    mode_root = run / MODES_DIR
    for d in sorted(mode_root.iterdir()) if mode_root.is_dir() else ():
        if (d / METRICS).is_file():
            m = json.loads((d / METRICS).read_text(encoding="utf-8"))
            modes[d.name] = {"landmarks": m.get("n_landmarks"), "ate_m": m.get("ate_rmse_m"),
                             "duration_s": m.get("duration_s"), "health": (m.get("health") or {}).get("verdict")}
    det = run / DETECTIONS
    n_det = sum(1 for line in det.read_text(encoding="utf-8").splitlines() if line.strip()) if det.is_file() else None
    duration = next((v["duration_s"] for v in modes.values() if v["duration_s"] is not None), None)
    # the run's health verdict (run.json): a dive that ran but went wrong is "bad", never "ok"
    verdict = "ok"
    if (run / "run.json").is_file():
        verdict = json.loads((run / "run.json").read_text(encoding="utf-8")).get("verdict", "ok")
    status = "bad" if verdict == "bad" else "ok"
    return {
        "dive": run.name,
        "source": source,
        "status": status,
        "health": verdict,
        "error": "",
        "duration_s": duration,
        "detections": n_det,
        "modes": modes,
        "report": "report.html" if (run / "report.html").is_file() else None,
    }


def _modes(rows: list) -> list:
    seen: list = []
    for r in rows:
        seen += [m for m in r["modes"] if m not in seen]
    return seen


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def table_rows(rows: list) -> tuple[list, list]:
    """Header and cells of the summary table (strings)."""
    modes = _modes(rows)
    header = ["dive", "status", "duration_s", "detections"]
    for m in modes:
        header += [f"landmarks_{m}", f"ate_{m}_m"]
    header.append("error")
    cells = []
    for r in rows:
        c = [r["dive"], r["status"], _fmt(r["duration_s"], 1), _fmt(r["detections"])]
        for m in modes:
            v = r["modes"].get(m, {})
            c += [_fmt(v.get("landmarks")), _fmt(v.get("ate_m"))]
        c.append(r["error"])
        cells.append(c)
    return header, cells


def write_tables(result: BatchResult) -> None:
    """``summary.csv``, ``summary.md``, ``index.html`` and ``timings.csv`` of a batch (each written atomically)."""
    from html import escape

    header, cells = table_rows(result.rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(cells)
    atomic_write_text(result.out / SUMMARY_CSV, buf.getvalue())
    atomic_write_text(result.out / SUMMARY_MD, markdown(header, cells) + "\n")
    n_ok = len(result.rows) - result.n_failed
    trs = []
    for r, c in zip(result.rows, cells):
        link = (f'<a href="{escape(r["dive"])}/{r["report"]}">{escape(r["dive"])}</a>' if r["report"]
                else escape(r["dive"]))
        trs.append("<tr>" + "".join(f"<td>{x}</td>" for x in [link] + [escape(x) for x in c[1:]]) + "</tr>")
    html = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>semslam batch</title>\n<style>"
            "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px}</style></head><body>\n"
            f"<h1>semslam batch: {n_ok} of {len(result.rows)} dives ok</h1>\n<table>\n<tr>"
            + "".join(f"<th>{escape(h)}</th>" for h in header) + "</tr>\n" + "\n".join(trs)
            + "\n</table>\n</body></html>\n")
    atomic_write_text(result.out / INDEX, html)
    lines = ["dive,action,wall_s"] + [f"{r['dive']},{a},{s:.3f}" for r, (a, s) in zip(result.rows, result.timings)]
    atomic_write_text(result.out / TIMINGS, "\n".join(lines) + "\n")


def markdown(header: list, cells: list) -> str:
    def row(c):
        return "| " + " | ".join(str(x).replace("|", "\\|") for x in c) + " |"

    return "\n".join([row(header), "|" + "---|" * len(header)] + [row(c) for c in cells])
