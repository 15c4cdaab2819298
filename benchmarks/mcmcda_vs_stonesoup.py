"""Our online MCMCDA (paper 004) against Stone Soup's GNN and JPDA trackers on the same reports.

Issue 6. For each dataset — the shipped ``darpa-grid-2`` and ``darpa-grid-3`` and a simulated
10-person DARPA grid with pfa raised to 0.1 (``bintrack simulate darpa-grid --people 10 --pfa 0.1
--seed N``) — our MCMCDA tracker (grid fusion + online MCMCDA, as ``bintrack track DIR --tracker
mcmcda`` makes it, defaults) runs once over the events; the fused ``PositionReports`` it
produced, scan by scan, then go unchanged into two Stone Soup multi-target trackers:

* **GNN**: ``DistanceHypothesiser`` (Mahalanobis gate) + ``GNNWith2DAssignment`` in a
  ``MultiTargetTracker``;
* **JPDA**: ``PDAHypothesiser`` + exact ``JPDA`` in a ``MultiTargetMixtureTracker`` (Stone
  Soup's tracker for mixture associators);

both with the *same* model as ours (taken from the ``MCMCDAConfig`` our tracker ran with):
constant velocity per axis with our white-acceleration spectral density q; as measurement noise
each report's own 2×2 covariance plus our ``extra_variance`` per axis (one ``LinearGaussian``
per detection; ours drops the off-diagonal term, Stone Soup keeps it); a new track's velocity
spread ``initial_speed``; for JPDA our pd and false-alarm density. Tracks are confirmed by a
``MultiMeasurementInitiator`` (tentative tracks associated by GNN) and deleted by an
``UpdateTimeStepsDeleter`` or a ``CovarianceBasedDeleter``. Stone Soup gets every scan, the
empty ones too, so its tracks coast and are deleted on the same clock as ours.

Stone Soup is tuned generously, on the very data it is scored on: for each dataset and
associator, every initiator ``min_points`` (2–6) × deleter (2, 3 or 5 consecutive missed scans,
or position-covariance trace > 20 m²) at the first gate (Mahalanobis 3 / P_G 0.99), then the
other gate (4 / 0.999) at the best of those — 21 settings — and the lowest mean GOSPA is
reported. A setting that needs over 60 s of tracking time is abandoned (exact JPDA is
exponential in the tracks sharing detections). Ours runs with its defaults throughout.

Scores (``bintrack.evaluation.metrics.multi_target_scores``, as ``bintrack eval``): at every scan from
the first person's entry to the last one's exit (as ``benchmarks/paper004.py``), including
scans where a tracker reports no track (all targets then count as missed),
GOSPA with c = 10 m, p = 2, α = 2 between the tracker's tracks and the targets existing at
that time; its localisation / missed / false parts (m²); mean |tracks − targets|; identity
switches (CLEAR MOT mismatches: a target's track id changing, where a target keeps its track
while that track stays within c). Time per scan is the wall time of the
tracking step alone (ours: ``OnlineMCMCDA.step`` replayed on the same reports; Stone Soup:
one tracker step), and for ours also fusion + MCMCDA (the whole tracker, events read
included), as a fraction of the 0.5 s scan period. Also writes a PNG of GOSPA and the number
of tracks per scan on darpa-grid-3.

Ours also runs with sampler seeds 0..N−1 (``--mcmc-seeds``, default 5; the table is seed 0, the
defaults), and the spread of its GOSPA and identity switches is printed: the chain's MAP moves
with the seed.

Needs the optional extra ``bench`` (Stone Soup): ``make bench`` installs it and runs this;
without it, exits 2 with a one-line message. 2–5 min on 2 shared cores (``--quick``: one
Stone Soup setting per associator, under 1 min). Progress on stderr, results on stdout.

Run: ``.venv/bin/python benchmarks/mcmcda_vs_stonesoup.py [--seed 10] [--quick] [--plot PNG]``
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import itertools
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench_support import DATASETS, DOCS, REPO, say

DEFAULT_PLOT = DOCS / "mcmcda_vs_stonesoup.png"
GOSPA_C, GOSPA_P = 10.0, 2.0  # m; α = 2 (bintrack.evaluation.metrics.gospa)
IDF1_HIT = 5.0  # m, the grid's spacing: how far a track may be from a person and count as theirs in IDF1
SIM_PEOPLE, SIM_PFA = 10, 0.1
EPOCH = datetime.datetime(2000, 1, 1)
SETTING_BUDGET = 60.0  # s of tracking time for one Stone Soup setting on one dataset


# --------------------------------------------------------------------------- data


@dataclass
class Case:
    """One dataset: its folder, the scans of fused reports and our tracks on them."""

    name: str
    path: Path
    paths: dict                      # target -> metrics.TruthPath
    reports: list = field(default_factory=list)   # our tracker's PositionReports per scan, in scan order
    plain_reports: list = field(default_factory=list)  # the same fusion without track aid (Stone Soup's input)
    ours: dict = field(default_factory=dict)      # scan t -> [(track, x, y)]
    ours_step_s: list = field(default_factory=list)
    tracker_s: float = 0.0           # whole MCMCDATracker over the dataset (fusion + MCMCDA)
    scan_period: float = 0.5
    config: object = None            # the MCMCDAConfig our tracker ran with (shared with Stone Soup)


@dataclass
class Result:
    """One tracker's tracks on one case: scan t -> [(track id, x, y)], and its step times (s)."""

    label: str
    setting: str
    tracks: dict
    step_s: list


