"""A fixed-lag smoother of a multi-target tracker's published tracks (ours; an option, off by
default): each scan's ``TrackSet`` is given ``lag`` scans late, amended with what the tracker
published in those later scans.

Online, a person the tracker loses for a few scans (hidden beside another, or a PIR that fires
less while they slow down) is missing from those scans, and a new track is shown only from its
second report. Once the later scans are known:

* a gap of at most ``lag`` scans between two showings of the same identity is filled, the
  position (and velocity) linear in time between the two;
* an identity shown for the first time is also shown in the scan before, where its first
  report was (the tracker publishes a track from its second), at its first shown position (a
  new identity is one larger than all shown before: mcmcda counts its identities up);
* every position and velocity is the mean over the scans within ``half_width`` of the scan
  (those that show the identity, gaps filled), a moving average centred on it.

The published identities are the tracker's own; nothing is shown that the tracker did not show
within ``lag`` scans on both sides, or the scan after. Chosen on the selection sets of the
real-PIR recording (``benchmarks/real_pir_choices.py``; docs/real_sensors.md).
"""

from __future__ import annotations

import math
from collections import deque

from bintrack.bus_payloads import Track, TrackSet
from bintrack.errors import TrackerConfigError
from bintrack.trackers.base import Tracker, TrackerInput, TrackerOutput


class FixedLagSmoother:
    """Wraps a tracker that publishes ``TrackSet``s (mcmcda): its other outputs pass at once,
    each ``TrackSet`` comes ``lag`` scans late (all of them at the end of the stream,
    ``flush(inf)``), smoothed as the module says. Other attributes are the tracker's."""

    def __init__(self, tracker: Tracker, lag: int):
        if lag < 1:
            raise TrackerConfigError(f"the fixed lag must be at least 1 scan, got {lag}")
        self.inner = tracker
        self.lag = lag
        self.half_width = math.ceil(lag / 2)
        # (t, tracker name, identity → Track, largest identity shown so far) of the scans still
        # needed: the unsmoothed ones, and before them those a gap or an average reaches back to
        self._scans: deque[tuple[float, str, dict[int, Track], int]] = deque()
        self._first = 0  # scan number of self._scans[0]
        self._next = 0  # scan number of the next TrackSet to give
        self._top = -1  # the largest identity shown so far

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
        for message in outputs:
            if not isinstance(message, TrackSet):
                out.append(message)
                continue
            tracks = {track.track: track for track in message.tracks}
            self._top = max(self._top, *tracks) if tracks else self._top
            self._scans.append((message.t, message.tracker, tracks, self._top))
            if self._last - self._next >= self.lag:
                out.append(self._give())
        while final and self._next <= self._last:
            out.append(self._give())
        return out

    @property
    def _last(self) -> int:
        """Scan number of the latest scan held."""
        return self._first + len(self._scans) - 1

    def _at(self, n: int) -> tuple[float, str, dict[int, Track], int]:
        return self._scans[n - self._first]

    def _give(self) -> TrackSet:
        """The smoothed ``TrackSet`` of scan ``_next``; then forget what no later one needs."""
        j = self._next
        t, name, _, _ = self._at(j)
        candidates = {k for n in range(max(self._first, j - self.lag), self._last + 1) for k in self._at(n)[2]}
        tracks = []
        for k in sorted(candidates):
            filled = {n: p for n in range(j - self.half_width, j + self.half_width + 1) if (p := self._filled(k, n)) is not None}
            if j not in filled:
                continue
            near = list(filled.values())
            x = sum(p[0] for p in near) / len(near)
            y = sum(p[1] for p in near) / len(near)
            moving = [p for p in near if p[2] is not None]
            vx = sum(p[2] for p in moving) / len(moving) if moving else None
            vy = sum(p[3] for p in moving) / len(moving) if moving else None
            tracks.append(Track(track=k, x=x, y=y, vx=vx, vy=vy))
        self._next += 1
        while self._first < self._next - self.lag - self.half_width - 1:
            self._scans.popleft()
            self._first += 1
        return TrackSet(t=t, tracker=name, tracks=tracks)

    def _filled(self, k: int, n: int) -> tuple[float, float, float | None, float | None] | None:
        """(x, y, vx, vy) of identity ``k`` at scan ``n`` from the scans held: as shown, else
        filled in a gap or shown a scan early (the module), else None."""
        if not self._first <= n <= self._last:
            return None
        t, _, tracks, top = self._at(n)
        if k in tracks:
            track = tracks[k]
            return track.x, track.y, track.vx, track.vy
        after = next((b for b in range(n + 1, min(n + self.lag, self._last) + 1) if k in self._at(b)[2]), None)
        if after is None:
            return None
        tb, _, later, _ = self._at(after)
        b = later[k]
        before = next((a for a in range(n - 1, max(self._first, after - self.lag - 1) - 1, -1) if k in self._at(a)[2]), None)
        if before is None:
            return (b.x, b.y, b.vx, b.vy) if after == n + 1 and k > top else None
        ta, _, earlier, _ = self._at(before)
        a = earlier[k]
        w = (t - ta) / (tb - ta)
        vx, vy = (b.x - a.x) / (tb - ta), (b.y - a.y) / (tb - ta)
        return a.x + w * (b.x - a.x), a.y + w * (b.y - a.y), vx, vy
