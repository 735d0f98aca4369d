"""Is a run's report readable in a minute? Checked in headless Chromium (issue 18, item 6).

Loads ``RUN/report.html`` in headless Chromium at 1280 x 900 with a probe script that measures, once the page has
loaded: where the summary table ends (it must be on the first screen), that every image decoded (natural width
> 0), how many table rows are visible without opening anything (collapsed tables hide theirs), the page's height
in screens, and whether raw metrics are dumped into the page. Prints a table; exit status 1 when a check fails.
Needs a Chromium (Debian: ``apt-get install chromium``); ``--chromium PATH`` to choose one.

    .venv/bin/python benchmarks/report_chromium.py runs/demo
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

_PROBE = """<script>
window.addEventListener('load', () => {
  const h2 = [...document.querySelectorAll('h2')];
  const summary = h2.find(h => h.textContent === 'Summary');
  let end = -1;
  if (summary) {
    let el = summary.nextElementSibling, last = summary;
    while (el && el.tagName !== 'H2') { last = el; el = el.nextElementSibling; }
    end = last.getBoundingClientRect().bottom + window.scrollY;
  }
  const imgs = [...document.images];
  const visible = r => r.offsetParent !== null && r.getClientRects().length > 0 && !r.closest('details:not([open])');
  const rows = [...document.querySelectorAll('tbody tr')].filter(visible).length;
  const out = {first_h2: h2.length ? h2[0].textContent : '', summary_bottom_px: end,
               images: imgs.length, images_broken: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).length,
               visible_table_rows: rows, collapsed_tables: document.querySelectorAll('details').length,
               page_height_px: document.documentElement.scrollHeight, pre_blocks: document.querySelectorAll('pre').length};
  const p = document.createElement('pre'); p.id = 'semslam-probe'; p.textContent = JSON.stringify(out);
  document.body.appendChild(p);
});
</script>"""

VIEWPORT = (1280, 900)


def probe(report: Path, chromium: str) -> dict:
    """Load ``report`` with the probe in headless Chromium; the probe's measurements."""
    html = report.read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "report.html"
        page.write_text(html.replace("</body>", _PROBE + "</body>"), encoding="utf-8")
        proc = subprocess.run([chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                               f"--window-size={VIEWPORT[0]},{VIEWPORT[1]}", "--virtual-time-budget=10000",
                               "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    m = re.search(r"<pre id=\"semslam-probe\">(.*?)</pre>", proc.stdout)
    if not m:
        raise RuntimeError(f"Chromium gave no probe result (exit {proc.returncode}): {proc.stderr[-500:]}")
    return json.loads(m.group(1).replace("&quot;", '"'))


def checks(r: dict) -> list[tuple[str, str, bool]]:
    """``(check, measured, passed)`` rows."""
    screens = r["page_height_px"] / VIEWPORT[1]
    return [
        ("summary is the first section", r["first_h2"], r["first_h2"] == "Summary"),
        ("summary ends on the first screen", f"{r['summary_bottom_px']:.0f} px (screen {VIEWPORT[1]} px)",
         0 < r["summary_bottom_px"] <= VIEWPORT[1]),
        ("every image decoded", f"{r['images'] - r['images_broken']} of {r['images']}", r["images_broken"] == 0),
        ("table rows visible without clicking", str(r["visible_table_rows"]), r["visible_table_rows"] <= 80),
        ("raw metrics not dumped (<pre> blocks)", str(r["pre_blocks"]), r["pre_blocks"] == 0),
        ("page height", f"{screens:.1f} screens", screens <= 25),
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="a run directory with report.html")
    ap.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    args = ap.parse_args()
    if not args.chromium:
        print("no Chromium found: install it (Debian: apt-get install chromium) or give --chromium PATH")
        return 2
    rows = checks(probe(Path(args.run) / "report.html", args.chromium))
    print("| check | measured | ok |\n|---|---|---|")
    for name, value, ok in rows:
        print(f"| {name} | {value} | {'yes' if ok else 'NO'} |")
    return 0 if all(ok for *_, ok in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
