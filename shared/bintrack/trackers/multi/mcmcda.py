"""Online Markov chain Monte Carlo data association (paper 004 §IV; Oh, Russell and Sastry,
"Markov chain Monte Carlo data association for multi-target tracking", IEEE TAC 54(3), 2009).

The state is a partition ω of the position reports of a sliding window of scans into tracks and
false alarms (paper 004 §II, conditions 1–5: a track has at most one report per scan and at
least two reports). Its posterior is eq. (3),

    P(ω|Y) ∝ P(Y|ω) ∏_t p_z^{z(t)} (1−p_z)^{c(t)} p_d^{d(t)} (1−p_d)^{g(t)} λ_b^{a(t)} λ_f^{f(t)},

with P(Y|ω) the product over tracks of the Kalman-filter innovation likelihoods of a constant-
velocity model (the first report of a new track is uniform over the region, which λ_b, a rate
per unit area, already accounts for). Because every term factors over tracks, the chain keeps
each track's log-score relative to leaving its reports as false alarms, and a move changes the
log-posterior by the change in the scores of the tracks it touches.

Moves (Oh et al. §IV-B): birth/death, split/merge, extension/reduction, track update and track
switch, chosen uniformly (birth only when there is no track); Metropolis–Hastings acceptance
eq. (5); the MAP is kept (Algorithm 1). The moves are in :mod:`.mcmcda_moves`.

Online (Oh et al. §IV-C): each scan the window slides; the chain starts from the previous MAP
with the new reports as false alarms. Reports that leave the window are fixed with their track:
the track's filtered state becomes its *anchor*, from which the track continues inside the
window, and whose identity it keeps (:mod:`.mcmcda_window`).

Identities are ours (Oh et al. leave output labels open): :mod:`.track_identity`. The Kalman
filter runs per axis: :mod:`.kalman_model`. The parameters: :mod:`.mcmcda_config`.

Real PIR sensors see motion, and a person standing still fades out. With ``still_misses`` (ours,
off by default) a track whose last report lies inside the sensor field may go on after a gap of
more than d̄ + 1 scans, as a target that stood still where it was last reported: the gap costs
log ``still_prior`` + (gap − 1) log(1 − ``still_pd``) in place of (gap − 1) log(1 − p_d), and the
next report is scored against the last position, spread by half ``still_reach``, with a velocity
drawn afresh (:meth:`ScanWindow._advance`).

Shared reports (copies the fusion makes for a track whose target hides in another's blob,
:mod:`bintrack.trackers.multi.target_fit`) are scored like any report, but no new track may begin with one.
``expected`` tells the fusion where the MAP's tracks expect their targets in the next scan.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import replace

from bintrack.bus_payloads import PositionReports, TrackSet
from bintrack.errors import TrackerConfigError
from bintrack.trackers.multi.mcmcda_checkpoint import upgrade_checkpoint
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.trackers.multi.mcmcda_moves import ChainMoves
from bintrack.trackers.multi.mcmcda_rates import RateEstimate
from bintrack.trackers.multi.mcmcda_window import Anchor, ChainTrack, Gate, ScanWindow, WindowReport
from bintrack.trackers.multi.track_identity import TrackIdentity


class OnlineMCMCDA(ScanWindow, ChainMoves, TrackIdentity):
    """Online MCMCDA over a sliding window of scans; ``step`` per scan gives the scan's tracks.

    Its parts, one module each, share this object's state: the window (:class:`ScanWindow`),
    the moves (:class:`ChainMoves`) and the identity policy (:class:`TrackIdentity`); here are
    the posterior's scores and the chain that runs the moves."""

    def __init__(self, config: MCMCDAConfig = MCMCDAConfig(), tracker_name: str = "mcmcda",
                 area: float | None = None, field_depth: Callable[[float, float], float] | None = None):
        """``area``: the field's area, units² (for ``config.adapt_rates``, which needs it);
        ``field_depth``: how far (units) a point lies inside the sensor field, negative outside
        (for ``config.exit_depth``; None: no field, tracks are coasted anywhere)."""
        self.config = config
        self.name = tracker_name
        self._rng = random.Random(config.seed)
        self._scans: deque[tuple[int, float, list[int]]] = deque()
        self._reports: dict[int, WindowReport] = {}
        self._gates: dict[int, Gate] = {}  # report → the reports that may follow it
        self._next_report = 0
        self._scan = -1
        self._tracks: list[ChainTrack] = []  # the current MAP
        self._owner: dict[int, int] = {}  # report → identity of the last labelled MAP track holding it
        # published identity → (its track's last report then (_end_of), t, state x, state y) when last shown
        self._last_seen: dict[int, tuple] = {}
        self._next_identity = 1
        self._log_lf = math.log(config.false_alarm_rate)
        self._log_lb = math.log(config.birth_rate)
        self._rates = None
        if config.adapt_rates:
            if not area or area <= 0:
                raise TrackerConfigError("MCMCDA adapt_rates needs the field's area")
            self._rates = RateEstimate(config.pd, config.false_alarm_rate, area, config.adapt_rates)
        self.field_depth = field_depth
        self.last_score = 0.0

    # the chain's scratch tables, made afresh for each scan's chain (_run_chain)
    _SCRATCH = ("_cache", "_filters", "_anchor_gates", "_latest", "_now")

    def __getstate__(self) -> dict:
        """For a checkpoint: the tracker without the chain's scratch tables."""
        return {k: v for k, v in self.__dict__.items() if k not in self._SCRATCH}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        upgrade_checkpoint(self)

    # ------------------------------------------------------------------ public

    def step(self, scan: PositionReports) -> TrackSet:
        """Take one scan's reports (event time ``scan.t``, s), slide the window, run n_mc MH
        iterations from the previous MAP and return the published tracks at ``scan.t``."""
        self._scan += 1
        ids = []
        for r in scan.reports:
            rid = self._next_report
            self._next_report += 1
            extra = self.config.extra_variance
            self._reports[rid] = WindowReport(self._scan, scan.t, r.x, r.y, max(r.cov[0][0] + extra, 1e-6),
                                         max(r.cov[1][1] + extra, 1e-6), r.shared, r.weight)
            ids.append(rid)
        self._scans.append((self._scan, scan.t, ids))
        while len(self._scans) > self.config.window:
            self._fix_oldest()
        if self._rates is not None:  # this scan's chain scores with the estimates (mcmcda_rates)
            self.config = replace(self.config, pd=self._rates.pd, false_alarm_rate=self._rates.false_alarm_rate)
            self._log_lf = math.log(self.config.false_alarm_rate)
        self._expire_anchors()
        self._add_gates(ids)
        self._run_chain()
        self._label()
        published = self._publish(scan.t)
        for track in self._tracks:
            if track.label is not None:
                self._owner.update(dict.fromkeys(track.reports, track.label))
        return published

    def skip(self, count: int) -> None:
        """``count`` scans were passed over (a long silence, ``MAX_SILENCE``): the next scan's
        number is that much further on, so no report can follow one from before the gap."""
        self._scan += count

    # ------------------------------------------------------------------ scoring

    def _score(self, track: ChainTrack) -> float:
        """log P contribution of ``track`` relative to its window reports being false alarms."""
        key = (id(track.anchor) if track.anchor else None, track.reports)
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        c = self.config
        if not self._shared_ok(track):
            self._cache[key] = -math.inf
            return -math.inf
        _, _, last_scan, _, score = self._filtered(track.anchor, track.reports)
        # after the last report: terminated at some scan up to now, or still alive undetected
        m = self._scan - last_scan
        if m > 0:
            alive = (1.0 - c.termination) * (1.0 - c.pd)
            score += math.log(c.termination * (1.0 - alive ** m) / (1.0 - alive) + alive ** m)
        self._cache[key] = score
        return score

    def _filtered(self, anchor: Anchor | None, reports: tuple[int, ...]):
        """The filter of a track with ``anchor`` after its window ``reports``: (state x, state y,
        scan and time of the last report, its score in ``_score`` before the term after that
        report). Memoised per prefix, as proposals mostly share their tracks' first reports."""
        key = (id(anchor) if anchor else None, reports)
        done = self._filters.get(key)
        if done is not None:
            return done
        c = self.config
        if not reports:
            done = anchor.x, anchor.y, anchor.scan, anchor.t, 0.0
        elif anchor is None and len(reports) == 1:
            rep = self._reports[reports[0]]
            sx, sy = self._initial(rep)
            # a new track's first report: a birth (λ_b, uniform position) that is detected
            done = sx, sy, rep.scan, rep.t, self._log_birth(rep) + math.log(c.pd) - self._log_lf
        else:
            sx, sy, last_scan, last_t, score = self._filtered(anchor, reports[:-1])
            rep = self._reports[reports[-1]]
            gap = rep.scan - last_scan
            sx, sy, log_n = self._advance(sx, sy, last_t, rep, last_scan)
            if gap > c.max_misses + 1:  # it stood still (still_misses), then walked on
                missed = math.log(c.still_prior) + (gap - 1) * math.log1p(-c.still_pd)
            else:
                missed = (gap - 1) * math.log1p(-c.pd)
            score += log_n + gap * math.log1p(-c.termination) + missed + math.log(c.pd) - self._log_lf
            done = sx, sy, rep.scan, rep.t, score
        self._filters[key] = done
        return done

    def _log_birth(self, rep: WindowReport) -> float:
        """log λ_b at a new track's first report: uniform, or (``birth_edge``) lower away from the
        room's doors (its walls, where the plan names no door)."""
        c = self.config
        if c.birth_edge is None or c.birth_area is None:
            return self._log_lb
        xmin, ymin, xmax, ymax = c.birth_area
        if c.birth_doors:
            near = min(math.hypot(rep.x - x, rep.y - y) for x, y in c.birth_doors)
        else:
            near = min(rep.x - xmin, xmax - rep.x, rep.y - ymin, ymax - rep.y)
        if near <= c.birth_edge:
            return self._log_lb
        return self._log_lb + math.log(c.birth_inside)

    def _shared_ok(self, track: ChainTrack) -> bool:
        """A new track may not begin with a shared report (a copy is no evidence of a target)."""
        return track.anchor is not None or not self._reports[track.reports[0]].shared

    # ------------------------------------------------------------------ chain

    def _run_chain(self) -> None:
        """``chains`` Metropolis–Hastings chains of n_mc iterations, each from the previous MAP
        (Algorithm 1 of Oh et al.), one after the other on the sampler's stream; the MAP over
        all of them is kept."""
        self._cache: dict = {}
        self._filters: dict = {}
        self._anchor_gates = {id(t.anchor): self._anchor_gate(t.anchor) for t in self._tracks if t.anchor is not None}
        self._latest = set(self._scans[-1][2])  # this scan's reports, which no track may begin with
        start = [ChainTrack(t.reports, t.anchor, t.label) for t in self._tracks]
        best, best_score = start, sum(self._score(t) for t in start)
        moves = (self._birth, self._death, self._split, self._merge, self._extension, self._reduction,
                 self._update, self._switch)
        birth, score_of, getrandbits, random_ = self._birth, self._score, self._rng.getrandbits, self._rng.random
        for _ in range(self.config.chains):
            self._now: dict = {}
            tracks = [ChainTrack(t.reports, t.anchor, t.label) for t in start]
            scores = [score_of(t) for t in tracks]  # in step with tracks
            used = {r for t in tracks for r in t.reports}
            free = {rid for _, _, ids in self._scans for rid in ids} - used
            score = sum(scores)
            for it in range(self.config.n_mc):
                if not tracks:
                    # only a birth can be proposed: if it has no report to begin with, or every
                    # report it may begin with has nothing to continue with, nothing can change
                    if not self._starts(free):
                        break
                    if self._stuck(free):
                        self._fail_births(free, self.config.n_mc - it)
                        break
                    move = birth
                else:
                    m = getrandbits(4)  # below(rng, 8) inline: the one draw of every iteration
                    while m >= 8:
                        m = getrandbits(4)
                    move = moves[m]
                proposal = move(tracks, free)
                if proposal is None:
                    continue
                removed, added, log_ratio = proposal
                added_scores = [score_of(t) for t in added]
                delta = sum(added_scores) - sum([scores[i] for i in removed])
                log_a = delta + log_ratio
                if log_a >= 0 or random_() < math.exp(log_a):
                    for i in sorted(removed, reverse=True):
                        free.update(tracks[i].reports)
                        del tracks[i], scores[i]
                    for t in added:
                        free.difference_update(t.reports)
                    tracks += added
                    scores += added_scores
                    score += delta
                    self._now = {}
                    if score > best_score + 1e-12:
                        best = [ChainTrack(t.reports, t.anchor, t.label) for t in tracks]
                        best_score = score
        self._tracks = best
        self.last_score = best_score

    def _stuck(self, free) -> bool:
        """With no track: True when no birth can be proposed, as no report a track may begin
        with has a free report in its gate at any scan an extension may reach (once per state)."""
        out = self._now.get("stuck")
        if out is None:
            out = self._now["stuck"] = not any(self._continuable(self._gates[first], free) for first in self._starts(free))
        return out

    def _fail_births(self, free, count: int) -> None:
        """Draw exactly what ``count`` births from a ``_stuck`` state draw: each a first report
        (``below(len(starts))``), then a gap (``below(span)``) at which it finds nothing. The
        state stays as it is; the stream ends where running the chain on would leave it."""
        starts = self._starts(free)
        getrandbits = self._rng.getrandbits
        n, k = len(starts), len(starts).bit_length()
        spans = [self._gaps(self._gates[first])[1] for first in starts]
        bits = [span.bit_length() for span in spans]
        for _ in range(count):
            i = getrandbits(k)
            while i >= n:
                i = getrandbits(k)
            span, b = spans[i], bits[i]
            if span >= 1:
                d = getrandbits(b)
                while d >= span:
                    d = getrandbits(b)