@dataclass(frozen=True)
class Score:
    gospa: float
    localisation: float
    missed: float
    false: float
    count_error: float
    switches: int
    ms_per_scan: float
    series: tuple  # (times, GOSPA per scan, tracks per scan)
    idf1: float = math.nan  # IDF1 (motmetrics), a track within IDF1_HIT of a person may be theirs
    track_ids: int = 0      # distinct track ids reported over the scored scans


def simulate_case(seed: int, folder: Path) -> Path:
    """The 10-person grid with pfa 0.1 (``bintrack simulate darpa-grid --people 10 --pfa 0.1``)."""
    from bintrack.formats import write_dataset
    from bintrack.sim import simulate

    sim = simulate("darpa-grid", seed, people=SIM_PEOPLE, pfa=SIM_PFA)
    return write_dataset(folder, sim.deployment, sim.events, sim.truth)


def load_case(name: str, path: Path) -> Case:
    from bintrack.formats import read_truth
    from bintrack.evaluation.metrics import truth_paths

    return Case(name, path, truth_paths(read_truth(path / "truth.csv")))


# --------------------------------------------------------------------------- ours


def plain_reports(dataset, evidence_reference: float | None = None, multiplicity: bool = False) -> list:
    """Stone Soup's input on ``dataset``: the fusion's reports (``PositionReports`` per scan)
    without the track aid, which Stone Soup cannot give (so without the copies made for
    unresolved targets either), with the bars in fixed nats and targets counted over the union
    of the disks, as the peers were tuned on them (``evidence_reference``: bars that grow with
    the sensors' evidence, as ours, instead; ``multiplicity``: each target detected on its own,
    as ours now counts them, ``FusionConfig.multiplicity``)."""
    from bintrack.bus_payloads import PositionReports
    from bintrack.pipeline import run_tracker
    from bintrack.trackers.multi.fusion_config import FusionConfig
    from bintrack.trackers.multi.tracker import MCMCDATracker

    plain = MCMCDATracker(dataset.deployment, FusionConfig(track_aided=False, evidence_reference=evidence_reference,
                                                           multiplicity=multiplicity))
    return [out for out in run_tracker(dataset, plain) if isinstance(out, PositionReports)]


