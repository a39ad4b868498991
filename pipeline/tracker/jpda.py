"""The assigner of joint probabilistic data association (JPDA) over each antenna scan: a soft assigner.

Global nearest neighbour gives each track at most one plot of a scan and updates it with that plot
alone; where aircraft cross or fly in formation, the plot it gives may be the neighbour's, and the
track follows the wrong aircraft. JPDA updates each track with every plot in its gate, each weighted
by the probability that it is the track's own, over all the ways the scan's plots can be shared out
among the tracks (Fortmann, Bar-Shalom & Scheffe, "Sonar tracking of multiple targets using joint
probabilistic data association", IEEE J. Oceanic Engineering 8(3), 1983).

**The probabilities.** A joint event gives each plot of the batch to at most one track and each track
at most one plot. With false plots a Poisson process of spatial density lambda
(`tracker.association.jpda_clutter_density_per_m3`) and each aircraft detected with probability P_D
(`jpda_detection_probability`) inside its gate of probability P_G (the chi-square gate's,
`kalman_gate_probability`), an event's probability is proportional to the product over its tracks of

- P_D N(nu_ij; 0, S_ij) / lambda for a track i given plot j (nu the plot's innovation against the
  track's prediction at the plot's time, S its covariance plus the plot's measurement covariance);
- 1 - P_D P_G for a track given none

(the parametric JPDA: Bar-Shalom, Willett & Tian, "Tracking and Data Fusion", YBS 2011, 3.4; Bar-Shalom,
Daum & Huang, "The probabilistic data association filter", IEEE Control Systems 29(6), 2009, eq. 47).
A track's weights (`Hypotheses`) are the marginal probabilities of its events: beta_ij, and beta_i0
that none of the plots is its own. Only mature tracks (gated by the chi-square gate, with a
prediction) take part; young tracks, gated by the radius, take the plot GNN gives them.

The marginals are exact, by efficient hypothesis management (EHM2 of `pyehm`, the library Stone Soup's
`JPDAwithEHM2` runs: Maskell, Briers & Wright, "Fast mutual exclusion", SPIE 5428, 2004; Horridge &
Maskell, "Real-time tracking of hundreds of targets with efficient exact JPDAF implementation", FUSION
2006), one call per cluster of tracks that share plots; a track alone in its cluster takes the closed
form of PDA, beta_j = L_j / (L_0 + sum_k L_k). A library rather than our own enumeration: the joint
events of a formation grow exponentially, and EHM's net is what keeps them exact at the scenes' sizes.

**What stays GNN's.** Batches (antenna scans), and the choices: which plot's row records a track's update
(the update table has one row per plot), which plots start tracks, and which tracks count a hit in
their management. A mature track with gated plots but no chosen plot is still updated (its filter),
silently: no row, a miss for its management. Each track is updated once per batch, at the time of its
reference plot (the chosen one, else its most probable), from the prediction at that time: the
competing plots of a scan come within hundredths of a second of each other (the antenna sweeps a few
degrees), so their innovations are taken against that one prediction, as Stone Soup's tracker takes a
batch's detections at one time (`pipeline.peers.stone_soup`). The update itself is the estimator's
(`update_mixtures`): each hypothesis's update merged per motion model (`batch_filters.collapsed`), for the
tuned classical filters (`kalman_cv_jpda` ... `imm_ca_ct_jpda`) and the network-scaled filter
(`kalman_net_jpda`). The LSTM update has none: its posterior is a network's output over MC-dropout copies,
not a Gaussian per hypothesis, and a mixture of such outputs would be a method of our own, not JPDA.
"""

from __future__ import annotations

import math

import numpy as np
from pyehm.core import EHM2
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.filters.batch_filters import LOG_NORMALISER, inverse3
from pipeline.tracker.assigner import Candidates, GlobalNearestPerScan, Hypotheses
from pipeline.tracker.tracks import LiveTracks


