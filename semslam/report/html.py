"""A single self-contained HTML page: figures embedded as base64 PNG, tables, metrics.

The page is built from :class:`Section` objects so that every producer (demo, ``semslam report``, a
``slam`` or ``recognize`` run) adds what it has and nothing else.
"""

from __future__ import annotations

import base64
import html
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from .._atomic import atomic_write_bytes, atomic_write_text


@dataclass
class Figure:
    """A figure saved as PNG beside the report and embedded in it."""

    filename: str
    png: bytes
    caption: str


@dataclass
class Section:
    title: str
    text: str = ""
    tables: list[tuple[str, Sequence[str], Sequence[Sequence[object]]]] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)


def figure_to_png(fig, dpi: int = 110) -> bytes:
    """Render a matplotlib figure to PNG bytes and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _table_html(caption: str, header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    def cell(v: object) -> str:
        if v in ("met", "NOT met"):  # a goal's verdict (the summary table)
            return f"<span class='verdict-{'met' if v == 'met' else 'not'}'>{v}</span>"
        if isinstance(v, float):
            return f"{v:.4g}"
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    table = (
        f"<table><caption>{html.escape(caption)}</caption><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    )
    if len(rows) > COLLAPSE_ROWS:  # a long table is one line until the reader opens it
        return (f"<details><summary>{html.escape(caption)}: {len(rows)} rows (click to show)</summary>"
                f"{table}</details>")
    return table


#: tables longer than this are collapsed (<details>)
COLLAPSE_ROWS = 12


_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:1em 0;font-size:.9em}caption{text-align:left;font-weight:600;padding:.3em 0}
td,th{border:1px solid #bbb;padding:.25em .6em;text-align:right}th{background:#f0f0f0}
td:first-child,th:first-child{text-align:left}figure{margin:1em 0}img{max-width:100%}
figcaption{font-size:.9em;color:#444}pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.8em}
details{margin:1em 0}summary{cursor:pointer;font-weight:600}.verdict-met{color:#176117}.verdict-not{color:#a00}
"""


#: in the head of every report semslam writes: what proves a report.html (and its figures/) are semslam's to rebuild
GENERATOR = "<meta name='generator' content='semslam report'>"


def check_report_target(run_dir: Path, figure_names: Sequence[str]) -> None:
    """A report is rebuilt in place only over files semslam wrote: in a directory semslam owns (its marker), or
    where report.html is semslam's (:data:`GENERATOR`). Elsewhere an existing report.html, or a figure file of the
    same name, is someone else's: :class:`~semslam.errors.ReportError`, nothing written."""
    from .._outdir import is_owned
    from ..errors import ReportError

    if is_owned(run_dir):
        return
    report = run_dir / "report.html"
    ours = False
    if report.is_file():
        with open(report, "rb") as f:
            ours = GENERATOR.encode() in f.read(4096)
    if report.exists() and not ours:
        raise ReportError(f"The directory '{run_dir}' holds a report.html semslam did not write: it is left as it is. "
                          f"Move it away, or report a directory semslam wrote.")
    if not ours:
        clash = sorted(n for n in set(figure_names) if (run_dir / "figures" / n).exists())
        if clash:
            raise ReportError(f"The directory '{run_dir}' holds figures/{clash[0]} that semslam did not write (no "
                              f"semslam report.html beside it): it is left as it is. Move it away first.")


def write_report(run_dir: str | Path, title: str, sections: Sequence[Section], *, metrics: dict | None = None,
                 summary: str = "", figure_files: bool = True) -> Path:
    """Write every figure as PNG into ``run_dir/figures`` and ``run_dir/report.html`` (atomically).

    ``metrics``: the run's metrics, linked as ``metrics.json`` (written beside the report when it is not there
    yet), never dumped into the page. ``figure_files``: False embeds the figures only (no ``figures/``). Tables longer
    than :data:`COLLAPSE_ROWS` rows are collapsed. Returns the
    report's path.
    """
    run_dir = Path(run_dir)
    if figure_files:
        check_report_target(run_dir, [fig.filename for sec in sections for fig in sec.figures])
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'>{GENERATOR}<title>{html.escape(title)}</title>"
             f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>"]
    if summary:
        parts.append(f"<p>{html.escape(summary)}</p>")
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec.title)}</h2>")
        if sec.text:
            parts.append("".join(f"<p>{html.escape(p)}</p>" for p in sec.text.split("\n\n")))
        for caption, header, rows in sec.tables:
            parts.append(_table_html(caption, header, rows))
        for fig in sec.figures:
            if figure_files:
                atomic_write_bytes(run_dir / "figures" / fig.filename, fig.png)
            b64 = base64.b64encode(fig.png).decode("ascii")
            parts.append(f"<figure><img alt='{html.escape(fig.caption)}' src='data:image/png;base64,{b64}'>"
                         f"<figcaption>{html.escape(fig.caption)}</figcaption></figure>")
    if metrics is not None:
        if not (run_dir / "metrics.json").is_file():
            atomic_write_text(run_dir / "metrics.json", json.dumps(metrics, indent=2))
        parts.append("<h2>All metrics</h2><p>Every number of this run, machine-readable: "
                     "<a href='metrics.json'>metrics.json</a>.</p>")
    parts.append("</body></html>")
    path = run_dir / "report.html"
    atomic_write_text(path, "\n".join(parts))
    return path
