"""An exact algebra of arcs (angular intervals) on a circle, for paper 001 eq. 1.

Angles are in radians, counter-clockwise from +x. An :class:`Arc` is ``start`` in [0, 2π)
and ``length`` in (0, 2π]; it covers the closed interval [start, start + length] taken
modulo 2π, and length 2π is the full circle. An :class:`ArcSet` is a finite union of
disjoint arcs, kept sorted by start, with ``&`` (intersection, "&" of paper 001 §3.2.2),
``-`` (exclusion, "−" of §3.2.2), ``|`` (union) and ``~`` (complement).

Endpoints closer than :data:`TOL` rad are the same point: arcs that only touch intersect in
nothing, pieces shorter than ``TOL`` are dropped and gaps shorter than ``TOL`` are closed.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from bintrack.geometry import TWO_PI, normalize_angle

TOL = 1e-9  # rad


class Arc(NamedTuple):
    """The closed arc from ``start`` (rad, [0, 2π)) counter-clockwise over ``length`` (rad, (0, 2π])."""

    start: float
    length: float

    @property
    def full(self) -> bool:
        return self.length >= TWO_PI - TOL

    @property
    def midpoint(self) -> float:
        """The angle (rad, [0, 2π)) halfway along the arc (``start + π`` for the full circle)."""
        return normalize_angle(self.start + 0.5 * self.length)

    def distance(self, theta: float) -> float:
        """Angular distance (rad, [0, π]) from ``theta`` to the nearest point of the arc; 0 within
        ``TOL`` of it, as :meth:`ArcSet.contains` counts touching endpoints."""
        if self.full:
            return 0.0
        past_start = normalize_angle(theta - self.start)
        if past_start <= self.length + TOL or past_start >= TWO_PI - TOL:
            return 0.0
        return min(past_start - self.length, TWO_PI - past_start)


def _linear(arcs: Iterable[Arc]) -> list[tuple[float, float]]:
    """Closed intervals within [0, 2π] covering ``arcs``, an arc across 0 split in two."""
    out = []
    for start, length in arcs:
        end = start + length
        if end <= TWO_PI:
            out.append((start, end))
        else:
            out.append((start, TWO_PI))
            out.append((0.0, end - TWO_PI))
    return out


def _merge(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Sorted union of closed intervals, gaps under TOL closed and pieces under TOL dropped."""
    merged: list[list[float]] = []
    for lo, hi in sorted(intervals):
        if merged and lo <= merged[-1][1] + TOL:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    return [(lo, hi) for lo, hi in merged if hi - lo > TOL]


def _arcs(intervals: list[tuple[float, float]]) -> tuple[Arc, ...]:
    """Arcs of sorted disjoint intervals within [0, 2π], joining the pieces that meet at 0 ≡ 2π."""
    intervals = _merge(intervals)
    if not intervals:
        return ()
    if len(intervals) == 1 and intervals[0][0] <= TOL and intervals[0][1] >= TWO_PI - TOL:
        return (Arc(0.0, TWO_PI),)
    arcs = [Arc(lo if 0.0 <= lo < TWO_PI else normalize_angle(lo), hi - lo) for lo, hi in intervals]
    if len(intervals) > 1 and intervals[0][0] <= TOL and intervals[-1][1] >= TWO_PI - TOL:
        last = arcs[-1]
        arcs = arcs[1:-1] + [Arc(last.start, TWO_PI - intervals[-1][0] + intervals[0][1])]
    return tuple(sorted(arcs))


