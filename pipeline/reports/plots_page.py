"""The page `dvc plots show` writes, readable without a network (issue 31).

DVC's own page loads Vega, Vega-Lite and Vega-Embed from a CDN (dvc-render's `VegaRenderer.SCRIPTS`), so
offline its one chart, the networks' loss per epoch, stays blank with no message. `write_template` writes
the HTML template DVC reads instead (`plots.html_template` in `.dvc/config`, a path relative to `.dvc/`):
the three libraries inline, from the Vega project's own `vl-convert-python` package
(`vl_convert.javascript_bundle`), so nothing is fetched, and pictures scaled to the page's width rather than
cut at its right edge. The template is committed (a fresh clone's `dvc plots show` needs it, and DVC
names no missing template, only "HTML template has to contain '{plot_divs}'"), made by `python -m pipeline
plots-template` with the version `constraints.txt` pins (a dev dependency; `tests/test_plots_page.py` holds
the committed file to what it makes). DVC fills its `{plot_divs}`; it has no `{scripts}`, so DVC adds no
CDN tags.

The loss chart's own template is `.dvc/plots/loss.json` (dvc.yaml's `plots:`): one colour per network,
the training and validation losses as solid and dashed lines, on a log axis, where DVC's `linear` template
gives every line one colour and a linear axis that the first epochs' losses flatten.
"""

from __future__ import annotations

from pathlib import Path

from pipeline import io

VEGA_LITE = "v5.21"  # the Vega-Lite major version of DVC's templates (their $schema is vega-lite/v5)
TEMPLATE = Path(".dvc") / "plots" / "offline.html"  # where `.dvc/config`'s plots.html_template points
STYLE = """
    body { font-family: sans-serif; margin: 1em; }
    img { max-width: 100%; height: auto; }
    table { border-spacing: 15px; }
"""


def page_template(bundle: str) -> str:
    """The template's HTML around the JavaScript `bundle` (which defines vegaEmbed globally)."""
    return "\n".join(["<!DOCTYPE html>", "<html>", "<head>", '<meta charset="utf-8">', "{refresh_tag}",
                      "<title>DVC plots</title>", f"<script>{bundle}</script>", f"<style>{STYLE}</style>", "</head>",
                      "<body>", "{plot_divs}", "</body>", "</html>", ""])


def write_template(out: Path) -> None:
    """Write the offline template (module docstring) to `out`, atomically."""
    import vl_convert

    io.write_text(page_template(vl_convert.javascript_bundle(vl_version=VEGA_LITE)), out)
