"""The proposals of the MCMCDA chain (paper 004 §IV; Oh, Russell and Sastry 2009, §IV-B):
birth/death, split/merge, extension/reduction, track update and track switch, each with the
log ratio of its reverse and forward proposal probabilities for the Metropolis–Hastings
acceptance (eq. 5).

Extension proposals grow a track forward: choose a gap d ∈ 1..d̄+1 scans uniformly (from an
anchor with ``still_misses``, one of the gaps to the window's scans up to ``still_misses`` + 1), then a false
alarm within the gate at that scan uniformly, and stop with probability γ. Proposal
probabilities enter the acceptance ratio; the probability that an extension stops because no
candidate lies in the gate is neglected (it is small next to γ).

Every random draw goes through the sampler's one stream, in a fixed order: the chain's output
for a seed depends on it.
"""

from __future__ import annotations

import math
import random
from bisect import bisect_right

from bintrack.trackers.multi.mcmcda_window import ChainTrack, Gate

_MISSING = object()


def below(rng: random.Random, n: int) -> int:
    """``rng.randrange(n)`` for ``n`` ≥ 1 with the same draws (CPython's ``_randbelow``), without
    its argument checks: the moves draw a few numbers each, and randrange's frames showed."""
    getrandbits = rng.getrandbits
    k = n.bit_length()
    r = getrandbits(k)
    while r >= n:
        r = getrandbits(k)
    return r


