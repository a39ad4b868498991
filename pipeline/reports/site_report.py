"""The radar-sites part of the comparison: each tracker's position error at every site against
its error at the training site (`reports/site_metrics.json`, written by `evaluate_sites`).

A tracker that works in the radar's own frame should not care where the radar stands: the
same routes at another site are the same problem, so its position error (MAE, m) there should
be within `TOLERANCE` of its error at the training site.
"""

from __future__ import annotations

import math

TOLERANCE = 0.10   # the goal: every site's position error within 10 % of the training site's


def _error(runs: dict[str, dict], name: str) -> float | None:
    value = runs.get(name, {}).get("MAE")
    return None if value is None or not math.isfinite(value) else float(value)


def site_comparison(report: dict) -> dict:
    """Per run: its MAE (m) at the training site, and at each site the MAE, the ratio to the
    training site's and whether that is within the tolerance; `within_everywhere` is false where
    any site is off or has no MAE to compare."""
    training = report["training"]
    runs = {}
    for name in training["runs"]:
        base = _error(training["runs"], name)
        at_sites = {}
        for site in report["sites"]:
            error = _error(site["runs"], name)
            ratio = None if error is None or not base else error / base
            at_sites[site["name"]] = {"MAE": error, "ratio": ratio,
                                      "within": ratio is not None and abs(ratio - 1.0) <= TOLERANCE}
        runs[name] = {"training_MAE": base, "sites": at_sites,
                      "within_everywhere": all(s["within"] for s in at_sites.values())}
    return {"tolerance": TOLERANCE,
            "sites": [{key: site[key] for key in ("name", "latitude_deg", "longitude_deg", "height_m")}
                      for site in [training, *report["sites"]]],
            "runs": runs}


def _place(site: dict) -> str:
    latitude, longitude = site["latitude_deg"], site["longitude_deg"]
    return (f"{abs(latitude):.1f}° {'N' if latitude >= 0 else 'S'}, "
            f"{abs(longitude):.1f}° {'E' if longitude >= 0 else 'W'}")


def site_table(comparison: dict, order: list[str]) -> str:
    """Runs in `order`, one row each: the training site's MAE, each site's MAE with its ratio to
    the training site's (marked when outside the tolerance), and whether every site is within."""
    training, *others = comparison["sites"]
    header = ["tracker", f"training site ({_place(training)}): MAE (m)",
              *(f"{site['name']} ({_place(site)}): MAE (m), ratio" for site in others),
              f"all within {comparison['tolerance']:.0%}"]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for name in order:
        run = comparison["runs"][name]
        cells = ["n/a" if run["training_MAE"] is None else f"{run['training_MAE']:.0f}"]
        for site in others:
            at = run["sites"][site["name"]]
            cells.append("n/a" if at["ratio"] is None else
                         f"{at['MAE']:.0f}, {at['ratio']:.3f}" + ("" if at["within"] else " **off**"))
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {'yes' if run['within_everywhere'] else 'no'} |")
    return "\n".join(lines)


def site_sentence(comparison: dict, neural: list[str]) -> str:
    """The goal in one sentence: how many of the `neural` runs keep their position error within
    the tolerance at every site, and the largest change among them."""
    changes = [(abs(at["ratio"] - 1.0), at["ratio"], name, site) for name in neural
               for site, at in comparison["runs"][name]["sites"].items() if at["ratio"] is not None]
    kept = sum(comparison["runs"][name]["within_everywhere"] for name in neural)
    _, ratio, name, site = max(changes, default=(None, None, None, None))
    largest = f"; the largest change: {name} at {site}, ratio {ratio:.3f}" if changes else ""
    return (f"- Radar sites: {kept} of {len(neural)} neural trackers keep their position error (MAE) within "
            f"{comparison['tolerance']:.0%} of the training site's at all {len(comparison['sites']) - 1} other "
            f"sites{largest}.")
