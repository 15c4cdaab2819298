"""How far two track outputs of the same data agree, scan by scan: the regions' merged tracks
against one base station over the whole field (DESIGN §9). Pure."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from bintrack.formats import TrackRow


@dataclass
class Agreement:
    """``scans``: scans in either output; ``count_equal``: scans with as many tracks in both;
    ``gaps``: the distance (units) of each matched pair of tracks; ``split``: reference tracks
    matched to more than one identity of the other output (an identity lost); ``joined``:
    identities of the other output matched to more than one reference track; ``switches``: times
    a reference track, kept under one identity, was matched to another identity of the other
    output than at its previous match (an identity lost where the reference kept it)."""

    scans: int = 0
    count_equal: int = 0
    count_diffs: list[tuple[float, int, int]] = field(default_factory=list)  # (t, reference, other)
    gaps: list[float] = field(default_factory=list)
    split: dict[int, set[int]] = field(default_factory=dict)
    joined: dict[int, set[int]] = field(default_factory=dict)
    switches: int = 0

    @property
    def max_gap(self) -> float:
        return max(self.gaps, default=0.0)

    def within(self, tolerance: float) -> float:
        """Share of the matched pairs closer than ``tolerance`` (units)."""
        return sum(g <= tolerance for g in self.gaps) / len(self.gaps) if self.gaps else 1.0

    def summary(self) -> str:
        return (f"{self.count_equal}/{self.scans} scans with the same count; matched pairs {len(self.gaps)}, "
                f"max gap {self.max_gap:.3f}, {100 * self.within(0.5):.1f}% within 0.5; "
                f"{self.switches} identity switches ({len(self.split)} split, {len(self.joined)} joined)")


def agreement(reference: Iterable[TrackRow], other: Iterable[TrackRow], gate: float = 5.0) -> Agreement:
    """Compare ``other`` with ``reference`` scan by scan (rows grouped by ``t``): counts, and the
    tracks paired by least total distance (pairs farther than ``gate`` units left unpaired)."""
    by_t: dict[float, tuple[list[TrackRow], list[TrackRow]]] = defaultdict(lambda: ([], []))
    for row in reference:
        by_t[round(row.t, 6)][0].append(row)
    for row in other:
        by_t[round(row.t, 6)][1].append(row)
    result = Agreement()
    ids: dict[int, set[int]] = defaultdict(set)
    back: dict[int, set[int]] = defaultdict(set)
    last: dict[int, int] = {}
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
                if last.get(ref[i].track, oth[j].track) != oth[j].track:
                    result.switches += 1
                last[ref[i].track] = oth[j].track
                back[oth[j].track].add(ref[i].track)
    result.split = {k: v for k, v in ids.items() if len(v) > 1}
    result.joined = {k: v for k, v in back.items() if len(v) > 1}
    return result
