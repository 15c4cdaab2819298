"""The peers of ``benchmarks/multi_target.py`` beyond GNN and JPDA (issue 42): JIPDA
(``peer_jipda``), MFA (``peer_mfa``) and a labelled GM-PHD (``peer_phd``), their settings, how
each is tuned, and one run over a case's fused reports.

Every peer gets what GNN and JPDA get (``mcmcda_vs_stonesoup``): our fusion's reports without
the track aid, one Stone Soup detection per report with the report's covariance plus our
extra variance, and our constant-velocity model (q, new-track velocity spread); the clutter
density is our MCMCDA's false-report density. Each is tuned on the tuning half by coordinate
search (``STAGES``): a first grid that always includes the detection probability the peer
assumes for a fused report (P_D ∈ ``PD_GRID``), then one parameter at a time from the best so far.
"""

from __future__ import annotations

import datetime
import time
from dataclasses import dataclass, fields

import numpy as np

import mcmcda_vs_stonesoup as vs

PEERS = ("JIPDA", "MFA", "PHD")
PD_GRID = (0.5, 0.6, 0.7, 0.85)   # P_D of a fused report, assumed by the peer
Q_GRID = (0.01, 0.05, 0.1)        # m²/s³, besides ours (0.02)


@dataclass(frozen=True)
class PeerSetting:
    """One setting of a peer; None: not used by that peer (or ours, for ``process_noise``)."""

    pd: float
    gate: float = 0.99                   # JIPDA, MFA: PDA gate probability P_G
    confirm: float | None = None         # JIPDA: existence that confirms a track
    delete: float | None = None          # JIPDA: existence below which a track goes
    birth: float | None = None           # JIPDA: a new track's existence; PHD: births per scan
    survival: float | None = None        # JIPDA, PHD: p_s per scan
    window: int | None = None            # MFA: N-scan window
    min_points: int | None = None        # MFA: reports that confirm a tentative track
    misses: int | None = None            # MFA: consecutive missed scans that delete a track
    extract: float | None = None         # PHD: component weight reported as a target
    merge: float | None = None           # PHD: squared Mahalanobis distance that merges components
    process_noise: float | None = None   # q, m²/s³; None: our MCMCDA's

    def text(self, kind: str) -> str:
        return ", ".join(f"{f.name} {getattr(self, f.name):g}" for f in fields(self)
                         if getattr(self, f.name) is not None and not (f.name == "gate" and kind == "PHD"))


FIRST = {
    "JIPDA": [PeerSetting(pd, confirm=c, delete=0.05, birth=0.1, survival=0.98) for pd in PD_GRID for c in (0.9, 0.99)],
    "MFA": [PeerSetting(pd, window=3, min_points=m, misses=3) for pd in PD_GRID for m in (2, 3)],
    "PHD": [PeerSetting(pd, birth=b, survival=0.99, extract=0.5, merge=4.0) for pd in PD_GRID for b in (0.01, 0.05)],
}
STAGES = {  # (label, field, values tried from the best so far), in order
    "JIPDA": [("deletion", "delete", (0.01, 0.1)), ("birth existence", "birth", (0.02, 0.05, 0.2)),
              ("survival", "survival", (0.95, 0.995)), ("gate", "gate", (0.999,)),
              ("process noise", "process_noise", Q_GRID)],
    "MFA": [("window", "window", (4, 5)), ("deletion", "misses", (2, 5)), ("gate", "gate", (0.999,)),
            ("process noise", "process_noise", Q_GRID)],
    "PHD": [("extraction", "extract", (0.3, 0.7)), ("merging", "merge", (1.0, 16.0)),
            ("survival", "survival", (0.95, 0.999)), ("process noise", "process_noise", Q_GRID)],
}
QUICK = {"JIPDA": [PeerSetting(0.7, confirm=0.9, delete=0.05, birth=0.1, survival=0.98)],
         "MFA": [PeerSetting(0.7, window=3, min_points=3, misses=3)],
         "PHD": [PeerSetting(0.7, birth=0.05, survival=0.99, extract=0.5, merge=4.0)]}


def make_peer(kind: str, setting: PeerSetting, config, field: tuple):
    """The peer's tracker (``step(when, detections) -> [(id, x, y)]``) with ``setting`` and our
    model from ``config`` (an ``MCMCDAConfig`` in the dataset's units); ``field`` is
    (xmin, ymin, xmax, ymax) of the deployment's region (the PHD's birth)."""
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.updater.kalman import KalmanUpdater

    predictor = KalmanPredictor(vs.stonesoup_model(config, setting.process_noise))
    updater = KalmanUpdater(measurement_model=None)  # every detection brings its own
    clutter = float(config.false_alarm_rate)
    if kind == "JIPDA":
        from peer_jipda import JIPDATracker
        return JIPDATracker(predictor, updater, pd=setting.pd, clutter_density=clutter, gate=setting.gate,
                            survival=setting.survival, birth=setting.birth, confirm=setting.confirm,
                            delete=setting.delete, initial_speed=float(config.initial_speed))
    if kind == "MFA":
        from peer_mfa import MFATracker
        return MFATracker(predictor, updater, _initiator(predictor, updater, config, setting.min_points),
                          pd=setting.pd, clutter_density=clutter, gate=setting.gate, window=setting.window,
                          misses=setting.misses)
    if kind == "PHD":
        from peer_phd import PHDTracker
        return PHDTracker(predictor, updater, pd=setting.pd, clutter_density=clutter, field=field,
                          birth=setting.birth, survival=setting.survival, extract=setting.extract,
                          merge=setting.merge, initial_speed=float(config.initial_speed))
    raise ValueError(f"unknown peer {kind!r} (expected one of {', '.join(PEERS)})")


def _initiator(predictor, updater, config, min_points: int):
    """Tentative tracks as GNN and JPDA get them (``mcmcda_vs_stonesoup.make_stonesoup``)."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.types.state import GaussianState

    v0 = float(config.initial_speed) ** 2
    hypothesiser = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=3.0)
    return MultiMeasurementInitiator(
        prior_state=GaussianState(np.zeros((4, 1)), np.diag([0.0, v0, 0.0, v0])), measurement_model=None,
        deleter=UpdateTimeStepsDeleter(2), data_associator=GNNWith2DAssignment(hypothesiser), updater=updater,
        min_points=min_points)


def run_peer(case: vs.Case, kind: str, setting: PeerSetting, field: tuple,
             budget: float = vs.SETTING_BUDGET) -> vs.Result | None:
    """The peer over the case's reports without track aid (as ``vs.run_stonesoup``); None when
    it needs more than ``budget`` s of tracking time, or when Stone Soup's MFA finds no feasible
    assignment (its ``RuntimeError``)."""
    extra = float(getattr(case.config, "extra_variance", 0.0))
    tracker = make_peer(kind, setting, case.config, field)
    ids: dict[str, int] = {}
    tracks: dict[float, list] = {}
    steps = []
    for reports in case.plain_reports:
        when = vs.EPOCH + datetime.timedelta(microseconds=round(reports.t * 1e6))
        detections = vs.to_detections(reports, when, extra)
        start = time.perf_counter()
        try:
            rows = tracker.step(when, detections)
        except RuntimeError:
            return None
        steps.append(time.perf_counter() - start)
        if sum(steps) > budget:
            return None
        tracks[reports.t] = [(ids.setdefault(key, len(ids) + 1), x, y) for key, x, y in rows]
    return vs.Result(kind, setting.text(kind), tracks, steps)
