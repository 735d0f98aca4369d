"""`semslam report DIR` rebuilds a report in place only over files semslam wrote (issue 31, item 1): a report.html
or a figure of someone else's is refused with one line and left byte for byte; semslam's own report is rebuilt."""

from __future__ import annotations

import pytest

from semslam._outdir import MARKER, marker_text
from semslam.errors import ReportError
from semslam.report.html import Figure, Section, write_report

PNG = b"\x89PNG\r\n\x1a\nnot really"


def _sections() -> list[Section]:
    return [Section("A", "text", figures=[Figure("fig.png", PNG, "a figure")])]


def test_a_foreign_report_html_is_refused_and_left_as_it_is(tmp_path):
    (tmp_path / "report.html").write_text("<html>my own notes</html>")
    with pytest.raises(ReportError, match=r"report.html semslam did not write"):
        write_report(tmp_path, "t", _sections())
    assert (tmp_path / "report.html").read_text() == "<html>my own notes</html>"
    assert not (tmp_path / "figures").exists()


def test_a_foreign_figure_of_the_same_name_is_refused(tmp_path):
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "fig.png").write_bytes(b"mine")
    with pytest.raises(ReportError, match=r"figures/fig.png"):
        write_report(tmp_path, "t", _sections())
    assert (tmp_path / "figures" / "fig.png").read_bytes() == b"mine" and not (tmp_path / "report.html").exists()


def test_semslams_own_report_is_rebuilt_in_place(tmp_path):
    write_report(tmp_path, "first", _sections())
    write_report(tmp_path, "second", _sections())   # its own report.html and figures: rebuilt
    assert "second" in (tmp_path / "report.html").read_text()
    assert (tmp_path / "figures" / "fig.png").read_bytes() == PNG


def test_a_directory_semslam_owns_is_rebuilt_whatever_its_report(tmp_path):
    """An earlier semslam's run (its marker) with a report from before the generator tag."""
    (tmp_path / MARKER).write_text(marker_text("run"))
    (tmp_path / "report.html").write_text("<html>an older semslam report</html>")
    write_report(tmp_path, "rebuilt", _sections())
    assert "rebuilt" in (tmp_path / "report.html").read_text()