class ChainMoves:
    """The moves' part of :class:`~bintrack.trackers.multi.mcmcda.OnlineMCMCDA`. A move takes
    the chain's state (``tracks``, the ``free`` reports) and returns None or (indices of the
    tracks it removes, the tracks it adds, log of the proposal ratio ξ·q).

    It draws from ``_rng`` and reads the window (``_scan``, ``_gates``, ``_latest``) and the
    memo ``_now`` of the chain's state, which the chain empties when the state changes."""

    def _extend(self, gate: Gate, free: set[int], must: bool) -> tuple[list[int], float]:
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
            if c.still_misses:
                first, span = self._gaps(gate)
            else:
                first, span = 1, min(c.max_misses + 1, self._scan - gate.scan)  # _gaps, inline in the chain's hottest loop
            if span < 1:
                return added, logq
            d = first + below(rng, span)  # randint(first, first + span - 1)
            # candidates lie after every report added so far, so none of those is among them
            cands = [r for r in gate.at.get(gate.scan + d, ()) if r in free]
            if not cands:
                return added, logq + math.log(1.0 / span)
            rid = cands[below(rng, len(cands))]
            logq += -math.log(span) - math.log(len(cands)) + (math.log1p(-c.stop) if (added or not must) else 0.0)
            added.append(rid)
            gate = gates[rid]

    def _path_logq(self, gate: Gate, path: list[int], free: set[int], must: bool) -> float:
        """log q of ``_extend`` proposing exactly ``path`` from ``gate``'s report or anchor (then stopping)."""
        c = self.config
        gates = self._gates
        logq = 0.0
        for i, rid in enumerate(path):
            span = self._gaps(gate)[1]
            if span < 1 or rid not in gate.all or rid not in free:
                return -math.inf
            after = gates[rid]
            cands = len(free.intersection(gate.at[after.scan]))
            logq += -math.log(span) - math.log(cands) + (math.log1p(-c.stop) if (i or not must) else 0.0)
            gate = after
        return logq + (math.log(c.stop) if self._gaps(gate)[1] >= 1 else 0.0)

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

    def _continuable(self, gate: Gate, free) -> bool:
        """Whether ``_extend`` from ``gate`` finds a free report at some gap it may draw."""
        first, span = self._gaps(gate)
        return any(r in free for d in range(first, first + span) for r in gate.at.get(gate.scan + d, ()))

    def _gaps(self, gate: Gate) -> tuple[int, int]:
        """The gaps (scans after ``gate``'s) an extension from it draws from: (the first, how
        many). 1 to d̄ + 1 up to the current scan; from an anchor, with ``still_misses``, the
        gaps to the window's scans up to ``still_misses`` + 1."""
        c = self.config
        if c.still_misses and gate.scan < self._scans[0][0]:
            first = self._scans[0][0] - gate.scan
            return first, min(max(c.max_misses, c.still_misses) + 1, self._scan - gate.scan) - first + 1
        return 1, min(c.max_misses + 1, self._scan - gate.scan)

    def _mortal(self, tracks):
        """Indices of the tracks without an anchor, which a death may remove."""
        return self._once("mortal", lambda: [i for i, t in enumerate(tracks) if t.anchor is None])

    @staticmethod
    def _can_split(t: ChainTrack) -> bool:
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
        first = starts[below(self._rng, len(starts))]
        rest, logq = self._extend(self._gates[first], free, must=True)
        if not rest:
            return None
        new = ChainTrack((first, *rest))
        deaths = len(self._mortal(tracks)) + 1
        return [], [new], self._ratio_k(len(tracks), len(tracks) + 1, -math.log(len(starts)) + logq, -math.log(deaths))

    def _death(self, tracks, free):
        mortal = self._mortal(tracks)
        if not mortal:
            return None
        i = mortal[below(self._rng, len(mortal))]
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
        i = choices[below(self._rng, len(choices))]
        t = tracks[i]
        lo = 0 if t.anchor is not None else 2
        points = range(lo, len(t.reports) - 1)  # first part keeps reports[:r]
        r = points[below(self._rng, len(points))]
        return self._once(("split", i, r), self._split_at, tracks, i, r, len(points))

    def _split_at(self, tracks, i: int, r: int, points: int):
        t = tracks[i]
        head, tail = ChainTrack(t.reports[:r], t.anchor, t.label), ChainTrack(t.reports[r:])
        merges = self._merges(tracks[:i] + tracks[i + 1:] + [head, tail])
        forward = -math.log(len(self._splittable(tracks))) - math.log(points)
        return [i], [head, tail], self._ratio_k(len(tracks), len(tracks) + 1, forward, -math.log(max(merges, 1)))

    def _merge(self, tracks, free):
        pairs = self._mergeable(tracks)
        if not pairs:
            return None
        i, j = pairs[below(self._rng, len(pairs))]
        return self._once(("merge", i, j), self._merged, tracks, i, j)

    def _merged(self, tracks, i: int, j: int):
        a, b = tracks[i], tracks[j]
        merged = ChainTrack(a.reports + b.reports, a.anchor, a.label)
        splits = len(self._splittable(tracks)) - self._can_split(a) - self._can_split(b) + self._can_split(merged)
        lo = 0 if merged.anchor is not None else 2
        reverse = -math.log(max(splits, 1)) - math.log(max(len(merged.reports) - 1 - lo, 1))
        return [i, j], [merged], self._ratio_k(len(tracks), len(tracks) - 1, -math.log(len(self._mergeable(tracks))), reverse)

    def _extension(self, tracks, free):
        i = below(self._rng, len(tracks))
        t = tracks[i]
        added, logq = self._extend(self._gate(t), free, must=True)
        if not added:
            return None
        new = ChainTrack(t.reports + tuple(added), t.anchor, t.label)
        lo = 0 if new.anchor is not None else 2
        reverse = -math.log(len(tracks)) - math.log(len(new.reports) - lo)
        return [i], [new], self._ratio_k(len(tracks), len(tracks), -math.log(len(tracks)) + logq, reverse)

    def _cut(self, tracks, keep: int):
        """A random track and a random cut in its window reports, leaving at least ``keep`` of
        them before the cut when it has no anchor: (index, cut), or None."""
        i = below(self._rng, len(tracks))
        t = tracks[i]
        lo = 0 if t.anchor is not None else keep
        if len(t.reports) <= lo:
            return None
        return i, lo + below(self._rng, len(t.reports) - lo)

    def _reduction(self, tracks, free):
        cut = self._cut(tracks, keep=2)
        if cut is None:
            return None
        return self._once(("reduction", *cut), self._reduced, tracks, free, *cut)

    def _reduced(self, tracks, free, i: int, r: int):
        t = tracks[i]
        lo = 0 if t.anchor is not None else 2
        new = ChainTrack(t.reports[:r], t.anchor, t.label)
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
        new = ChainTrack(t.reports[:r] + tuple(added), t.anchor, t.label)
        return [i], [new], reverse - logq

    def _updatable(self, tracks, free, i: int, r: int):
        """What an update of track i from its report r on starts from: (the gate to extend, the
        free reports then, log q of proposing its present reports from r on)."""
        t = tracks[i]
        gate = self._gate(ChainTrack(t.reports[:r], t.anchor))
        freed = free.union(t.reports[r:])
        return gate, freed, self._path_logq(gate, t.reports[r:], freed, True)

    def _switch(self, tracks, free):
        if len(tracks) < 2:
            return None
        i, j = self._rng.sample(range(len(tracks)), 2)
        scans_a, scans_b, both = self._once(("scans", i, j), self._switch_scans, tracks[i], tracks[j])
        if len(both) < 2:
            return None
        cut = both[below(self._rng, len(both) - 1)]  # switch the reports after scan ``cut`` (not the last)
        return self._once(("switch", i, j, cut), self._switched, tracks, i, j, bisect_right(scans_a, cut), bisect_right(scans_b, cut))

    def _switch_scans(self, a: ChainTrack, b: ChainTrack):
        """The scans of a's and of b's reports (increasing), and those of both."""
        scans_a = [self._gates[r].scan for r in a.reports]
        scans_b = [self._gates[r].scan for r in b.reports]
        return scans_a, scans_b, sorted({*scans_a, *scans_b})

    def _switched(self, tracks, i: int, j: int, ka: int, kb: int):
        a, b = tracks[i], tracks[j]
        new_a = ChainTrack(a.reports[:ka] + b.reports[kb:], a.anchor, a.label)
        new_b = ChainTrack(b.reports[:kb] + a.reports[ka:], b.anchor, b.label)
        if new_a.reports == a.reports or not (self._valid(new_a) and self._valid(new_b)):
            return None
        return [i, j], [new_a, new_b], 0.0
