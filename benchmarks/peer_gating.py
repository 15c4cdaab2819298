"""A cheap gate in front of a Stone Soup hypothesiser, for the peers of ``benchmarks/multi_target.py``.

Stone Soup's ``PDAHypothesiser`` and ``DistanceHypothesiser`` predict the track once per
detection and score every detection; the kd-tree gate Stone Soup has
(``DetectionKDTreeMixIn``) needs one measurement model for all detections, and each of our
fused reports carries its own covariance. ``GatedHypothesiser`` predicts once, drops the
detections whose squared Mahalanobis distance to the predicted position (innovation
covariance: the prediction's position block plus the detection's own noise) exceeds
``limit``, and hands the rest to the wrapped hypothesiser. With ``limit`` at or above the
wrapped hypothesiser's own gate the hypotheses it returns are the same.
"""

from __future__ import annotations

import numpy as np
from stonesoup.base import Property
from stonesoup.hypothesiser.base import Hypothesiser
from stonesoup.predictor import Predictor

POSITION = (0, 2)  # x, y in the constant-velocity state (x, vx, y, vy)


class GatedHypothesiser(Hypothesiser):
    """``hypothesiser`` on the detections within squared Mahalanobis distance ``limit``."""

    hypothesiser: Hypothesiser = Property(doc="the hypothesiser that scores what passes")
    predictor: Predictor = Property(doc="predicts the track to the scan")
    limit: float = Property(doc="squared Mahalanobis distance (2 degrees of freedom)")

    def hypothesise(self, track, detections, timestamp, **kwargs):
        return self.hypothesiser.hypothesise(track, self.near(track, detections, timestamp), timestamp, **kwargs)

    def near(self, track, detections, timestamp) -> set:
        """The detections within the gate of ``track`` predicted to ``timestamp``."""
        detections = list(detections)
        if not detections:
            return set()
        prediction = self.predictor.predict(track, timestamp=timestamp)
        mean = np.asarray(prediction.state_vector, dtype=float)[POSITION, 0]
        covar = np.asarray(prediction.covar, dtype=float)[np.ix_(POSITION, POSITION)]
        z = np.array([np.asarray(d.state_vector, dtype=float).ravel() for d in detections]) - mean
        s = covar + np.array([d.measurement_model.covar() for d in detections], dtype=float)
        d2 = np.einsum("ni,nij,nj->n", z, np.linalg.inv(s), z)
        return {d for d, q in zip(detections, d2) if q <= self.limit}
