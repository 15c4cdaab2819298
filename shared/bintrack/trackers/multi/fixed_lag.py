"""A fixed-lag smoother of mcmcda's tracks (ours; an option, off by default): each scan's
``TrackSet`` is given ``lag`` scans late, made from what the sampler decided about that scan's
reports in the scans after it.

Online, each scan's tracks are the MAP's guess of the moment: a track is shown predicted a scan
past its last report, a new one only from its second report, and a false one as long as it
lasts. Online MCMCDA revises the association of the reports of its whole window every scan
(Oh, Russell and Sastry, IEEE TAC 2009, §IV-C: the estimate of a scan is final once its reports
leave the window). So the smoother keeps, for each scan, the last association the tracker gave
of its reports (:meth:`MCMCDATracker.keep_revisions`; tracks without an identity left out), and
once ``lag`` later scans are known:

* an identity is shown at a scan where one of the MAP's tracks holds a report of that scan
  under it, at that report's position;
* a gap of at most ``lag`` scans between two such reports of the same identity is filled, the
  position linear in time between the two;
* every position is the mean over the scans within ``half_width`` of the scan (those that show
  the identity, gaps filled), a moving average centred on it, and the velocity the
  least-squares slope of those positions against time. ``half_width`` is half the lag, at most
  ``MAX_HALF_WIDTH`` scans: the association is settled by about 6 scans, and a wider average
  only blurs a person who turns (r1-easy, seeds 0 and 1: ``--lag 20`` averaged over ±10 scans
  scored MOTA 61–63 %, over ±3 scans 82–83 %, as ``--lag 6``).

The identities are the tracker's; no track is shown that the sampler did not hold reports for
within ``lag`` scans on both sides. Chosen on the selection sets of the real-PIR recording
(``benchmarks/real_pir_choices.py``; docs/real_sensors.md).
"""

from __future__ import annotations

import math
from collections import deque

from bintrack.bus_payloads import Track, TrackSet
from bintrack.errors import TrackerConfigError
from bintrack.trackers.base import TrackerInput, TrackerOutput

MAX_HALF_WIDTH = 3
"""scans: the moving average reaches at most this far on each side of a scan, however long the lag"""
Association = dict[int, tuple[float, float]]
"""identity → (x, y) of the report the MAP's track of that identity holds in a scan, units"""


