"""Reports: the papers' tables and figures regenerated from a run, as PNG and one self-contained HTML page."""
