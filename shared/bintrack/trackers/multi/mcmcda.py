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
eq. (5); the MAP is kept (Algorithm 1). Extension proposals grow a track forward: choose a gap
d ∈ 1..d̄+1 scans uniformly, then a false alarm within the gate at that scan uniformly, and stop
with probability γ. Proposal probabilities enter the acceptance ratio; the probability that an
extension stops because no candidate lies in the gate is neglected (it is small next to γ).

Online (Oh et al. §IV-C): each scan the window slides; the chain starts from the previous MAP
with the new reports as false alarms. Reports that leave the window are fixed with their track:
the track's filtered state becomes its *anchor*, from which the track continues inside the
window, and whose identity it keeps.

Identities (ours; Oh et al. leave output labels open). A track without an anchor takes the
identity that most of its reports were last published under; failing that, it gets one when it
is first published (below). The chain often re-explains a target's last few reports as a new
track while the old one stays in the MAP, unreported; a scan or two later it joins them again.
So a track without an identity does not get published while a track with one, unreported for
more than ``coast`` and at most d̄ scans, could be its target: the newcomer is within
``gate_sigmas`` σ of where the old track predicts it (σ² the two position variances summed), or
its first report lies in the old track's gate. The old track is shown instead, predicted. If it
stays unreported for over d̄ scans it can no longer continue, and the newcomer inherits its
identity. And a track published for the first time takes the identity of the nearest published
track that has ended (left the MAP) whose last report its first one could follow, if any: the
chain found a new target more likely than a long gap, but for the user it is most likely the
same person. Failing that, it is re-identified: it takes the identity of the track last shown at
most ``reidentify`` s before, and before its first report, whose Kalman prediction that report
fits best within ``gate_sigmas`` (a person lost for longer than d̄ scans, in clutter or beside
someone else). Else it gets a fresh identity.

Shared reports (copies the fusion makes for a track whose target hides in another's blob,
:mod:`bintrack.trackers.multi.target_fit`) are scored like any report, but no new track may begin with one.
``expected`` tells the fusion where the MAP's tracks expect their targets in the next scan.