def run_ours(case: Case) -> None:
    """Run our MCMCDA tracker over the events once, keep its reports and tracks per scan, and
    time ``OnlineMCMCDA.step`` alone by replaying the same reports into a fresh instance (same
    config and seed, so it must give the same tracks)."""
    from bintrack.formats import open_dataset
    from bintrack.trackers.multi.mcmcda import OnlineMCMCDA
    from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
    from bintrack.bus_payloads import PositionReports, TrackSet
    from bintrack.pipeline import run_tracker
    from bintrack.trackers import make_tracker
    from bintrack.trackers.multi.tracker import MCMCDATracker

    dataset = open_dataset(case.path)
    try:  # as `bintrack track DIR --tracker mcmcda` makes it, with its defaults
        tracker = make_tracker("mcmcda", dataset.deployment)
    except (ValueError, TypeError):
        tracker = MCMCDATracker(dataset.deployment, config=MCMCDAConfig())
    config = case.config = tracker.mcmcda.config  # in the dataset's units
    tracksets = []
    start = time.perf_counter()
    for out in run_tracker(dataset, tracker):
        if isinstance(out, PositionReports):
            case.reports.append(out)
        elif isinstance(out, TrackSet):
            tracksets.append(out)
    case.tracker_s = time.perf_counter() - start
    if len(case.reports) > 1:
        case.scan_period = float(np.median(np.diff([r.t for r in case.reports])))

    case.plain_reports = plain_reports(dataset)

    online = OnlineMCMCDA(config, tracker.name)
    replayed = {}
    for reports in case.reports:
        start = time.perf_counter()
        out = online.step(reports)
        case.ours_step_s.append(time.perf_counter() - start)
        replayed[out.t] = [(k.track, k.x, k.y) for k in out.tracks]
    case.ours = {ts.t: [(k.track, k.x, k.y) for k in ts.tracks] for ts in tracksets}
    if case.ours != replayed:
        say(f"  note: {case.name}: OnlineMCMCDA replayed on the captured reports differs from the "
            f"tracker's own output; scoring the tracker's output")


def ours_over_seeds(case: Case, seeds: range) -> list[Score]:
    """Our tracker's scores with other seeds of its sampler (everything else at the defaults)."""
    from bintrack.formats import open_dataset
    from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
    from bintrack.bus_payloads import TrackSet
    from bintrack.pipeline import run_tracker
    from bintrack.trackers.multi.tracker import MCMCDATracker

    dataset = open_dataset(case.path)
    scores = []
    for seed in seeds:
        tracker = MCMCDATracker(dataset.deployment, config=MCMCDAConfig(seed=seed))
        tracks = {out.t: [(k.track, k.x, k.y) for k in out.tracks]
                  for out in run_tracker(dataset, tracker) if isinstance(out, TrackSet)}
        scores.append(score(tracks, case, []))
    return scores


# --------------------------------------------------------------------------- Stone Soup


@dataclass(frozen=True)
class Setting:
    """One Stone Soup configuration tried."""

    gate: float        # GNN: Mahalanobis missed_distance; JPDA: chi-square gate probability
    min_points: int    # MultiMeasurementInitiator: reports (its first included) needed to confirm
    deleter: str       # "steps:N" (UpdateTimeStepsDeleter) or "cov:T" (position-covariance trace, m²)
    process_noise: float | None = None  # q of its CV model, m²/s³; None: our MCMCDA's
    pd: float | None = None  # JPDA: detection probability of a report; None: our MCMCDA's

    def text(self, kind: str) -> str:
        gate = f"gate d_M<{self.gate:g}" if kind == "GNN" else f"P_G={self.gate:g}"
        kind_, value = self.deleter.split(":")
        deleter = (f"deleted at {value} consecutive missed scans" if kind_ == "steps"
                   else f"delete when pos. cov. trace > {value} m²")
        q = "" if self.process_noise is None else f", q {self.process_noise:g} m²/s³"
        pd = "" if self.pd is None else f", pd {self.pd:g}"
        return f"{gate}, confirmed at {self.min_points} reports, {deleter}{q}{pd}"


GATES = {"GNN": (3.0, 4.0), "JPDA": (0.99, 0.999)}  # Mahalanobis distance; PDA gate probability
MIN_POINTS = (2, 3, 4, 5, 6)
DELETERS = ("steps:2", "steps:3", "steps:5", "cov:20")
QUICK = {"GNN": Setting(3.0, 5, "steps:2"), "JPDA": Setting(0.99, 5, "steps:2")}