class ArcSet:
    """A union of disjoint arcs of one circle (angles in rad); immutable."""

    __slots__ = ("arcs",)

    def __init__(self, arcs: Iterable[Arc | tuple[float, float]] = ()):
        clean = []
        for start, length in arcs:
            if length >= TWO_PI - TOL:
                clean.append(Arc(0.0, TWO_PI))
            elif length > TOL:  # judged on the given length: rounded endpoints could keep a TOL-long piece
                clean.append(Arc(normalize_angle(start), float(length)))
        self.arcs: tuple[Arc, ...] = _arcs(_linear(clean))

    @classmethod
    def full(cls) -> ArcSet:
        """The whole circle, 2π (FA's initial value in eq. 1)."""
        return cls([Arc(0.0, TWO_PI)])

    @classmethod
    def between(cls, a: float, b: float) -> ArcSet:
        """The arc counter-clockwise from angle ``a`` to angle ``b`` (rad); empty if they coincide."""
        return cls([Arc(normalize_angle(a), normalize_angle(b - a))])

    @classmethod
    def centred(cls, centre: float, half_width: float) -> ArcSet:
        """The arc ``centre ± half_width`` (rad); the full circle for half_width ≥ π."""
        return cls([Arc(normalize_angle(centre - half_width), 2.0 * half_width)])

    @classmethod
    def of_intervals(cls, intervals: Iterable[tuple[float, float]]) -> ArcSet:
        """The union of the angle intervals [lo, hi] (rad, 0 ≤ lo < 2π, lo ≤ hi ≤ lo + 2π),
        without per-arc normalisation: for many pieces cut from one circle."""
        linear = []
        for lo, hi in intervals:
            if hi <= TWO_PI:
                linear.append((lo, hi))
            else:
                linear += [(lo, TWO_PI), (0.0, min(hi - TWO_PI, lo))]
        return cls._of(linear)

    @classmethod
    def _of(cls, intervals: list[tuple[float, float]]) -> ArcSet:
        out = cls.__new__(cls)
        out.arcs = _arcs(intervals)
        return out

    # ------------------------------------------------------------------ algebra

    def __and__(self, other: ArcSet) -> ArcSet:
        a, b = _linear(self.arcs), _linear(other.arcs)
        out = []
        for lo1, hi1 in a:
            for lo2, hi2 in b:
                lo, hi = max(lo1, lo2), min(hi1, hi2)
                if hi - lo > TOL:
                    out.append((lo, hi))
        return ArcSet._of(out)

    def __or__(self, other: ArcSet) -> ArcSet:
        return ArcSet._of(_linear(self.arcs) + _linear(other.arcs))

    def __invert__(self) -> ArcSet:
        gaps, cursor = [], 0.0
        for lo, hi in _merge(_linear(self.arcs)):
            gaps.append((cursor, lo))
            cursor = hi
        gaps.append((cursor, TWO_PI))
        return ArcSet._of([(lo, hi) for lo, hi in gaps if hi - lo > TOL])

    def __sub__(self, other: ArcSet) -> ArcSet:
        return self & ~other

    # ------------------------------------------------------------------ queries

    @property
    def length(self) -> float:
        """Total angle covered (rad, [0, 2π])."""
        return float(sum(arc.length for arc in self.arcs))

    @property
    def is_empty(self) -> bool:
        return not self.arcs

    @property
    def is_full(self) -> bool:
        return len(self.arcs) == 1 and self.arcs[0].full

    def __bool__(self) -> bool:
        return bool(self.arcs)

    def __len__(self) -> int:
        return len(self.arcs)

    def __iter__(self):
        return iter(self.arcs)

    def __repr__(self) -> str:
        return f"ArcSet({list(self.arcs)!r})"

    def __eq__(self, other) -> bool:
        if not isinstance(other, ArcSet):
            return NotImplemented
        return (self - other).is_empty and (other - self).is_empty

    __hash__ = None

    def contains(self, theta, tol: float = TOL):
        """Whether angle(s) ``theta`` (rad) lie on the set, endpoints within ``tol`` included."""
        theta = np.asarray(theta, dtype=float)
        inside = np.zeros(theta.shape, dtype=bool)
        for start, length in self.arcs:
            past = normalize_angle(theta - start)
            inside |= (past <= length + tol) | (past >= TWO_PI - tol)
        return bool(inside) if inside.ndim == 0 else inside

    def issubset(self, other: ArcSet) -> bool:
        return (self - other).is_empty

    def nearest(self, theta: float) -> Arc:
        """The arc of the set nearest to angle ``theta`` (rad): the piece chosen for a split result
        (paper 001 Fig. 3(d), "resolved by the most recent estimate"). Ties go to the longer arc."""
        if not self.arcs:
            raise ValueError("empty arc set has no nearest arc")
        return min(self.arcs, key=lambda arc: (arc.distance(theta), -arc.length))

    def longest(self) -> Arc:
        if not self.arcs:
            raise ValueError("empty arc set has no longest arc")
        return max(self.arcs, key=lambda arc: arc.length)


def depth_extreme(sets: list[ArcSet], within: ArcSet, deepest: bool) -> ArcSet:
    """The part of ``within`` covered by the most (``deepest``) or fewest of ``sets``.

    Used when eq. 1 has no solution because of inconsistent reports: the angles agreeing with
    as many "1" reports (deepest) or contradicting as few "0" reports (not deepest) as possible.
    """
    cuts = {0.0, TWO_PI}
    for s in [within, *sets]:
        for lo, hi in _linear(s.arcs):
            cuts.update((lo, hi))
    edges = np.array(sorted(cuts))
    lo, hi = edges[:-1], edges[1:]
    keep = hi - lo > TOL
    lo, hi = lo[keep], hi[keep]
    mid = 0.5 * (lo + hi)
    inside = within.contains(mid, tol=0.0)
    if not inside.any():
        return ArcSet()
    count = np.zeros(len(mid), dtype=int)
    for s in sets:
        count += s.contains(mid, tol=0.0)
    target = count[inside].max() if deepest else count[inside].min()
    chosen = inside & (count == target)
    return ArcSet._of([(float(a), float(b)) for a, b in zip(lo[chosen], hi[chosen])])


def union(sets: Iterable[ArcSet]) -> ArcSet:
    """The union of arc sets (rad), in one merge."""
    return ArcSet._of([interval for s in sets for interval in _linear(s.arcs)])


def combine(base: ArcSet, ins: list[ArcSet], outs: list[ArcSet]) -> ArcSet:
    """The final arc FA of eq. 1 (paper 001 §3.2.2; paper 000 §III.B.3, eq. 1):
    ``base & ins[0] & ins[1] … − (outs[0] | outs[1] | …)``, angles in rad.

    ``base`` is FA's initial value: the whole circle for a disk (paper 001) or the crossed
    sector's arc 2π/s (paper 000). With inconsistent reports (paper 001 §5.6) the result of "&"
    can be empty: then it is the part of ``base`` inside the most ``ins``; and if "−" empties
    it, the part of the "&" result inside the fewest ``outs`` (:func:`depth_extreme`).
    """
    fa = base
    for arc in ins:
        fa = fa & arc
    if fa.is_empty:
        fa = depth_extreme(ins, base, deepest=True)
    remaining = fa - union(outs)
    if remaining.is_empty:
        remaining = depth_extreme(outs, fa, deepest=False)
    return remaining


def overlap_matrix(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Whether single arcs i and j (starts and lengths in rad) share more than a point, pairwise.

    Two arcs meet iff the start of one lies within the other; touching within TOL is not meeting.
    """
    starts = np.asarray(starts, dtype=float)
    lengths = np.asarray(lengths, dtype=float)
    gap = normalize_angle(starts[None, :] - starts[:, None])  # start j seen from start i
    j_in_i = gap < lengths[:, None] - TOL
    return j_in_i | j_in_i.T | (lengths[:, None] >= TWO_PI - TOL) | (lengths[None, :] >= TWO_PI - TOL)

