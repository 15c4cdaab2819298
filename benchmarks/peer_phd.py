"""A GM-PHD filter with labels from Stone Soup's parts.

Vo and Ma, *The Gaussian mixture probability hypothesis density filter*, IEEE Trans. Signal
Processing 54(11), 2006, as Stone Soup 1.9 builds it: ``GaussianMixtureHypothesiser`` over a
``DistanceHypothesiser`` (every component against every detection), ``PHDUpdater`` (P_D,
clutter density, survival) and ``GaussianMixtureReducer`` (prune, merge), run by
``PointProcessMultiTargetTracker`` with a birth component. Components are
``TaggedWeightedGaussianState``: a component born from a detection gets a new tag and its
descendants keep it, so a tag is a track's label. At each scan the tracks reported are the
labels whose component weighs at least ``extract`` (one estimate per label: the reducer
merges a label's components, keeping the heaviest one's tag).

The birth intensity is one wide Gaussian over the field (centre, standard deviation half the
field's side, velocity spread ``initial_speed``) of weight ``birth`` targets per scan. A
gate of squared Mahalanobis distance 18.4 (P 0.9999) drops the far pairs before Stone Soup
scores them (``peer_gating.GatedHypothesiser``), which leaves the PHD's weights as they were
to within e⁻⁹.
"""

from __future__ import annotations

import numpy as np
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
from stonesoup.measures import Mahalanobis
from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
from stonesoup.tracker.pointprocess import PointProcessMultiTargetTracker
from stonesoup.types.numeric import Probability
from stonesoup.types.state import TaggedWeightedGaussianState
from stonesoup.updater.pointprocess import PHDUpdater

from peer_gating import GatedHypothesiser

FAR = 18.4  # chi-square, 2 degrees of freedom, P = 0.9999


class _Scans:
    """The detector the Stone Soup tracker pulls from: one scan handed in at a time."""

    def __init__(self):
        self.scan = None

    def __iter__(self):
        while True:
            yield self.scan


class PHDTracker:
    """GM-PHD with labels (see the module text); ``step`` returns (label, x, y) of the
    components of weight ≥ ``extract``."""

    def __init__(self, predictor, updater, *, pd: float, clutter_density: float, field: tuple,
                 birth: float = 0.05, survival: float = 0.99, extract: float = 0.5, merge: float = 4.0,
                 prune: float = 1e-5, initial_speed: float = 1.5):
        distance = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=np.sqrt(FAR),
                                        include_all=True)
        hypothesiser = GaussianMixtureHypothesiser(GatedHypothesiser(distance, predictor, FAR),
                                                   order_by_detection=True)
        phd = PHDUpdater(updater, clutter_spatial_density=clutter_density, prob_detection=Probability(pd),
                         prob_survival=Probability(survival))
        reducer = GaussianMixtureReducer(prune_threshold=prune, pruning=True, merge_threshold=merge, merging=True)
        xmin, ymin, xmax, ymax = field
        half = max(xmax - xmin, ymax - ymin) / 2
        born = TaggedWeightedGaussianState(
            np.array([[(xmin + xmax) / 2], [0.0], [(ymin + ymax) / 2], [0.0]]),
            np.diag([half ** 2, initial_speed ** 2, half ** 2, initial_speed ** 2]),
            weight=Probability(birth), tag=TaggedWeightedGaussianState.BIRTH)
        self.scans = _Scans()
        self.tracker = iter(PointProcessMultiTargetTracker(
            detector=self.scans, updater=phd, hypothesiser=hypothesiser, reducer=reducer,
            extraction_threshold=extract, birth_component=born))
        self.extract = extract

    def step(self, when, detections) -> list[tuple[str, float, float]]:
        """One scan at ``when`` (datetime) with ``detections`` (set of Stone Soup Detections)."""
        self.scans.scan = (when, set(detections))
        _, tracks = next(self.tracker)
        rows = []
        for track in tracks:
            state = track.state
            if state.timestamp == when and float(state.weight) >= self.extract:
                rows.append((str(state.tag), float(state.state_vector[0, 0]), float(state.state_vector[2, 0])))
        return rows