class JointProbabilisticPerScan(GlobalNearestPerScan):
    """GNN's scans and choices, and the JPDA weights of each scan's mature tracks (module docstring).
    `detection_probability` P_D and `gate_probability` P_G in (0, 1), `clutter_density_per_m3` lambda > 0
    (ValueError otherwise)."""

    def __init__(self, detection_probability: float, gate_probability: float, clutter_density_per_m3: float
                 ) -> None:
        super().__init__()
        if not 0.0 < detection_probability < 1.0 or not 0.0 < gate_probability < 1.0:
            raise ValueError(f"JPDA: detection probability {detection_probability} and gate probability "
                             f"{gate_probability} must lie in (0, 1)")
        if not clutter_density_per_m3 > 0.0:
            raise ValueError(f"JPDA: clutter density {clutter_density_per_m3} per m^3 must be above 0")
        self.log_missed = math.log(1.0 - detection_probability * gate_probability)
        self.log_detected = math.log(detection_probability) - math.log(clutter_density_per_m3)

    def hypotheses(self, tracks: LiveTracks, rows: range, candidates: list[Candidates],
                   choices: list[int | None]) -> Hypotheses | None:
        """The batch's mature gated (track, plot) pairs with their marginal probabilities; None when the
        batch has none."""
        pairs = _gated_pairs(rows, candidates)
        if pairs is None:
            return None
        slots, plot_rows, indices, prediction = pairs
        plots = tracks.plots
        innovation = plots.position[plot_rows] - prediction.positions[indices]
        inverse, determinant = inverse3(prediction.covariances[indices] + plots.covariance[plot_rows])
        distance = np.einsum("ni,nij,nj->n", innovation, inverse, innovation)
        log_likelihood = self.log_detected - 0.5 * (distance + np.log(determinant) + LOG_NORMALISER)
        track_slots, track = np.unique(slots, return_inverse=True)
        weights, missed = marginals(track, np.unique(plot_rows, return_inverse=True)[1], log_likelihood,
                                    self.log_missed, len(track_slots))
        reference = _references(track, weights, len(track_slots))
        chosen = _chosen_pairs(rows, candidates, choices)
        if chosen:  # a track chosen for a plot is updated at that plot's time
            pair = {key: k for k, key in enumerate(zip(slots.tolist(), plot_rows.tolist()))}
            at = np.array([pair[key] for key in chosen])
            reference[np.searchsorted(track_slots, slots[at])] = at
        return Hypotheses(track_slots, missed, track, plot_rows, weights, plot_rows[reference], indices[reference],
                          prediction)


def _gated_pairs(rows: range, candidates: list[Candidates]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, object] | None:
    """The mature (track, plot) pairs inside the gate, plot by plot: their slots, plot rows and rows of
    the batch's prediction, and that prediction (the one every candidate of a pairwise batch shares);
    None for none."""
    slots, plot_rows, indices, prediction = [], [], [], None
    for row, c in zip(rows, candidates):
        if c.prediction is None or not len(c.slots):
            continue
        if prediction is not None and c.prediction is not prediction:
            raise ValueError("JPDA needs one prediction per batch: compose it with pairwise roles")
        prediction = c.prediction
        index = c.first + np.cumsum(c.mature) - 1
        gated = c.mature & np.isfinite(c.errors)
        slots.append(c.slots[gated])
        plot_rows.append(np.full(np.count_nonzero(gated), row))
        indices.append(index[gated])
    if prediction is None or not sum(len(s) for s in slots):
        return None
    return np.concatenate(slots), np.concatenate(plot_rows), np.concatenate(indices), prediction


def marginals(track: np.ndarray, plot: np.ndarray, log_likelihood: np.ndarray, log_missed: float, tracks: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """The JPDA marginal probabilities of H (track, plot) hypotheses, each given by its track (H,) and
    plot (H,) numbers (from 0, no pair twice) and its log-likelihood ln L_ij (H,), with ln L_0 =
    `log_missed` for every track: each hypothesis's probability (H,) and each track's probability of
    none (T,). Exact: a cluster of tracks that share plots by EHM2, a track alone by the closed form."""
    scale = np.full(tracks, log_missed)  # each track's likelihoods over their largest: no overflow or underflow
    np.maximum.at(scale, track, log_likelihood)
    likelihood = np.exp(log_likelihood - scale[track])
    none = np.exp(log_missed - scale)
    total = none.copy()
    np.add.at(total, track, likelihood)
    weights, missed = likelihood / total[track], none / total
    plots = int(plot.max()) + 1
    if np.bincount(plot, minlength=plots).max() < 2:  # no plot shared: every track its own cluster
        return weights, missed
    graph = coo_matrix((np.ones(len(track)), (track, tracks + plot)), shape=(tracks + plots,) * 2)
    _, label = connected_components(graph, directed=False)
    cluster = label[:tracks]
    sizes = np.bincount(cluster)
    for number in np.flatnonzero(sizes > 1).tolist():
        members = np.flatnonzero(cluster == number)
        mine = np.flatnonzero(cluster[track] == number)
        own_track = np.searchsorted(members, track[mine])
        own_plots, own_plot = np.unique(plot[mine], return_inverse=True)
        valid = np.zeros((len(members), len(own_plots) + 1), dtype=np.int32)
        valid[:, 0] = 1
        valid[own_track, own_plot + 1] = 1
        matrix = np.zeros(valid.shape)
        matrix[:, 0] = none[members]
        matrix[own_track, own_plot + 1] = likelihood[mine]
        probability = EHM2().run(valid, matrix)
        missed[members] = probability[:, 0]
        weights[mine] = probability[own_track, own_plot + 1]
    return weights, missed


def _references(track: np.ndarray, weights: np.ndarray, tracks: int) -> np.ndarray:
    """Each track's most probable hypothesis (T,), the first of equals."""
    order = np.lexsort((-weights, track))
    first = np.concatenate([[True], track[order][1:] != track[order][:-1]])
    reference = np.empty(tracks, dtype=np.int64)
    reference[track[order][first]] = order[first]
    return reference


def _chosen_pairs(rows: range, candidates: list[Candidates], choices: list[int | None]) -> list[tuple[int, int]]:
    """The (slot, plot row) of each plot's chosen candidate that is mature."""
    return [(int(c.slots[choice]), row) for row, c, choice in zip(rows, candidates, choices)
            if choice is not None and c.mature[choice]]
