"""Multi-frame assignment (MFA) over an N-scan window: Stone Soup's ``MFADataAssociator`` with
track initiation and deletion around it.

Stone Soup 1.9's MFA (``stonesoup.dataassociator.mfa``, Xia, Granström, Svensson,
García-Fernández and Williams, *Multiscan implementation of the trajectory Poisson
multi-Bernoulli mixture filter*, J. Adv. Information Fusion 14(2), 2019) keeps, per track, a
Gaussian mixture whose components are the track's measurement histories over the last
``window`` scans (``MFAHypothesiser`` over a ``PDAHypothesiser``: weights P_D N(z)/λ against
1 − P_D P_G), solves the multi-scan assignment by Lagrangian relaxation (``ortools``) and
prunes every history that disagrees with the best one ``window`` scans back. It has no track
management; here, as in Stone Soup's example, a track's state is a ``GaussianMixtureUpdate``
of Kalman updates, and around it:

* initiation: Stone Soup's ``MultiMeasurementInitiator`` (tentative tracks by GNN, confirmed at
  ``min_points`` reports) on the detections that no kept history of any track takes now;
* a track's estimate: its heaviest component;
* deletion: once its heaviest component has missed ``misses`` consecutive scans.

Every history the n-scan pruning keeps stays: keeping only a track's heaviest few can drop the
one the global assignment chose, and Stone Soup's solver then finds no feasible assignment.
Where it finds none all the same it raises ``RuntimeError`` (``run_peer`` counts the setting
as abandoned on that grid).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.stats import chi2
from stonesoup.dataassociator.mfa import MFADataAssociator
from stonesoup.hypothesiser.mfa import MFAHypothesiser
from stonesoup.hypothesiser.probability import PDAHypothesiser
from stonesoup.types.mixture import GaussianMixture
from stonesoup.types.numeric import Probability
from stonesoup.types.state import TaggedWeightedGaussianState
from stonesoup.types.track import Track
from stonesoup.types.update import GaussianMixtureUpdate

from peer_gating import GatedHypothesiser


class MFATracker:
    """MFA with the track management of the module text; ``step`` returns (id, x, y) of the
    tracks."""

    def __init__(self, predictor, updater, initiator, *, pd: float, clutter_density: float, gate: float = 0.99,
                 window: int = 3, misses: int = 3):
        pda = PDAHypothesiser(predictor=predictor, updater=updater, clutter_spatial_density=clutter_density,
                              prob_detect=Probability(pd), prob_gate=Probability(gate))
        gated = GatedHypothesiser(pda, predictor, 1.001 * chi2.ppf(gate, 2))  # the PDA gate, checked once
        self.associator = MFADataAssociator(MFAHypothesiser(gated), slide_window=window)
        self.updater, self.initiator = updater, initiator
        self.misses = misses
        self.tracks: set[Track] = set()

    def step(self, when, detections) -> list[tuple[str, float, float]]:
        """One scan at ``when`` (datetime) with ``detections`` (set of Stone Soup Detections)."""
        order = tuple(detections)  # the associator numbers detections by their place in this tuple
        taken = set()
        with warnings.catch_warnings():  # its note that it solves the whole problem when the parts do not fit
            warnings.simplefilter("ignore", UserWarning)
            associations = self.associator.associate(self.tracks, order, when)
        for track, hypotheses in associations.items():
            parts = [self.updater.update(h) if h else h.prediction for h in hypotheses]
            for h in hypotheses:
                if h:
                    taken.add(h.measurement)
            track.append(GaussianMixtureUpdate(components=parts, hypothesis=hypotheses))
        for track in [t for t in self.tracks if self._missed(t)]:
            self.tracks.discard(track)
        for track in self.initiator.initiate(set(detections) - taken, when):
            component = TaggedWeightedGaussianState(track.state_vector, track.covar, timestamp=when,
                                                    weight=Probability(1), tag=[])
            self.tracks.add(Track([GaussianMixture([component])], id=track.id))
        return [(t.id, *self._position(t)) for t in self.tracks]

    @staticmethod
    def _best(track: Track):
        return max(track.state.components, key=lambda c: float(c.weight))

    def _missed(self, track: Track) -> bool:
        """Its heaviest history ends in ``misses`` scans without a detection (index 0)."""
        tag = self._best(track).tag
        return len(tag) >= self.misses and not any(tag[-self.misses:])

    def _position(self, track: Track) -> tuple[float, float]:
        best = np.asarray(self._best(track).state_vector, dtype=float)
        return float(best[0, 0]), float(best[2, 0])
