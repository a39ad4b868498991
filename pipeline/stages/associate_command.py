"""`python -m pipeline associate`: two users' track tables associated and fused (issue 19).

Reads each table with its radar description (`track_tables`), takes both users' tracks at common times
(`common_time_states`), associates them with the chosen method and fuses the pairs (`table_association`).
Everything is computed before anything is written, so bad input (an InputError, exit 2) leaves no output,
and an output that would replace an input or the other output is refused first (`io.check_outputs`);
each output is written atomically, with the mode a plain write would give it (`io.atomic_path`).
Track pairs alike but left unpaired at several common times (`clock_check`: a probable clock offset between
the radars) are warned of, naming both files, the second's radars and the offset they imply.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.association import association_net, clock_check, registry, table_association
from pipeline.association.associator import Decision
from pipeline.association.common_time_states import Snapshot, common_frame, common_snapshots
from pipeline.association.track_tables import TrackTable, read_track_table
from pipeline.params import Params

log = logging.getLogger("pipeline")


def run_associate(params: Params, track_paths: list[Path], radar_paths: list[Path], method: str, models_dir: Path,
                  pairs_out: Path, fused_out: Path) -> None:
    io.check_outputs({"--tracks": track_paths, "--radar": radar_paths},
                           {"--pairs": pairs_out, "--fused": fused_out})
    first, second = (read_track_table(tracks, radar, params.associate.max_speed_mps)
                     for tracks, radar in zip(track_paths, radar_paths))
    model = association_net.load(models_dir / "association_net.pt") if registry.needs_network([method]) else None
    frame = common_frame(first, second)
    snapshots = common_snapshots(first, second, frame, params.associate)
    decisions = table_association.decide(snapshots, method, params.association, model,
                                           params.associate.keep_probability)
    _warn_of_clock_offset(first, second, snapshots, decisions, params)
    pairs = table_association.pairs_table(snapshots, decisions)
    fused = table_association.fused_table(snapshots, decisions, frame, params.associate.fusion_criterion)
    io.write_parquet(pairs, pairs_out)
    io.write_parquet(fused, fused_out)
    log.info("associate (%s): %d common times, %d pairs -> %s; %d picture rows -> %s", method, len(snapshots),
             pairs.num_rows, pairs_out, fused.num_rows, fused_out)


def _warn_of_clock_offset(first: TrackTable, second: TrackTable, snapshots: list[Snapshot],
                          decisions: list[Decision], params: Params) -> None:
    """A warning when the decisions leave track pairs alike unpaired (`clock_check.clock_evidence`)."""
    evidence = clock_check.clock_evidence(snapshots, [d.pairs for d in decisions], [d.bias_m for d in decisions],
                                          [d.time_offset_s for d in decisions], params.association)
    if evidence.pairs:
        reach = params.association.max_bias_m / 1e3
        log.warning("%s (radars %s) against %s (radars %s): %d track pairs with matching velocities stay unpaired "
                    "at %d common times, displaced along their velocity (within %.1f km across it): a probable clock "
                    "offset, the second table's time stamps about %.2f s late (its radars' clock; beyond the "
                    "method's own estimate); --method bias_robust estimates it (association.max_time_offset_s)",
                    second.path, sorted(second.sites), first.path, sorted(first.sites), evidence.pairs,
                    evidence.times, reach, evidence.offset_s)
