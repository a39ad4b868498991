"""Draw the architecture picture of docs/architecture.md: a plot's path from its file to a confirmed track.

    python tools/architecture_picture.py [--out reports/architecture.png]

Boxes are the modules a plot passes through (pipeline/recordings/plot_table.py and pipeline/tracker/), in
the order the loop (pipeline/tracker/run.py) calls them; the picture is written atomically.
"""

from __future__ import annotations

import argparse
import io as bytes_io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

from pipeline import io  # noqa: E402

ROLE, DATA, STEP = "#dbe9f6", "#f3f3f3", "#fdebd3"  # box colours: a role (Protocol), data, a loop step

# (x centre, y centre, width, text, colour), in axes units of a 10 x 15 canvas
BOXES = {
    "files": (5.0, 14.2, 9.0, "simulated Parquet  |  your Parquet + radar description  |  ASTERIX CAT048 + CAT034\n"
                              "plots: radar id, time, slant range, azimuth, altitude", DATA),
    "table": (5.0, 12.6, 9.0, "plot_table.py: one Plots table, per plot: ECEF position from its own radar's site\n"
                              "(thesis eqs 4.1-4.6), measured range, covariance R from its own radar's errors", DATA),
    "batch": (5.0, 11.1, 9.0, "assigner.batches: one plot (nearest neighbour, oracle) or one antenna scan of one "
                              "radar (GNN)", ROLE),
    "manage": (5.0, 9.9, 9.0, "management (tracks.LiveTracks + management.ThesisWeights): silent tracks lose 0.2,\n"
                              "deleted when lowered at the candidate weight or below the start weight", ROLE),
    "near": (5.0, 8.6, 9.0, "pre-filter: the live tracks within 20 km of the plot (LiveTracks.near)", STEP),
    "young": (2.4, 7.2, 4.4, "young tracks: gate.RadiusGate\n(distance to the last plot / radius)", ROLE),
    "predict": (7.6, 7.2, 4.4, "mature tracks: estimator.predict,\nonce for all candidates -> Prediction", ROLE),
    "gate": (7.6, 5.9, 4.4, "gate (Window, ChiSquare, MIA, AE):\nnormalised errors from the Prediction", ROLE),
    "assign": (5.0, 4.6, 9.0, "assigner.assign: nearest per plot | global nearest per scan | true association",
               ROLE),
    "update": (7.6, 3.3, 4.4, "a track chosen: estimator.update from the\nsame Prediction; LiveTracks.associate "
                              "+0.2", ROLE),
    "start": (2.4, 3.3, 4.4, "no track: LiveTracks.start (weight 0.4),\nestimator.start", ROLE),
    "updates": (5.0, 2.0, 9.0, "updates.py: the update table, one row per update (position, weight, association, "
                               "covariance)", DATA),
    "confirmed": (5.0, 0.75, 9.0, "confirmed_associations: not a start and the weight confirmed (1.0)\n"
                                  "-> track output status, the thesis's metrics, OSPA, NEES, the pictures", DATA),
}
ARROWS = [("files", "table"), ("table", "batch"), ("batch", "manage"), ("manage", "near"), ("near", "young"),
          ("near", "predict"), ("predict", "gate"), ("young", "assign"), ("gate", "assign"), ("assign", "update"),
          ("assign", "start"), ("predict", "update"), ("update", "updates"), ("start", "updates"),
          ("updates", "confirmed")]
HEIGHT = 0.85


def picture() -> bytes:
    figure, axis = plt.subplots(figsize=(10.8, 15))
    axis.set_xlim(0, 10.8)
    axis.set_ylim(0, 15)
    axis.axis("off")
    for x, y, width, text, colour in BOXES.values():
        axis.add_patch(FancyBboxPatch((x - width / 2, y - HEIGHT / 2), width, HEIGHT, boxstyle="round,pad=0.05",
                                      facecolor=colour, edgecolor="0.4"))
        axis.text(x, y, text, ha="center", va="center", fontsize=8.5)
    for start, end in ARROWS:
        (x0, y0, *_), (x1, y1, *_) = BOXES[start], BOXES[end]
        if start == "predict" and end == "update":  # the same Prediction, handed on: along the right edge
            axis.annotate("", xy=(x1 + 2.25, y1), xytext=(x0 + 2.25, y0), arrowprops=dict(
                arrowstyle="->", color="tab:blue", linestyle="--", connectionstyle="arc3,rad=-0.3"))
            axis.text(10.75, (y0 + y1) / 2, "same\nPrediction", color="tab:blue", fontsize=8, ha="right")
            continue
        axis.annotate("", xy=(x1, y1 + HEIGHT / 2 + 0.05), xytext=(x0, y0 - HEIGHT / 2 - 0.05),
                      arrowprops=dict(arrowstyle="->", color="0.3"))
    axis.set_title("A plot's path from its file to a confirmed track (blue: roles, orange: loop steps, grey: data)",
                   fontsize=10)
    figure.tight_layout()
    buffer = bytes_io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    plt.close(figure)
    return buffer.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="reports/architecture.png")
    args = parser.parse_args()
    io.write_bytes(picture(), Path(args.out))


if __name__ == "__main__":
    main()