The Kalman filter runs per axis (x and y independent: constant velocity with white-acceleration
spectral density q, measurement variance the report covariance's diagonal), which keeps the
chain's inner loop in scalar arithmetic; the report covariance's off-diagonal term is dropped.
"""

from __future__ import annotations

import math
import random
from bisect import bisect_right
from collections import deque
from dataclasses import dataclass, replace

from bintrack.messages import PositionReports, Track, TrackSet
from bintrack.trackers.multi.target_fit import Expectation

_LOG_2PI = math.log(2.0 * math.pi)
_MISSING = object()


@dataclass(frozen=True)
class MCMCDAConfig:
    """Parameters of the model (eq. 3, Kalman filter) and of the online sampler.

    Lengths are in the reports' units; the defaults are for metres (people walking through PIR
    sensors of about 8 m range), and :meth:`in_units` converts them to other units."""

    window: int = 5
    """sliding-window length, scans"""
    n_mc: int = 500
    """Metropolis–Hastings iterations per scan and chain"""
    chains: int = 4
    """chains per scan, each of n_mc iterations from the previous MAP; the MAP over them is kept
    (4 chosen on the tuning half of ``benchmarks/multi_target.py``: fewer identity switches and
    half the seed spread of one chain; it takes about 4 × one chain's time)"""
    seed: int = 0
    """seed of the sampler's random stream"""
    process_noise: float = 0.02
    """q: white-acceleration spectral density of the constant-velocity model, units²/s³ (0.02
    chosen on the tuning half of ``benchmarks/multi_target.py``: people walk with few sharp
    turns; it was 0.1)"""
    extra_variance: float = 4.0
    """added to each report's variance per axis, units² (a cluster's spread understates the
    error of its centre)"""
    initial_speed: float = 1.5
    """standard deviation of a new track's velocity per axis, units/s"""
    pd: float = 0.85
    """probability that a present target yields a report in a scan"""
    false_alarm_rate: float = 3e-4
    """λ_f: false reports per unit area per scan"""
    birth_rate: float = 1e-4
    """λ_b: new targets per unit area per scan"""
    termination: float = 0.05
    """p_z: probability that a target disappears between scans"""
    max_speed: float = 3.0
    """v̄: fastest target, units/s (gates which reports may follow each other in a track)"""
    gate_sigmas: float = 3.0
    """added to v̄·Δt in that gate: this many standard deviations of the two positions' noise"""
    max_misses: int = 3
    """d̄: consecutive scans a track may go unreported"""
    stop: float = 0.3
    """γ: probability that an extension proposal stops after each added report"""
    min_reports: int = 2
    """reports a track needs (fixed and in the window) before it is published"""
    coast: int = 1
    """scans a published track is predicted past its last report before it is dropped"""
    reidentify: float = 8.0
    """s: a new track takes the identity of a track last shown at most this long ago (and
    before its first report), if that report lies within ``gate_sigmas`` of the old track's
    prediction"""
    birth_edge: float | None = None
    """real PIR: people are born within this distance (units) of ``birth_area``'s edge (the
    room's doors are on its walls); None: anywhere (the paper's uniform birth)"""
    birth_area: tuple[float, float, float, float] | None = None
    """xmin, ymin, xmax, ymax (units) of the room for ``birth_edge``; None: no room"""
    birth_inside: float = 0.1
    """λ_b farther than ``birth_edge`` from the edge, as a fraction of λ_b near it"""

    def in_units(self, metres_per_unit: float) -> MCMCDAConfig:
        """This configuration, read as metres and seconds, in units of ``metres_per_unit`` m:
        speeds and the report variance scale by 1/metres_per_unit (squared for variances and
        q), and the rates per unit area by metres_per_unit²."""
        k = 1.0 / metres_per_unit
        return replace(self, process_noise=self.process_noise * k * k, extra_variance=self.extra_variance * k * k,
                       initial_speed=self.initial_speed * k, max_speed=self.max_speed * k,
                       false_alarm_rate=self.false_alarm_rate / (k * k), birth_rate=self.birth_rate / (k * k),
                       birth_edge=None if self.birth_edge is None else self.birth_edge * k,
                       birth_area=None if self.birth_area is None else tuple(v * k for v in self.birth_area))

    def __post_init__(self):
        checks = [("window", self.window >= 2), ("n_mc", self.n_mc >= 1), ("chains", self.chains >= 1), ("max_misses", self.max_misses >= 0),
                  ("pd", 0 < self.pd < 1), ("termination", 0 < self.termination < 1), ("stop", 0 < self.stop < 1),
                  ("false_alarm_rate", self.false_alarm_rate > 0), ("birth_rate", self.birth_rate > 0),
                  ("max_speed", self.max_speed > 0), ("initial_speed", self.initial_speed > 0),
                  ("process_noise", self.process_noise > 0), ("extra_variance", self.extra_variance >= 0),
                  ("gate_sigmas", self.gate_sigmas > 0), ("coast", self.coast >= 0), ("reidentify", self.reidentify >= 0), ("min_reports", self.min_reports >= 2)]
        bad = [name for name, ok in checks if not ok]
        if bad:
            raise ValueError(f"MCMCDA parameter out of range: {', '.join(f'{n}={getattr(self, n)}' for n in bad)}")


@dataclass
class Anchor:
    """The fixed part of a track: its identity and per-axis filtered state at its last fixed report."""

    identity: int
    scan: int
    t: float
    x: tuple[float, float, float, float, float]  # p, v, P_pp, P_pv, P_vv of axis x
    y: tuple[float, float, float, float, float]
    reports: int


@dataclass(slots=True)
class _Report:
    scan: int
    t: float
    x: float
    y: float
    rx: float
    ry: float
    shared: bool = False


def _predict(state, dt: float, q: float):
    p, v, ppp, ppv, pvv = state
    return (p + v * dt, v,
            ppp + 2 * dt * ppv + dt * dt * pvv + q * dt ** 3 / 3.0,
            ppv + dt * pvv + q * dt * dt / 2.0,
            pvv + q * dt)


def _update(state, z: float, r: float):
    """Kalman update of one axis with measurement z (variance r); returns (state, log N(ν; 0, S))."""
    p, v, ppp, ppv, pvv = state
    s = ppp + r
    nu = z - p
    kp, kv = ppp / s, ppv / s
    new = (p + kp * nu, v + kv * nu, ppp - kp * ppp, ppv - kp * ppv, pvv - kv * ppv)
    return new, -0.5 * (_LOG_2PI + math.log(s) + nu * nu / s)


class _Gate:
    """The window's reports that may follow one report or anchor in a track (``_follows``):
    ``at[k]`` those of scan k in report order, ``all`` all of them. Which reports may follow
    which depends only on the two and the configuration, so the chain looks it up here."""

    __slots__ = ("scan", "at", "all")

    def __init__(self, scan: int):
        self.scan = scan
        self.at: dict[int, list[int]] = {}
        self.all: set[int] = set()

    def add(self, scan: int, rids: list[int]) -> None:
        if rids:
            self.at[scan] = rids
            self.all.update(rids)


def _below(rng: random.Random, n: int) -> int:
    """``rng.randrange(n)`` for ``n`` ≥ 1 with the same draws (CPython's ``_randbelow``), without
    its argument checks: the moves draw a few numbers each, and randrange's frames showed."""
    getrandbits = rng.getrandbits
    k = n.bit_length()
    r = getrandbits(k)
    while r >= n:
        r = getrandbits(k)
    return r


@dataclass(slots=True)
class _Track:
    reports: tuple[int, ...]
    anchor: Anchor | None = None
    label: int | None = None


class OnlineMCMCDA:
    """Online MCMCDA over a sliding window of scans; ``step`` per scan gives the scan's tracks."""

    def __init__(self, config: MCMCDAConfig = MCMCDAConfig(), tracker_name: str = "mcmcda"):
        self.config = config
        self.name = tracker_name
        self._rng = random.Random(config.seed)
        self._scans: deque[tuple[int, float, list[int]]] = deque()
        self._reports: dict[int, _Report] = {}
        self._gates: dict[int, _Gate] = {}  # report → the reports that may follow it
        self._next_report = 0
        self._scan = -1
        self._tracks: list[_Track] = []  # the current MAP
        self._owner: dict[int, int] = {}  # report → identity of the last labelled MAP track holding it
        # published identity → (its track's last report then (_end_of), t, state x, state y) when last shown
        self._last_seen: dict[int, tuple] = {}
        self._next_identity = 1
        self._log_lf = math.log(config.false_alarm_rate)
        self._log_lb = math.log(config.birth_rate)
        self.last_score = 0.0

    # the chain's scratch tables, made afresh for each scan's chain (_run_chain)
    _SCRATCH = ("_cache", "_filters", "_anchor_gates", "_latest", "_now")

    def __getstate__(self) -> dict:
        """For a checkpoint: the tracker without the chain's scratch tables."""
        return {k: v for k, v in self.__dict__.items() if k not in self._SCRATCH}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if "_gates" not in state:  # a checkpoint taken before the gate tables: make them from the window
            self.__dict__.pop("_by_scan", None)
            self._gates, now = {}, self._scan
            for k, _, ids in self._scans:
                self._scan = k
                self._add_gates(ids)
            self._scan = now

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
            self._reports[rid] = _Report(self._scan, scan.t, r.x, r.y, max(r.cov[0][0] + extra, 1e-6),
                                         max(r.cov[1][1] + extra, 1e-6), r.shared)
            ids.append(rid)
        self._scans.append((self._scan, scan.t, ids))
        while len(self._scans) > self.config.window:
            self._fix_oldest()
        self._expire_anchors()
        self._add_gates(ids)
        self._run_chain()
        self._label()
        published = self._publish(scan.t)
        for track in self._tracks:
            if track.label is not None:
                self._owner.update(dict.fromkeys(track.reports, track.label))
        return published

    # ------------------------------------------------------------------ window

    def _fix_oldest(self) -> None:
        k, t, ids = self._scans.popleft()
        gone = set(ids)
        for track in self._tracks:
            fixed = [r for r in track.reports if r in gone]
            if not fixed:
                continue
            rid = fixed[0]
            rep = self._reports[rid]
            if track.label is None:
                track.label = self._new_identity()
            if track.anchor is None:
                ax, ay = self._initial(rep)
                track.anchor = Anchor(track.label, k, t, ax, ay, 1)
            else:
                a = track.anchor
                sx, sy, _ = self._advance(a.x, a.y, a.t, rep)
                track.anchor = Anchor(a.identity, k, t, sx, sy, a.reports + 1)
            track.reports = tuple(r for r in track.reports if r != rid)
        for rid in ids:
            del self._reports[rid]
            del self._gates[rid]
            self._owner.pop(rid, None)

    def _expire_anchors(self) -> None:
        keep = []
        for track in self._tracks:
            if not track.reports and (track.anchor is None or self._scan - track.anchor.scan > self.config.max_misses + 1):
                continue
            if track.anchor is None and len(track.reports) < 2:
                continue
            keep.append(track)
        self._tracks = keep

    def _new_identity(self) -> int:
        identity = self._next_identity
        self._next_identity += 1
        return identity

    def _initial(self, rep: _Report):
        v0 = self.config.initial_speed ** 2
        return (rep.x, 0.0, rep.rx, 0.0, v0), (rep.y, 0.0, rep.ry, 0.0, v0)

    # ------------------------------------------------------------------ scoring

    def _advance(self, sx, sy, t: float, rep: _Report):
        """Predict the per-axis states from time ``t`` (s) to ``rep``'s and update them with it:
        (state x, state y, log-likelihood of the innovations)."""
        q = self.config.process_noise
        sx, lx = _update(_predict(sx, rep.t - t, q), rep.x, rep.rx)
        sy, ly = _update(_predict(sy, rep.t - t, q), rep.y, rep.ry)
        return sx, sy, lx + ly

    def _start(self, track: _Track):
        """The track's filter before its remaining window reports: (state x, state y, scan and
        time of the last report taken, reports taken, reports still to take)."""
        reps = [self._reports[r] for r in track.reports]
        if track.anchor is not None:
            a = track.anchor
            return a.x, a.y, a.scan, a.t, a.reports, reps
        sx, sy = self._initial(reps[0])
        return sx, sy, reps[0].scan, reps[0].t, 1, reps[1:]

    def _score(self, track: _Track) -> float:
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
            sx, sy, log_n = self._advance(sx, sy, last_t, rep)
            score += log_n + gap * math.log1p(-c.termination) + (gap - 1) * math.log1p(-c.pd) + math.log(c.pd) - self._log_lf
            done = sx, sy, rep.scan, rep.t, score
        self._filters[key] = done
        return done

    def _log_birth(self, rep: _Report) -> float:
        """log λ_b at a new track's first report: uniform, or (``birth_edge``) lower inside the room."""
        c = self.config
        if c.birth_edge is None or c.birth_area is None:
            return self._log_lb
        xmin, ymin, xmax, ymax = c.birth_area
        if min(rep.x - xmin, xmax - rep.x, rep.y - ymin, ymax - rep.y) <= c.birth_edge:
            return self._log_lb
        return self._log_lb + math.log(c.birth_inside)

    def _shared_ok(self, track: _Track) -> bool:
        """A new track may not begin with a shared report (a copy is no evidence of a target)."""
        return track.anchor is not None or not self._reports[track.reports[0]].shared

    # ------------------------------------------------------------------ gate

    def _follows(self, a_scan: int, a_t: float, ax: float, ay: float, a_var: float, rid: int) -> bool:
        rep = self._reports[rid]
        gap = rep.scan - a_scan
        if gap < 1 or gap > self.config.max_misses + 1:
            return False
        reach = self.config.max_speed * (rep.t - a_t) + self.config.gate_sigmas * math.sqrt(a_var + max(rep.rx, rep.ry))
        return (rep.x - ax) ** 2 + (rep.y - ay) ** 2 <= reach * reach

    def _add_gates(self, ids: list[int]) -> None:
        """Gates for the new scan's reports ``ids``, which join the gates of the reports they may follow."""
        for rid, gate in self._gates.items():
            rep = self._reports[rid]
            gate.add(self._scan, [r for r in ids if self._follows(rep.scan, rep.t, rep.x, rep.y, max(rep.rx, rep.ry), r)])
        for rid in ids:
            self._gates[rid] = _Gate(self._scan)

    def _anchor_gate(self, a: Anchor) -> _Gate:
        gate = _Gate(a.scan)
        end = (a.scan, a.t, a.x[0], a.y[0], max(a.x[2], a.y[2]))
        for k, _, ids in self._scans:
            gate.add(k, [r for r in ids if self._follows(*end, r)])
        return gate

    def _gate(self, track: _Track) -> _Gate:
        """The gate of the track's last report, or of its anchor if it has none."""
        if track.reports:
            return self._gates[track.reports[-1]]
        return self._anchor_gates[id(track.anchor)]

    def _end_of(self, track: _Track) -> tuple[int, float, float, float, float] | None:
        """(scan, t, x, y, position variance) of the track's last report or anchor."""
        if track.reports:
            rep = self._reports[track.reports[-1]]
            return rep.scan, rep.t, rep.x, rep.y, max(rep.rx, rep.ry)
        if track.anchor is not None:
            a = track.anchor
            return a.scan, a.t, a.x[0], a.y[0], max(a.x[2], a.y[2])
        return None

    def _valid(self, track: _Track) -> bool:
        if track.anchor is None:
            if len(track.reports) < 2:
                return False
            gate, rest = self._gates[track.reports[0]], track.reports[1:]
        else:
            gate, rest = self._anchor_gates[id(track.anchor)], track.reports
        for rid in rest:
            if rid not in gate.all:
                return False
            gate = self._gates[rid]
        return True

    # ------------------------------------------------------------------ proposals

    def _extend(self, gate: _Gate, free: set[int], must: bool) -> tuple[list[int], float]:
        """Grow a path forward from the report or anchor of ``gate`` through reports of ``free``;
        (added, log q). ``must``: the first report may not be skipped by the stop draw (a birth
        needs two)."""
        c = self.config
        rng, gates = self._rng, self._gates
        added: list[int] = []
        logq = 0.0
        while True:
            if (added or not must) and rng.random() < c.stop:
                return added, logq + math.log(c.stop)
            span = min(c.max_misses + 1, self._scan - gate.scan)  # _span, inline in the chain's hottest loop
            if span < 1:
                return added, logq
            d = 1 + _below(rng, span)  # randint(1, span)
            # candidates lie after every report added so far, so none of those is among them
            cands = [r for r in gate.at.get(gate.scan + d, ()) if r in free]
            if not cands:
                return added, logq + math.log(1.0 / span)
            rid = cands[_below(rng, len(cands))]
            logq += -math.log(span) - math.log(len(cands)) + (math.log1p(-c.stop) if (added or not must) else 0.0)
            added.append(rid)
            gate = gates[rid]

    def _path_logq(self, gate: _Gate, path: list[int], free: set[int], must: bool) -> float:
        """log q of ``_extend`` proposing exactly ``path`` from ``gate``'s report or anchor (then stopping)."""
        c = self.config
        gates = self._gates
        logq = 0.0
        for i, rid in enumerate(path):
            span = self._span(gate)
            if span < 1 or rid not in gate.all or rid not in free:
                return -math.inf
            after = gates[rid]
            cands = len(free.intersection(gate.at[after.scan]))
            logq += -math.log(span) - math.log(cands) + (math.log1p(-c.stop) if (i or not must) else 0.0)
            gate = after
        return logq + (math.log(c.stop) if self._span(gate) >= 1 else 0.0)

    # ------------------------------------------------------------------ chain

    def _run_chain(self) -> None:
        """``chains`` Metropolis–Hastings chains of n_mc iterations, each from the previous MAP
        (Algorithm 1 of Oh et al.), one after the other on the sampler's stream; the MAP over
        all of them is kept."""
        self._cache: dict = {}
        self._filters: dict = {}
        self._anchor_gates = {id(t.anchor): self._anchor_gate(t.anchor) for t in self._tracks if t.anchor is not None}
        self._latest = set(self._scans[-1][2])  # this scan's reports, which no track may begin with
        start = [_Track(t.reports, t.anchor, t.label) for t in self._tracks]
        best, best_score = start, sum(self._score(t) for t in start)
        moves = (self._birth, self._death, self._split, self._merge, self._extension, self._reduction,
                 self._update, self._switch)
        birth, score_of, getrandbits, random_ = self._birth, self._score, self._rng.getrandbits, self._rng.random
        for _ in range(self.config.chains):
            self._now: dict = {}
            tracks = [_Track(t.reports, t.anchor, t.label) for t in start]
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
                    m = getrandbits(4)  # _below(rng, 8) inline: the one draw of every iteration
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
                        best = [_Track(t.reports, t.anchor, t.label) for t in tracks]
                        best_score = score
        self._tracks = best
        self.last_score = best_score

    def _ratio_k(self, k_before: int, k_after: int, forward_q: float, reverse_q: float) -> float:
        # ξ is uniform over the eight moves whenever there is a track; birth only when none
        xi_f = 1.0 if k_before == 0 else 1.0 / 8
        xi_r = 1.0 if k_after == 0 else 1.0 / 8
        return math.log(xi_r) + reverse_q - math.log(xi_f) - forward_q

    # Most proposals are rejected (over 95 %), so the chain's state (its tracks and free reports)
    # rarely changes: what the moves derive from it alone, including a proposal once its random
    # draws are made, is kept in self._now, which _run_chain empties when the state changes.

    def _once(self, key, make, *args):
        """``make(*args)``, computed once per state of the chain under ``key``."""
        out = self._now.get(key, _MISSING)
        if out is _MISSING:
            out = self._now[key] = make(*args)
        return out

    def _starts(self, free):
        """The free reports a new track may begin with, in order (once per state of the chain;
        not through _once: a birth asks for them at nearly every iteration of an empty state)."""
        out = self._now.get("starts")
        if out is None:
            out = self._now["starts"] = sorted(free.difference(self._latest))
        return out

    def _stuck(self, free) -> bool:
        """With no track: True when no birth can be proposed, as no report a track may begin
        with has a free report in its gate at any scan an extension may reach (once per state)."""
        out = self._now.get("stuck")
        if out is None:
            out = self._now["stuck"] = not any(self._continuable(self._gates[first], free) for first in self._starts(free))
        return out

    def _continuable(self, gate: _Gate, free) -> bool:
        """Whether ``_extend`` from ``gate`` finds a free report at some gap it may draw."""
        return any(r in free for d in range(1, self._span(gate) + 1) for r in gate.at.get(gate.scan + d, ()))

    def _span(self, gate: _Gate) -> int:
        """How many scans after ``gate``'s an extension from it may reach in the window."""
        return min(self.config.max_misses + 1, self._scan - gate.scan)

    def _fail_births(self, free, count: int) -> None:
        """Draw exactly what ``count`` births from a ``_stuck`` state draw: each a first report
        (``_below(len(starts))``), then a gap (``_below(span)``) at which it finds nothing. The
        state stays as it is; the stream ends where running the chain on would leave it."""
        starts = self._starts(free)
        getrandbits = self._rng.getrandbits
        n, k = len(starts), len(starts).bit_length()
        spans = [self._span(self._gates[first]) for first in starts]
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

    def _mortal(self, tracks):
        """Indices of the tracks without an anchor, which a death may remove."""
        return self._once("mortal", lambda: [i for i, t in enumerate(tracks) if t.anchor is None])

    @staticmethod
    def _can_split(t: _Track) -> bool:
        return len(t.reports) >= (2 if t.anchor is not None else 4)

    def _splittable(self, tracks):
        """Indices of the tracks a split may cut."""
        return self._once("splittable", lambda: [i for i, t in enumerate(tracks) if self._can_split(t)])

    def _mergeable(self, tracks):
        """(i, j) pairs, in order, where track j (no anchor) may continue track i."""
        return self._once("mergeable", self._merge_pairs, tracks)

    def _merge_pairs(self, tracks):
        heads = [(j, b.reports[0]) for j, b in enumerate(tracks) if b.anchor is None]
        pairs = []
        for i, a in enumerate(tracks):
            follow = self._gate(a).all
            pairs += [(i, j) for j, first in heads if first in follow and i != j]
        return pairs

    def _merges(self, tracks) -> int:
        """How many pairs ``_mergeable`` would list for ``tracks``, a proposed state (a track's
        first report never follows its own last one, so i ≠ j needs no test)."""
        firsts = {b.reports[0] for b in tracks if b.anchor is None}
        if not firsts:
            return 0
        return sum(len(firsts.intersection(self._gate(a).all)) for a in tracks)

    def _birth(self, tracks, free):
        starts = self._starts(free)
        if not starts:
            return None
        first = starts[_below(self._rng, len(starts))]
        rest, logq = self._extend(self._gates[first], free, must=True)
        if not rest:
            return None
        new = _Track((first, *rest))
        deaths = len(self._mortal(tracks)) + 1
        return [], [new], self._ratio_k(len(tracks), len(tracks) + 1, -math.log(len(starts)) + logq, -math.log(deaths))

    def _death(self, tracks, free):
        mortal = self._mortal(tracks)
        if not mortal:
            return None
        i = mortal[_below(self._rng, len(mortal))]
        return self._once(("death", i), self._death_of, tracks, free, i)

    def _death_of(self, tracks, free, i: int):
        t = tracks[i]
        freed = free.union(t.reports)
        starts = len(self._starts(free)) + len(t.reports) - len(self._latest.intersection(t.reports))
        reverse = -math.log(starts) + self._path_logq(self._gates[t.reports[0]], t.reports[1:], freed, True)
        return [i], [], self._ratio_k(len(tracks), len(tracks) - 1, -math.log(len(self._mortal(tracks))), reverse)

    def _split(self, tracks, free):
        choices = self._splittable(tracks)
        if not choices:
            return None
        i = choices[_below(self._rng, len(choices))]
        t = tracks[i]
        lo = 0 if t.anchor is not None else 2
        points = range(lo, len(t.reports) - 1)  # first part keeps reports[:r]
        r = points[_below(self._rng, len(points))]
        return self._once(("split", i, r), self._split_at, tracks, i, r, len(points))

    def _split_at(self, tracks, i: int, r: int, points: int):
        t = tracks[i]
        head, tail = _Track(t.reports[:r], t.anchor, t.label), _Track(t.reports[r:])
        merges = self._merges(tracks[:i] + tracks[i + 1:] + [head, tail])
        forward = -math.log(len(self._splittable(tracks))) - math.log(points)
        return [i], [head, tail], self._ratio_k(len(tracks), len(tracks) + 1, forward, -math.log(max(merges, 1)))

    def _merge(self, tracks, free):
        pairs = self._mergeable(tracks)
        if not pairs:
            return None
        i, j = pairs[_below(self._rng, len(pairs))]
        return self._once(("merge", i, j), self._merged, tracks, i, j)

    def _merged(self, tracks, i: int, j: int):
        a, b = tracks[i], tracks[j]
        merged = _Track(a.reports + b.reports, a.anchor, a.label)
        splits = len(self._splittable(tracks)) - self._can_split(a) - self._can_split(b) + self._can_split(merged)
        lo = 0 if merged.anchor is not None else 2
        reverse = -math.log(max(splits, 1)) - math.log(max(len(merged.reports) - 1 - lo, 1))
        return [i, j], [merged], self._ratio_k(len(tracks), len(tracks) - 1, -math.log(len(self._mergeable(tracks))), reverse)

    def _extension(self, tracks, free):
        i = _below(self._rng, len(tracks))
        t = tracks[i]
        added, logq = self._extend(self._gate(t), free, must=True)
        if not added:
            return None
        new = _Track(t.reports + tuple(added), t.anchor, t.label)
        lo = 0 if new.anchor is not None else 2
        reverse = -math.log(len(tracks)) - math.log(len(new.reports) - lo)
        return [i], [new], self._ratio_k(len(tracks), len(tracks), -math.log(len(tracks)) + logq, reverse)

    def _cut(self, tracks, keep: int):
        """A random track and a random cut in its window reports, leaving at least ``keep`` of
        them before the cut when it has no anchor: (index, cut), or None."""
        i = _below(self._rng, len(tracks))
        t = tracks[i]
        lo = 0 if t.anchor is not None else keep
        if len(t.reports) <= lo:
            return None
        return i, lo + _below(self._rng, len(t.reports) - lo)

    def _reduction(self, tracks, free):
        cut = self._cut(tracks, keep=2)
        if cut is None:
            return None
        return self._once(("reduction", *cut), self._reduced, tracks, free, *cut)

    def _reduced(self, tracks, free, i: int, r: int):
        t = tracks[i]
        lo = 0 if t.anchor is not None else 2
        new = _Track(t.reports[:r], t.anchor, t.label)
        freed = free.union(t.reports[r:])
        reverse = -math.log(len(tracks)) + self._path_logq(self._gate(new), t.reports[r:], freed, True)
        return [i], [new], self._ratio_k(len(tracks), len(tracks), -math.log(len(tracks)) - math.log(len(t.reports) - lo), reverse)

    def _update(self, tracks, free):
        cut = self._cut(tracks, keep=1)
        if cut is None:
            return None
        i, r = cut
        t = tracks[i]
        gate, freed, reverse = self._once(("update", i, r), self._updatable, tracks, free, i, r)
        added, logq = self._extend(gate, freed, must=True)
        if not added or tuple(added) == t.reports[r:]:
            return None
        new = _Track(t.reports[:r] + tuple(added), t.anchor, t.label)
        return [i], [new], reverse - logq

    def _updatable(self, tracks, free, i: int, r: int):
        """What an update of track i from its report r on starts from: (the gate to extend, the
        free reports then, log q of proposing its present reports from r on)."""
        t = tracks[i]
        gate = self._gate(_Track(t.reports[:r], t.anchor))
        freed = free.union(t.reports[r:])
        return gate, freed, self._path_logq(gate, t.reports[r:], freed, True)

    def _switch(self, tracks, free):
        if len(tracks) < 2:
            return None
        i, j = self._rng.sample(range(len(tracks)), 2)
        scans_a, scans_b, both = self._once(("scans", i, j), self._switch_scans, tracks[i], tracks[j])
        if len(both) < 2:
            return None
        cut = both[_below(self._rng, len(both) - 1)]  # switch the reports after scan ``cut`` (not the last)
        return self._once(("switch", i, j, cut), self._switched, tracks, i, j, bisect_right(scans_a, cut), bisect_right(scans_b, cut))

    def _switch_scans(self, a: _Track, b: _Track):
        """The scans of a's and of b's reports (increasing), and those of both."""
        scans_a = [self._gates[r].scan for r in a.reports]
        scans_b = [self._gates[r].scan for r in b.reports]
        return scans_a, scans_b, sorted({*scans_a, *scans_b})

    def _switched(self, tracks, i: int, j: int, ka: int, kb: int):
        a, b = tracks[i], tracks[j]
        new_a = _Track(a.reports[:ka] + b.reports[kb:], a.anchor, a.label)
        new_b = _Track(b.reports[:kb] + a.reports[ka:], b.anchor, b.label)
        if new_a.reports == a.reports or not (self._valid(new_a) and self._valid(new_b)):
            return None
        return [i, j], [new_a, new_b], 0.0

    # ------------------------------------------------------------------ output

    def _label(self) -> None:
        """Give each MAP track without an anchor the identity most of its reports last had. An
        identity held by a track that can no longer be extended (unreported for over d̄ scans)
        passes to such a track; the old holder gets an identity nobody has seen."""
        c = self.config
        holders = {}
        for t in self._tracks:
            if t.anchor is not None:
                t.label = t.anchor.identity
                holders[t.label] = t
        taken = {label for label, t in holders.items() if self._scan - self._end_of(t)[0] <= c.max_misses}
        for t in sorted((t for t in self._tracks if t.anchor is None), key=lambda t: t.reports):
            votes: dict[int, int] = {}
            for r in t.reports:
                label = self._owner.get(r)
                if label is not None and label not in taken:
                    votes[label] = votes.get(label, 0) + 1
            t.label = max(sorted(votes), key=votes.get) if votes else None
            if t.label is None:
                continue
            taken.add(t.label)
            dead = holders.pop(t.label, None)
            if dead is not None:
                dead.anchor = replace(dead.anchor, identity=self._new_identity())
                dead.label = dead.anchor.identity

    def _predicted(self, track: _Track, t: float):
        """(state x, state y, reports in all) of ``track``, filtered and predicted to time ``t`` (s)."""
        sx, sy, _, last_t, count, rest = self._start(track)
        for rep in rest:
            sx, sy, _ = self._advance(sx, sy, last_t, rep)
            last_t = rep.t
        q = self.config.process_noise
        return _predict(sx, t - last_t, q), _predict(sy, t - last_t, q), count + len(rest)

    def expected(self, t: float) -> list[Expectation]:
        """Where the MAP's live tracks (of two reports or more, unreported for at most d̄ scans
        by then) expect their targets at time ``t`` (s), the longest tracks first, for the
        fusion of the next scan."""
        c = self.config
        out = []
        for track in self._tracks:
            end = self._end_of(track)
            if end is None or self._scan + 1 - end[0] > c.max_misses:
                continue
            sx, sy, count = self._predicted(track, t)
            if count < 2:
                continue
            out.append(Expectation(x=sx[0], y=sy[0], sigma=math.sqrt(max(sx[2], sy[2])), vx=sx[1], vy=sy[1],
                                   reports=count, unreported=self._scan + 1 - end[0]))
        out.sort(key=lambda e: -e.reports)
        return out

    def _stitch(self, track: _Track, in_use: set[int], now: float) -> int:
        """The identity for a track published for the first time at ``now`` (s): that of the
        nearest ended track whose last report its first report could follow (within the chain's
        gate); else that of the ended track, last shown before that report and at most
        ``reidentify`` s before ``now``, whose prediction the report fits best within
        ``gate_sigmas``; else a fresh one."""
        first = self._reports[track.reports[0]]
        ended = [(math.hypot(first.x - end[2], first.y - end[3]), label) for label, (end, *_) in self._last_seen.items()
                 if label not in in_use and self._follows(*end, track.reports[0])]
        if ended:
            return min(ended)[1]
        fits = []
        for label, (_, t, sx, sy) in self._last_seen.items():
            if label in in_use or not (t < first.t and now - t <= self.config.reidentify):
                continue
            px = _predict(sx, first.t - t, self.config.process_noise)
            py = _predict(sy, first.t - t, self.config.process_noise)
            d2 = (first.x - px[0]) ** 2 / (px[2] + first.rx) + (first.y - py[0]) ** 2 / (py[2] + first.ry)
            if d2 <= self.config.gate_sigmas ** 2:
                fits.append((d2, label))
        return min(fits)[1] if fits else self._new_identity()

    def _publish(self, t: float) -> TrackSet:
        c = self.config
        shown, hidden = [], []
        for track in self._tracks:
            end = self._end_of(track)
            if end is None or self._scan - end[0] > c.max_misses:
                continue
            sx, sy, count = self._predicted(track, t)
            if count < c.min_reports:
                continue
            if self._scan - end[0] <= c.coast:
                shown.append((track, sx, sy))
            elif track.label is not None:
                hidden.append((track, sx, sy))
        for n, (track, sx, sy) in enumerate(shown):
            if track.label is not None:
                continue
            for h, (old, ox, oy) in enumerate(hidden):
                reach = c.gate_sigmas * math.sqrt(max(ox[2], oy[2]) + max(sx[2], sy[2]))
                if ((sx[0] - ox[0]) ** 2 + (sy[0] - oy[0]) ** 2 <= reach * reach
                        or self._follows(*self._end_of(old), track.reports[0])):
                    # the newcomer is most likely the hidden track's target: show that track,
                    # and let the newcomer inherit its identity if it never comes back (_label)
                    shown[n] = hidden.pop(h)
                    self._owner.update(dict.fromkeys(track.reports, old.label))
                    break
        # forgotten once no report of the window can follow its last one and it is too old to re-identify
        for label in [k for k, (end, seen, *_) in self._last_seen.items()
                      if self._scan - end[0] > c.window + c.max_misses and t - seen > c.reidentify]:
            del self._last_seen[label]
        in_use = {t.label for t in self._tracks if t.label is not None}
        out = []
        for track, sx, sy in shown:
            if track.label is None:
                track.label = self._stitch(track, in_use, t)
                in_use.add(track.label)
            self._last_seen[track.label] = (self._end_of(track), t, sx, sy)
            out.append(Track(track=track.label, x=sx[0], y=sy[0], vx=sx[1], vy=sy[1]))
        out.sort(key=lambda tr: tr.track)
        return TrackSet(t=t, tracker=self.name, tracks=out)
