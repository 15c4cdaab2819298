"""JIPDA (joint integrated probabilistic data association) built from Stone Soup's parts.

Stone Soup 1.9 has JPDA (``JPDAwithEHM``: exact joint association probabilities by efficient
hypothesis management) but no track existence. JIPDA (Mušicki and Evans, *Joint Integrated
Probabilistic Data Association: JIPDA*, IEEE Trans. AES 40(3), 2004) adds to each track the
probability ``r`` that its target exists:

* prediction: ``r⁻ = p_s · r`` (eq. 7, Markov chain one of the paper's);
* association: JPDA over the tracks with each track's detection probability ``r⁻ · P_D``: a
  track misses with weight ``1 − P_D P_G r⁻`` and takes detection z with weight
  ``r⁻ · P_D · N(z; ẑ, S) / λ`` (Stone Soup's ``PDAHypothesiser`` with the existence factor put
  in), giving the marginal β₀ (no detection) and β_z;
* existence update (eq. 30): ``r = 1 − β₀ + β₀ · r⁻ (1 − P_D P_G) / (1 − P_D P_G r⁻)``;
* state: the Gaussian mixture of the prediction (weight β₀ r⁻ (1 − P_D P_G)/(1 − P_D P_G r⁻),
  the part of β₀ in which the target exists) and Stone Soup's Kalman updates (weights β_z),
  divided by ``r`` and reduced to one Gaussian (``gm_reduce_single``).

A detection that the tracks take with total probability below one half starts a tentative
track there (one-point initiation, velocity 0 with spread ``initial_speed``) with existence
``birth``. A track is confirmed (reported, and from then on under its own id) when ``r``
reaches ``confirm``, and removed when ``r`` falls below ``delete``.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2
from stonesoup.base import Property
from stonesoup.dataassociator.probability import JPDAwithEHM
from stonesoup.functions import gm_reduce_single
from stonesoup.hypothesiser.base import Hypothesiser
from stonesoup.hypothesiser.probability import PDAHypothesiser
from stonesoup.types.array import StateVectors
from stonesoup.types.numeric import Probability
from stonesoup.types.state import GaussianState
from stonesoup.types.track import Track
from stonesoup.types.update import GaussianStateUpdate

from peer_gating import GatedHypothesiser


class ExistenceHypothesiser(Hypothesiser):
    """Stone Soup's PDA hypotheses for one track, weighted by the track's predicted existence
    (JIPDA's association weights: miss ``1 − P_D P_G r⁻``, detection ``r⁻ P_D N / λ``)."""

    hypothesiser: Hypothesiser = Property(doc="PDA hypotheses (normalise=False), gated or not")
    detect: float = Property(doc="P_D · P_G of the PDA hypothesiser")
    existence: dict = Property(default=None, doc="track -> predicted existence r⁻ at this scan")

    def hypothesise(self, track, detections, timestamp, **kwargs):
        hypotheses = self.hypothesiser.hypothesise(track, detections, timestamp, **kwargs)
        r = self.existence[track]
        for hypothesis in hypotheses:
            if hypothesis:
                hypothesis.probability = hypothesis.probability * r
            else:
                hypothesis.probability = Probability(1.0 - self.detect * r)
        return hypotheses


class JIPDATracker:
    """JIPDA over scans of Stone Soup detections (see the module text). ``step`` returns the
    confirmed tracks' (id, x, y); ``existence`` maps every live track to its ``r``."""

    def __init__(self, predictor, updater, *, pd: float, clutter_density: float, gate: float = 0.99,
                 survival: float = 0.98, birth: float = 0.1, confirm: float = 0.9, delete: float = 0.05,
                 initial_speed: float = 1.5):
        pda = PDAHypothesiser(predictor=predictor, updater=updater, clutter_spatial_density=clutter_density,
                              prob_detect=Probability(pd), prob_gate=Probability(gate), normalise=False)
        gated = GatedHypothesiser(pda, predictor, 1.001 * chi2.ppf(gate, 2))  # the PDA gate, checked once
        self.hypothesiser = ExistenceHypothesiser(gated, pd * gate, existence={})
        self.associator = JPDAwithEHM(self.hypothesiser)
        self.updater = updater
        self.pd_pg = pd * gate
        self.survival, self.birth, self.confirm, self.delete = survival, birth, confirm, delete
        self.velocity_var = initial_speed ** 2
        self.existence: dict[Track, float] = {}
        self.confirmed: set[Track] = set()

    def step(self, when, detections) -> list[tuple[str, float, float]]:
        """One scan at ``when`` (datetime) with ``detections`` (set of Stone Soup Detections):
        the confirmed tracks' ids and positions (m)."""
        predicted = {track: self.survival * r for track, r in self.existence.items()}
        self.hypothesiser.existence = predicted
        associations = self.associator.associate(set(predicted), detections, when) if predicted else {}
        taken = {d: 0.0 for d in detections}
        for track, hypotheses in associations.items():
            r_pred = predicted[track]
            weights, states = [], []
            for hypothesis in hypotheses:
                beta = float(hypothesis.probability)
                if hypothesis:
                    taken[hypothesis.measurement] += beta
                    weights.append(beta)
                    states.append(self.updater.update(hypothesis))
                else:
                    weights.append(beta * r_pred * (1 - self.pd_pg) / (1 - self.pd_pg * r_pred))
                    states.append(hypothesis.prediction)
            r = float(np.clip(sum(weights), 0.0, 1.0))  # eq. (30)
            mean, covar = gm_reduce_single(StateVectors([s.state_vector for s in states]),
                                           np.stack([s.covar for s in states], axis=2),
                                           np.asarray(weights) / max(r, 1e-300))
            track.append(GaussianStateUpdate(mean, covar, hypotheses, when))
            self.existence[track] = r
        for track in [t for t, r in self.existence.items() if r < self.delete]:
            del self.existence[track]
            self.confirmed.discard(track)
        self.confirmed |= {t for t, r in self.existence.items() if r >= self.confirm}
        for detection, used in taken.items():
            if used < 0.5:
                self.existence[self._start(detection, when)] = self.birth
        return [(t.id, float(t.state_vector[0, 0]), float(t.state_vector[2, 0])) for t in self.confirmed]

    def _start(self, detection, when) -> Track:
        """A tentative track at ``detection`` (velocity 0 ± initial_speed per axis)."""
        x, y = np.asarray(detection.state_vector, dtype=float).ravel()
        cov = np.asarray(detection.measurement_model.covar(), dtype=float)
        covar = np.zeros((4, 4))
        covar[np.ix_((0, 2), (0, 2))] = cov
        covar[1, 1] = covar[3, 3] = self.velocity_var
        return Track([GaussianState(np.array([[x], [0.0], [y], [0.0]]), covar, timestamp=when)])