def tune(case: Case, kind: str, config, quick: bool, grid_scores: dict | None = None):
    """Stone Soup ``kind`` with the setting of lowest mean GOSPA on ``case``: first every
    initiator ``min_points`` × deleter at the first gate, then the other gates at the best of
    those (coordinate search). Returns (result, score, settings tried, settings abandoned);
    the scores of the first-stage grid (common to every dataset) go into ``grid_scores``."""
    def attempt(setting: Setting, i: int, n: int | str):
        say(f"  {case.name}: Stone Soup {kind} {i}/{n}: {setting.text(kind)}")
        result = run_stonesoup(case, kind, setting, config)
        if result is None:
            say(f"    abandoned: over {SETTING_BUDGET:g} s of tracking time")
            return None
        return result, score(result.tracks, case, result.step_s)

    if quick:
        settings = [QUICK[kind]]
    else:
        settings = [Setting(GATES[kind][0], m, d) for m, d in itertools.product(MIN_POINTS, DELETERS)]
    total = len(settings) + (0 if quick else len(GATES[kind]) - 1)
    tried = abandoned = 0
    best = None
    for setting in settings:
        tried += 1
        out = attempt(setting, tried, total)
        abandoned += out is None
        if grid_scores is not None:
            grid_scores[setting] = None if out is None else out[1]
        if out is not None and (best is None or out[1].gospa < best[1].gospa):
            best = out
    if not quick and best is not None:
        first = next(s for s in settings if s.text(kind) == best[0].setting)
        for gate in GATES[kind][1:]:
            tried += 1
            out = attempt(Setting(gate, first.min_points, first.deleter), tried, total)
            abandoned += out is None
            if out is not None and out[1].gospa < best[1].gospa:
                best = out
    if best is None:
        return None, None, tried, abandoned
    return best[0], best[1], tried, abandoned


def stonesoup_model(config, process_noise: float | None = None):
    """Stone Soup's version of our model: CV per axis with our q (or ``process_noise``, m²/s³)."""
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity

    q = float(config.process_noise if process_noise is None else process_noise)
    return CombinedLinearGaussianTransitionModel([ConstantVelocity(q), ConstantVelocity(q)])


def to_detections(reports, when: datetime.datetime, extra_variance: float) -> set:
    """Stone Soup detections of one scan: position (x, y) with the report's own covariance plus
    the variance our MCMCDA adds to every report (``MCMCDAConfig.extra_variance``)."""
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.detection import Detection

    detections = set()
    for r in reports.reports:
        cov = np.array(r.cov, dtype=float) + extra_variance * np.eye(2)
        model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=cov)
        detections.add(Detection(np.array([[r.x], [r.y]]), timestamp=when, measurement_model=model))
    return detections


