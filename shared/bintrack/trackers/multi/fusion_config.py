"""Parameters of the grid fusion of paper 004 §III, shared by :mod:`.fusion` (the grid, the
clustering) and :mod:`.target_fit` (the fit of targets to a scan)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class FusionConfig:
    """Parameters of the grid fusion (paper 004 §III)."""

    cell: float | None = None
    """side of a grid cell, deployment units; default: an eighth of the smallest sensing range
    (1 m for the 8 m PIR sensors of paper 004)"""
    threshold: int = 3
    """n_d: detections a cell needs before its detection-likelihood is computed"""
    scan: float | None = None
    """scan period, s; default: the sensors' sampling period (0.5 s if they have none)"""
    owner_detects: bool = False
    """compute a cell only when the sensor it is assigned to detects itself (the paper's
    trigger); by default a sensor computes its cells whenever n_d covering sensors detect,
    which does not lose the cells of a sensor that missed the target (1 − pd of the time)"""
    full: bool = True
    """weight cells by eq. (4) in full (up to a common factor) rather than its detection part"""
    clustering: Literal["paper", "explain", "fit"] = "fit"
    """how a scan's detections become reports (see ``GridFusion.reports``)"""
    min_gain: float = 4.0
    """"fit": the least gain, nats of eq. (4)'s likelihood ratio, for which a new target is placed
    (or one target is split in two); 4 chosen on the tuning half of ``benchmarks/multi_target.py``"""
    expected_gain: float = 0.0
    """"fit": the least support, nats, for a target placed where a track expects one (0: the
    scan favours the target being there at least as much as not; chosen with ``multiplicity``
    on the tuning half of ``benchmarks/multi_target.py``, 1 before)"""
    expected_sigmas: float = 3.0
    """"fit": an expected target may sit within this many standard deviations of the prediction"""
    expected_split_gain: float = 3.5
    """"fit": the least gain, nats, for which a target placed where a track expects one is split
    in two, the track's target (still within its gate) and a new one; ``inf``: never (3.5 chosen
    with ``multiplicity`` on the tuning half of ``benchmarks/multi_target.py``, 4 before)"""
    evidence_reference: float | None = 1.7
    """"fit": nats. ``min_gain`` and ``expected_split_gain`` hold as they are for sensors whose
    evidence of a person per covering sensor, pd·log(pd/pfa) + (1 − pd)·log((1 − pd)/(1 − pfa))
    (the median over the sensors that state both), is at most this; for cleaner sensors both
    grow in proportion to it (:func:`.fusion.bar_scale`). A person then gives more evidence, and
    a fixed bar lets stray detections and split blobs through as new targets. 1.7 chosen on the
    tuning half of ``benchmarks/multi_target.py`` (paper 004's sensors, pd 0.7 and pfa 0.05,
    give 1.5); None: the bars in fixed nats"""
    multiplicity: bool = True
    """"fit": a sensor that n ≥ 1 targets cover detects with P_n = 1 − (1 − pd)^n, each target
    detected on its own (as the simulator draws them), rather than with pd however many cover
    it (eq. (4) over the union of the disks, False): a second target in an overlap gains
    log(P_2/P_1) per detection there and loses log(1 − pd) per miss, so two people in one blob
    are told from one (chosen on the tuning half of ``benchmarks/multi_target.py``)"""
    split: bool = True
    """"fit": try replacing each target by two"""
    shared: bool = True
    """"fit": copy a report for an established track hidden in another track's blob"""
    shared_speed: float = 0.0
    """the least difference in velocity, m/s (converted to the deployment's units), between the
    hidden track and the report's (0: none; two people walking side by side move alike)"""
    shared_age: int = 3
    """reports both tracks must have taken before a copy is made"""
    shared_unreported: int = 2
    """a copy is made for a track reported (or given a copy) within this many scans, counting the
    one being fused (1: in the previous scan); 2 chosen on the tuning half of
    ``benchmarks/multi_target.py``"""
    shared_chain: int | None = None
    """a copy is made only for a track with a report of its own (not a copy) within this many
    scans, counting the one being fused (at most MCMCDA's window); None: copies may follow
    copies without end (2–5 scans tried on the tuning half of ``benchmarks/multi_target.py``: no
    better)"""
    shared_support: float | None = -4.0
    """a copy is made only for a track whose target the scan's evidence does not rule out: its
    support given the targets placed (log Σ π e^gain over its gate, nats) is at least this. With
    ``multiplicity``, a second track on one person's blob pays log(1 − pd) for each of the blob's
    sensors that missed, so a duplicate track is not kept alive on copies of its twin's reports.
    None: no such bar (−4 the best of −1 … −8 on the tuning half of ``benchmarks/multi_target.py``,
    where it ties with none; it removes a duplicate track from the conditions' row of 2 people)"""
    shared_gap: float = 1.0
    """a copy is made when the hidden track's prediction is within this multiple of the
    sensing range of the report"""
    shared_edge: float = 0.5
    """no copy for a track predicted within this multiple of the sensing range of the edge of
    the sensor field (the sensors' convex hull): there a person with no support of their own
    has as likely left"""
    track_aided: bool = True
    """the MCMCDA tracker passes its tracks' expectations to the "fit" fusion"""
    soft_spread: float | None = None
    """real PIR: a "fit" target's report is its position's posterior under Gaussian footprints of
    σ = soft_spread × each sensor's range (:mod:`.soft_footprint`); None: under the disks (the
    paper's model)"""
    soft_count: float | None = None
    """real PIR: after the fit, a target stays only if its evidence given the other targets
    under Gaussian footprints of σ = soft_count × each sensor's range reaches ``min_gain`` (a
    new target) or ``expected_gain`` (a track's) (:meth:`.SoftFootprint.gains`); None: the
    disks alone count the targets"""
    count_switch: float | None = None
    """real PIR: a count of the people from how many sensors fire, filtered over the scans
    (:mod:`.firing_count`; someone comes or goes with this probability per scan). While it holds
    more people than the fit's targets and shared copies, that many more targets are sought
    (``count_threshold``, ``count_soft``). None: no count"""
    count_threshold: int = 1
    """n_d for a target the count asks for"""
    count_soft: float | None = None
    """a target the count asks for is kept only if its evidence given the others, under Gaussian
    footprints of σ = count_soft × each sensor's range (:meth:`.SoftFootprint.gains`), reaches
    ``min_gain``: a walker's far firings need no second person; None: no such check"""
    explained: float = 1.0
    """"explain": a report explains the detections of sensors within this multiple of their
    sensing range of it"""
