"""A matplotlib figure as PNG bytes, the one way every report picture is serialised.

The bytes go to `io.write_bytes`, which writes them atomically; no `Software` metadata, so the
same figure gives the same bytes whatever matplotlib version wrote it (determinism)."""

from __future__ import annotations

import io as bytes_io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

DPI = 110


def png(figure: plt.Figure) -> bytes:
    """`figure` as PNG bytes at DPI dots per inch; the figure is closed."""
    buffer = bytes_io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    plt.close(figure)
    return buffer.getvalue()
