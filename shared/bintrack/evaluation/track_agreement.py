"""How far two track outputs of the same data agree, scan by scan: the regions' merged tracks
against one base station over the whole field (DESIGN §9). Pure."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from bintrack.evaluation.metrics import identity_pairs
from bintrack.formats import TrackRow


@dataclass
class Agreement:
    """``scans``: scans in either output; ``count_equal``: scans with as many tracks in both;
    ``gaps``: the distance (units) of each matched pair of tracks; ``split``: reference tracks
    matched to more than one identity of the other output (an identity lost); ``joined``:
    identities of the other output matched to more than one reference track; ``switches``: times
    a reference track, kept under one identity, was matched to another identity of the other
    output than at its previous match (an identity lost where the reference kept it), counted
    as CLEAR MOT counts mismatches; ``switches_redecided``: the same with the pairs decided
    afresh at every scan, which also counts two people within a metre or two of each other
    whose tracks noise puts nearer the other's."""

    scans: int = 0
    count_equal: int = 0
    count_diffs: list[tuple[float, int, int]] = field(default_factory=list)  # (t, reference, other)
    gaps: list[float] = field(default_factory=list)
    split: dict[int, set[int]] = field(default_factory=dict)
    joined: dict[int, set[int]] = field(default_factory=dict)
    switches: int = 0
    switches_redecided: int = 0

    @property
    def max_gap(self) -> float:
        return max(self.gaps, default=0.0)

    def within(self, tolerance: float) -> float:
        """Share of the matched pairs closer than ``tolerance`` (units)."""
        return sum(g <= tolerance for g in self.gaps) / len(self.gaps) if self.gaps else 1.0

    def summary(self) -> str:
        return (f"{self.count_equal}/{self.scans} scans with the same count; matched pairs {len(self.gaps)}, "
                f"max gap {self.max_gap:.3f}, {100 * self.within(0.5):.1f}% within 0.5; "
                f"{self.switches} identity switches ({self.switches_redecided} with the pairs decided afresh at every scan; "
                f"{len(self.split)} split, {len(self.joined)} joined)")


def agreement(reference: Iterable[TrackRow], other: Iterable[TrackRow], gate: float = 5.0) -> Agreement:
    """Compare ``other`` with ``reference`` scan by scan (rows grouped by ``t``): counts, and the
    tracks paired by least total distance (pairs farther than ``gate`` units left unpaired).

    The gaps are of those pairs. Identity switches are counted as CLEAR MOT counts mismatches
    (Bernardin and Stiefelhagen, 2008; as :func:`bintrack.evaluation.metrics.multi_target_scores`
    does against the truth): at each scan a reference track keeps the identity of ``other`` it
    had while that track is still within ``gate`` and not kept by another; the rest are paired
    by least total distance."""
    by_t: dict[float, tuple[list[TrackRow], list[TrackRow]]] = defaultdict(lambda: ([], []))
    for row in reference:
        by_t[round(row.t, 6)][0].append(row)
    for row in other:
        by_t[round(row.t, 6)][1].append(row)
    result = Agreement()
    ids: dict[int, set[int]] = defaultdict(set)
    back: dict[int, set[int]] = defaultdict(set)
    last: dict[int, int] = {}
    last_redecided: dict[int, int] = {}
    for t in sorted(by_t):
        ref, oth = by_t[t]
        result.scans += 1
        if len(ref) == len(oth):
            result.count_equal += 1
        else:
            result.count_diffs.append((t, len(ref), len(oth)))
        if not ref or not oth:
            continue
        cost = np.array([[math.hypot(a.x - b.x, a.y - b.y) for b in oth] for a in ref])
        for i, j in zip(*linear_sum_assignment(cost)):
            if cost[i, j] <= gate:
                result.gaps.append(float(cost[i, j]))
                ids[ref[i].track].add(oth[j].track)
                if last_redecided.get(ref[i].track, oth[j].track) != oth[j].track:
                    result.switches_redecided += 1
                last_redecided[ref[i].track] = oth[j].track
                back[oth[j].track].add(ref[i].track)
        kept = identity_pairs(oth, [r.track for r in ref], np.array([(r.x, r.y) for r in ref]), last, gate)
        for track, partner in kept.items():
            if last.get(track, partner) != partner:
                result.switches += 1
            last[track] = partner
    result.split = {k: v for k, v in ids.items() if len(v) > 1}
    result.joined = {k: v for k, v in back.items() if len(v) > 1}
    return result