class FixedLagSmoother:
    """Wraps an :class:`~bintrack.trackers.multi.tracker.MCMCDATracker`: its other outputs pass
    at once, each ``TrackSet`` comes ``lag`` scans late (all of them at the end of the stream,
    ``flush(inf)``), made as the module says. Other attributes are the tracker's."""

    def __init__(self, tracker, lag: int):
        if lag < 1:
            raise TrackerConfigError(f"the fixed lag must be at least 1 scan, got {lag}")
        self.inner = tracker
        tracker.keep_revisions()
        self.lag = lag
        self.half_width = min(math.ceil(lag / 2), MAX_HALF_WIDTH)
        # (t, tracker name, the latest association of the scan's reports) of the scans still
        # needed: the ones not given yet, and before them those a gap or an average reaches back to
        self._scans: deque[tuple[float, str, Association]] = deque()
        self._first = 0  # scan number of self._scans[0]
        self._next = 0  # scan number of the next TrackSet to give

    def __setstate__(self, state: dict) -> None:
        """From a checkpoint. One taken before the smoother read the tracker's associations (it
        held the published tracks, and the largest identity shown) goes on from the published
        positions of the scans it holds."""
        if state.pop("_top", None) is not None:
            state["_scans"] = deque((t, name, {k: (tr.x, tr.y) for k, tr in tracks.items()})
                                    for t, name, tracks, _ in state["_scans"])
        self.__dict__.update(state)
        if self.inner.revisions is None:
            self.inner.keep_revisions()

    def __getattr__(self, name: str):
        if name.startswith("__") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def update(self, message: TrackerInput) -> list[TrackerOutput]:
        return self._take(self.inner.update(message), final=False)

    def flush(self, t: float) -> list[TrackerOutput]:
        return self._take(self.inner.flush(t), final=t == math.inf)

    def _take(self, outputs: list[TrackerOutput], final: bool) -> list[TrackerOutput]:
        out: list[TrackerOutput] = []
        revisions = self.inner.revisions
        for message in outputs:
            if not isinstance(message, TrackSet):
                out.append(message)
                continue
            self._scans.append((message.t, message.tracker, {}))
            self._revise(revisions.pop(0))
            if self._last - self._next >= self.lag:
                out.append(self._give())
        while final and self._next <= self._last:
            out.append(self._give())
        return out

    def _revise(self, revision: list[tuple[float, Association]]) -> None:
        """Take the tracker's latest association of the scans of its window (oldest first)."""
        n = self._last
        for t, association in reversed(revision):
            while n >= self._first and self._at(n)[0] > t:
                n -= 1
            if n < self._first:
                return
            if self._at(n)[0] == t:
                self._scans[n - self._first] = (t, self._at(n)[1], association)

    @property
    def _last(self) -> int:
        """Scan number of the latest scan held."""
        return self._first + len(self._scans) - 1

    def _at(self, n: int) -> tuple[float, str, Association]:
        return self._scans[n - self._first]

    def _give(self) -> TrackSet:
        """The smoothed ``TrackSet`` of scan ``_next``; then forget what no later one needs."""
        j = self._next
        t, name, _ = self._at(j)
        candidates = {k for n in range(max(self._first, j - self.lag), self._last + 1) for k in self._at(n)[2]}
        tracks = []
        for k in sorted(candidates):
            filled = {n: p for n in range(j - self.half_width, j + self.half_width + 1) if (p := self._filled(k, n)) is not None}
            if j not in filled:
                continue
            near = [(self._at(n)[0], p) for n, p in filled.items()]
            x = sum(p[0] for _, p in near) / len(near)
            y = sum(p[1] for _, p in near) / len(near)
            tracks.append(Track(track=k, x=x, y=y, vx=_slope(near, 0), vy=_slope(near, 1)))
        self._next += 1
        while self._first < self._next - self.lag - self.half_width - 1:
            self._scans.popleft()
            self._first += 1
        return TrackSet(t=t, tracker=name, tracks=tracks)

    def _filled(self, k: int, n: int) -> tuple[float, float] | None:
        """(x, y) of identity ``k`` at scan ``n`` from the scans held: its report there, else
        filled in a gap of at most ``lag`` scans, else None."""
        if not self._first <= n <= self._last:
            return None
        t, _, association = self._at(n)
        if k in association:
            return association[k]
        after = next((b for b in range(n + 1, min(n + self.lag, self._last) + 1) if k in self._at(b)[2]), None)
        if after is None:
            return None
        before = next((a for a in range(n - 1, max(self._first, after - self.lag - 1) - 1, -1) if k in self._at(a)[2]), None)
        if before is None:
            return None
        (ta, _, earlier), (tb, _, later) = self._at(before), self._at(after)
        (ax, ay), (bx, by) = earlier[k], later[k]
        w = (t - ta) / (tb - ta)
        return ax + w * (bx - ax), ay + w * (by - ay)


def _slope(points: list[tuple[float, tuple[float, float]]], axis: int) -> float | None:
    """Least-squares slope (units/s) of coordinate ``axis`` against time over ``points`` ((t,
    (x, y)) pairs); None for fewer than two times."""
    if len(points) < 2:
        return None
    mt = sum(t for t, _ in points) / len(points)
    mp = sum(p[axis] for _, p in points) / len(points)
    stt = sum((t - mt) ** 2 for t, _ in points)
    return sum((t - mt) * (p[axis] - mp) for t, p in points) / stt if stt > 0 else None