def make_stonesoup(kind: str, setting: Setting, config, scans):
    """A Stone Soup MultiTargetTracker (GNN) or MultiTargetMixtureTracker (JPDA) over ``scans``
    (a list of (datetime, set of detections))."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDA
    from stonesoup.deleter.error import CovarianceBasedDeleter
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetMixtureTracker, MultiTargetTracker
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater

    predictor = KalmanPredictor(stonesoup_model(config, setting.process_noise))
    updater = KalmanUpdater(measurement_model=None)  # every detection brings its own
    if kind == "GNN":
        hypothesiser = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(),
                                            missed_distance=setting.gate)
        associator = GNNWith2DAssignment(hypothesiser)
        tracker_class = MultiTargetTracker
    else:
        hypothesiser = PDAHypothesiser(predictor=predictor, updater=updater,
                                       clutter_spatial_density=float(config.false_alarm_rate),
                                       prob_detect=float(config.pd if setting.pd is None else setting.pd),
                                       prob_gate=setting.gate)
        associator = JPDA(hypothesiser)
        tracker_class = MultiTargetMixtureTracker
    # The initiator's tentative tracks: associated by GNN (as in Stone Soup's tutorials), dropped
    # at their second consecutive missed scan; confirmed at ``min_points`` reports.
    init_hypothesiser = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(),
                                             missed_distance=setting.gate if kind == "GNN" else 3.0)
    v0 = float(config.initial_speed) ** 2  # our new-track velocity variance per axis
    prior = GaussianState(np.zeros((4, 1)), np.diag([0.0, v0, 0.0, v0]))
    initiator = MultiMeasurementInitiator(
        prior_state=prior, measurement_model=None, deleter=UpdateTimeStepsDeleter(2),
        data_associator=GNNWith2DAssignment(init_hypothesiser), updater=updater,
        min_points=setting.min_points)
    kind_, value = setting.deleter.split(":")
    if kind_ == "steps":
        deleter = UpdateTimeStepsDeleter(int(value))
    else:
        deleter = CovarianceBasedDeleter(covar_trace_thresh=float(value), mapping=[0, 2])
    return tracker_class(initiator=initiator, deleter=deleter, detector=ScanFeeder(scans),
                         data_associator=associator, updater=updater)


class ScanFeeder:
    """The detector Stone Soup trackers pull from: yields ``(time, set of detections)`` per scan
    and records when each scan was handed over (for the time per scan)."""

    def __init__(self, scans):
        self.scans = scans
        self.handed: list[float] = []

    def __iter__(self):
        for when, detections in self.scans:
            self.handed.append(time.perf_counter())
            yield when, detections


def run_stonesoup(case: Case, kind: str, setting: Setting, config, budget: float = SETTING_BUDGET) -> Result | None:
    """Stone Soup ``kind`` with ``setting`` over the case's reports; None when it needs more than
    ``budget`` s of tracking time (exhaustive JPDA is exponential in the tracks that share
    detections and can run away with many tentative tracks)."""
    extra = float(getattr(config, "extra_variance", 0.0))
    scans = []
    for r in case.plain_reports:
        when = EPOCH + datetime.timedelta(microseconds=round(r.t * 1e6))
        scans.append((when, to_detections(r, when, extra)))
    tracker = make_stonesoup(kind, setting, config, scans)
    feeder = tracker.detector
    ids: dict[str, int] = {}
    tracks: dict[float, list] = {}
    steps = []
    for reports, (when, current) in zip(case.plain_reports, tracker):
        steps.append(time.perf_counter() - feeder.handed[-1])
        if sum(steps) > budget:
            return None
        rows = []
        for track in current:
            if track.state.timestamp != when:  # not at this scan (cannot happen; be safe)
                continue
            number = ids.setdefault(track.id, len(ids) + 1)
            rows.append((number, float(track.state_vector[0, 0]), float(track.state_vector[2, 0])))
        tracks[reports.t] = rows
    return Result(kind, setting.text(kind), tracks, steps)


# --------------------------------------------------------------------------- scores


def score(tracks: dict, case: Case, step_s: list) -> Score:
    """``metrics.multi_target_scores`` (as ``bintrack eval``) at every scan of ``case`` from the
    first person's entry to the last one's exit (as ``benchmarks/paper004.py``), scans without
    a track included, IDF1 over the same scans (motmetrics, hit threshold ``IDF1_HIT``), the
    number of track ids, and the mean time per scan (over all scans)."""
    from bintrack.formats import TrackRow
    from bintrack.evaluation.clear_mot import Frame, clear_mot
    from bintrack.evaluation.metrics import multi_target_scores

    entry = min(p.start for p in case.paths.values())
    leave = max(p.end for p in case.paths.values())
    times = [r.t for r in case.reports if entry <= r.t <= leave]
    rows = [TrackRow(t, k, x, y) for t in times for k, x, y in tracks.get(t, [])]
    m = multi_target_scores(rows, case.paths, GOSPA_C, GOSPA_P, times=times)
    frames = []
    for t in times:
        present = [k for k, p in case.paths.items() if p.exists(t)]
        mine = tracks.get(t, [])
        frames.append(Frame(t, tuple(present), np.array([case.paths[k].position(t) for k in present]).reshape(-1, 2),
                            tuple(k for k, _, _ in mine), np.array([(x, y) for _, x, y in mine]).reshape(-1, 2)))
    idf1 = clear_mot(frames, IDF1_HIT, "hungarian").idf1
    return Score(m.gospa_mean, m.localisation_mean, m.missed_mean, m.false_mean, m.count_error_mean,
                 m.identity_switches, 1e3 * float(np.mean(step_s)) if step_s else math.nan,
                 (np.array([s.t for s in m.scans]), np.array([s.gospa.distance for s in m.scans]),
                  np.array([s.n_tracks for s in m.scans])), math.nan if idf1 is None else idf1,
                 len({r.track for r in rows}))


# --------------------------------------------------------------------------- printing


def table(case: Case, rows: list[tuple[str, Score]]) -> list[str]:
    ours = rows[0][1]
    head = (f"{'tracker':<8} {'GOSPA':>7} {'loc':>7} {'missed':>7} {'false':>7} {'|count err|':>11} "
            f"{'ID sw':>5} {'ms/scan':>8}  {'ours/this: GOSPA':>16} {'ms/scan':>7}")
    lines = [f"{case.name}: {len(case.paths)} targets, {len(case.reports)} scans of "
             f"{case.scan_period:g} s, {np.mean([len(r.reports) for r in case.reports]):.2f} reports/scan; "
             f"GOSPA c = {GOSPA_C:g} m, p = {GOSPA_P:g}, alpha = 2 (m; parts in m²) over the "
             f"{len(ours.series[0])} scans from the first entry to the last exit", head, "-" * len(head)]
    for label, s in rows:
        ratio = "" if s is ours else f"{ours.gospa / s.gospa:16.2f} {ours.ms_per_scan / s.ms_per_scan:7.2f}"
        lines.append(f"{label:<8} {s.gospa:7.2f} {s.localisation:7.2f} {s.missed:7.2f} {s.false:7.2f} "
                     f"{s.count_error:11.2f} {s.switches:5d} {s.ms_per_scan:8.2f}  {ratio}")
    return lines


def plot(case: Case, results: list[tuple[str, Score]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True,
                                      gridspec_kw={"height_ratios": [3, 1.4]})
    for label, s in results:
        t, d, n = s.series
        line, = top.plot(t, d, lw=1.2, label=f"{label} (mean {s.gospa:.2f} m, {s.switches} ID switches)")
        bottom.step(t, n, where="mid", lw=1.0, color=line.get_color(), alpha=0.8, label=f"{label} tracks")
    top.set_ylabel(f"GOSPA (c = {GOSPA_C:g} m, p = 2), m")
    top.set_title(f"{case.name}: GOSPA per scan, same fused reports into each tracker")
    top.set_ylim(0, 1.3 * max(float(s.series[1].max()) for _, s in results) + 0.5)
    top.legend(loc="upper right", fontsize="small")
    top.grid(alpha=0.3)
    t = results[0][1].series[0]
    bottom.step(t, [sum(bool(p.exists(x)) for p in case.paths.values()) for x in t], "k-", where="mid", lw=2.0,
                label="targets", zorder=0)
    bottom.set_ylabel("number")
    counts = max(max(int(s.series[2].max()) for _, s in results), len(case.paths))
    bottom.set_ylim(-0.2, counts + 1.8)
    bottom.legend(loc="upper right", fontsize="small", ncol=4)
    bottom.set_xlabel("t, s")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def common_setting(grids: dict, cases: list[Case]) -> list[str]:
    """Stone Soup with one setting for every dataset (less fitted to each): per associator, the
    first-stage setting with the lowest mean GOSPA averaged over the datasets."""
    lines = ["Stone Soup with ONE setting for all datasets (lowest GOSPA averaged over them; "
             "GOSPA m / ID switches, ours in brackets):"]
    for kind, per_case in grids.items():
        settings = [s for s in per_case[0] if s != "ours"
                    and all(isinstance(c.get(s), Score) for c in per_case)]
        if not settings:
            continue
        best = min(settings, key=lambda s: float(np.mean([c[s].gospa for c in per_case])))
        figures = "; ".join(f"{case.name} {c[best].gospa:.2f} / {c[best].switches} "
                            f"({c['ours'].gospa:.2f} / {c['ours'].switches})" for case, c in zip(cases, per_case))
        lines.append(f"  {kind}: {best.text(kind)}: {figures}")
    return lines


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=10, help="seed of the simulated 10-person grid (default 10; our sampler keeps its own default seed)")
    parser.add_argument("--quick", action="store_true",
                        help="one Stone Soup setting per associator instead of the tuning grid")
    parser.add_argument("--mcmc-seeds", type=int, default=5,
                        help="also run ours with sampler seeds 0..N-1 and print the spread (default 5)")
    parser.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help=f"PNG (default {DEFAULT_PLOT.relative_to(REPO)})")
    args = parser.parse_args(argv)

    if importlib.util.find_spec("stonesoup") is None:
        print("mcmcda_vs_stonesoup: Stone Soup is not installed (install with make bench)", file=sys.stderr)
        return 2

    verdicts = []
    grids: dict[str, list[dict]] = {"GNN": [], "JPDA": []}  # per kind, per case: setting -> Score
    with tempfile.TemporaryDirectory(prefix="bintrack-bench-") as tmp:
        say(f"simulating darpa-grid --people {SIM_PEOPLE} --pfa {SIM_PFA} --seed {args.seed}")
        sim_path = simulate_case(args.seed, Path(tmp) / "grid10")
        cases = [load_case("darpa-grid-2", DATASETS / "darpa-grid-2"),
                 load_case("darpa-grid-3", DATASETS / "darpa-grid-3"),
                 load_case(f"grid-10 (pfa {SIM_PFA:g}, seed {args.seed})", sim_path)]
        for case in cases:
            say(f"{case.name}: our MCMCDA tracker (fusion + online MCMCDA)")
            run_ours(case)
            config = case.config
            if case is cases[0]:
                print(f"Shared model (our MCMCDAConfig defaults): constant velocity per axis, q = "
                      f"{config.process_noise:g} m²/s³; measurement noise = each report's covariance + "
                      f"{getattr(config, 'extra_variance', 0.0):g} m² per axis; new-track velocity sd "
                      f"{config.initial_speed:g} m/s; JPDA: pd {config.pd:g}, clutter density "
                      f"{config.false_alarm_rate:g} /m² per scan.\n", flush=True)
            rows = [("MCMCDA", score(case.ours, case, case.ours_step_s))]
            chosen = {}
            for kind in ("GNN", "JPDA"):
                grids[kind].append({})
                result, best, tried, abandoned = tune(case, kind, config, args.quick, grids[kind][-1])
                if result is None:
                    print(f"mcmcda_vs_stonesoup: every Stone Soup {kind} setting ran over its time budget "
                          f"on {case.name}", file=sys.stderr)
                    return 1
                rows.append((kind, best))
                grids[kind][-1]["ours"] = rows[0][1]
                chosen[kind] = (result.setting, tried, abandoned)
            lines = table(case, rows)
            for kind, (text, tried, abandoned) in chosen.items():
                lines.append(f"  {kind}: best of {tried} settings tried{f' ({abandoned} abandoned as too slow)' if abandoned else ''}: {text}")
            if case is cases[-1]:
                mean_step = float(np.mean(case.ours_step_s))
                whole = case.tracker_s / max(len(case.reports), 1)
                lines.append(f"  MCMCDA time per scan with {SIM_PEOPLE} people (window {config.window} scans, "
                             f"n_mc {config.n_mc}): step {1e3 * mean_step:.1f} ms = "
                             f"{mean_step / case.scan_period:.3f} of the {case.scan_period:g} s scan period "
                             f"(p95 {np.percentile(case.ours_step_s, 95) / case.scan_period:.3f}, max "
                             f"{max(case.ours_step_s) / case.scan_period:.3f}); fusion + MCMCDA "
                             f"{1e3 * whole:.1f} ms = {whole / case.scan_period:.3f} (below 1: real time)")
            if case.name == "darpa-grid-3":
                plot(case, rows, args.plot)
                lines.append(f"  plot: {args.plot}")
            print("\n".join(lines) + "\n", flush=True)
            ours, theirs = rows[0][1], [s for _, s in rows[1:]]
            verdict = (f"  {case.name}: lower mean GOSPA than GNN and JPDA: "
                       f"{'yes' if all(ours.gospa < s.gospa for s in theirs) else 'no'}; "
                       f"fewer identity switches: {'yes' if all(ours.switches < s.switches for s in theirs) else 'no'}")
            if args.mcmc_seeds > 1:
                say(f"{case.name}: ours with sampler seeds 1..{args.mcmc_seeds - 1}")
                spread = [ours] + ours_over_seeds(case, range(1, args.mcmc_seeds))  # seed 0: the table's run
                g = [s.gospa for s in spread]
                k = [s.switches for s in spread]
                print(f"  MCMCDA over sampler seeds 0..{args.mcmc_seeds - 1}: GOSPA mean {np.mean(g):.2f} "
                      f"(min {min(g):.2f}, max {max(g):.2f}); ID switches mean {np.mean(k):.1f} "
                      f"(min {min(k)}, max {max(k)})\n", flush=True)
                verdict += (f"; over {args.mcmc_seeds} seeds, GOSPA below both in {sum(x < min(s.gospa for s in theirs) for x in g)} "
                            f"(mean {'below' if np.mean(g) < min(s.gospa for s in theirs) else 'not below'}), "
                            f"fewer switches in {sum(x < min(s.switches for s in theirs) for x in k)}")
            verdicts.append(verdict)
    against = "Stone Soup with one untuned setting (--quick)" if args.quick else "the best Stone Soup settings"
    print(f"MCMCDA against {against}:\n" + "\n".join(verdicts), flush=True)
    if not args.quick:
        print("\n" + "\n".join(common_setting(grids, cases)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
