"""`dvc plots show` offline: the committed HTML template holds Vega, Vega-Lite and Vega-Embed itself."""

from __future__ import annotations

from pathlib import Path

from pipeline.reports import plots_page
from tests.project import REPOSITORY

COMMITTED = REPOSITORY / plots_page.TEMPLATE


def test_the_committed_template_is_what_the_pinned_vl_convert_makes(tmp_path: Path) -> None:
    """Regenerated with `python -m pipeline plots-template` after an upgrade of vl-convert-python."""
    plots_page.write_template(tmp_path / "offline.html")
    assert (tmp_path / "offline.html").read_bytes() == COMMITTED.read_bytes()


def test_the_template_loads_no_script_and_scales_pictures_to_the_page() -> None:
    """DVC fills `{plot_divs}`; without `{scripts}` it adds none of its CDN tags; vegaEmbed is defined inline."""
    page = COMMITTED.read_text()
    assert "{plot_divs}" in page and "{scripts}" not in page and "<script src" not in page
    assert "window.vegaEmbed=" in page and "img { max-width: 100%; height: auto; }" in page
    assert "html_template = plots/offline.html" in (REPOSITORY / ".dvc" / "config").read_text()
