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
  under it, or in a gap of at most ``lag`` scans between two such reports;
* its position and velocity there are the Rauch–Tung–Striebel smoother's (Rauch, Tung and
  Striebel, AIAA J. 3(8), 1965) over the reports of that identity held: those of the ``lag``
  scans after it and of up to ``lag`` + ``half_width`` + 1 scans before, each with the
  variance the chain scored it with, under the chain's constant-velocity model
  (:func:`.kalman_model.kf_smoothed`) with its own q, ``MCMCDAConfig.smooth_noise``. A shared
  copy, whose variance is loose, pulls little; a gap is bridged along the model's path.

The smoother replaced a moving average of the reports over ±``half_width`` scans (half the lag,
at most ``MAX_HALF_WIDTH``): on the five selection sets of the real-PIR recording the
smoother's MOTA is better or the same on all five and its GOSPA lower on all five
(docs/real_sensors.md, "A fixed-lag smoother").

The identities are the tracker's; no track is shown that the sampler did not hold reports for
within ``lag`` scans on both sides. Chosen on the selection sets of the real-PIR recording
(``benchmarks/real_pir_choices.py``).
"""

from __future__ import annotations

import math
from collections import deque

from bintrack.bus_payloads import Track, TrackSet
from bintrack.errors import TrackerConfigError
from bintrack.trackers.base import TrackerInput, TrackerOutput
from bintrack.trackers.multi.kalman_model import kf_smoothed

MAX_HALF_WIDTH = 3
"""scans: beyond the lag, the smoother reads each identity's reports at most this much further back"""
Association = dict[int, tuple[float, float, float, float]]
"""identity → (x, y, x variance, y variance) of the report the MAP's track of that identity holds
in a scan, units and units²"""


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
        self._scans = deque((t, name, self._with_variances(association)) for t, name, association in self._scans)
        if self.inner.revisions is None:
            self.inner.keep_revisions()

    def _with_variances(self, association: dict) -> Association:
        """``association`` with a variance on every position: one held by a version before the
        smoother read them (x, y) gets the least a report has, ``extra_variance``."""
        least = self.inner.motion[2]
        return {k: p if len(p) == 4 else (p[0], p[1], least, least) for k, p in association.items()}

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
        q, speed_variance, _ = self.inner.motion
        tracks = []
        for k in sorted(candidates):
            if not self._shown_at(k, j):
                continue
            held = [(self._at(n)[0], self._at(n)[2][k]) for n in range(self._first, self._last + 1) if k in self._at(n)[2]]
            x, vx = kf_smoothed([(u, p[0], p[2]) for u, p in held], t, q, speed_variance)
            y, vy = kf_smoothed([(u, p[1], p[3]) for u, p in held], t, q, speed_variance)
            tracks.append(Track(track=k, x=x, y=y, vx=vx, vy=vy))
        self._next += 1
        while self._first < self._next - self.lag - self.half_width - 1:
            self._scans.popleft()
            self._first += 1
        return TrackSet(t=t, tracker=name, tracks=tracks)

    def _shown_at(self, k: int, n: int) -> bool:
        """Whether identity ``k`` is shown at scan ``n``: a report there, or on both sides of it
        within a gap of at most ``lag`` scans."""
        if k in self._at(n)[2]:
            return True
        after = next((b for b in range(n + 1, min(n + self.lag, self._last) + 1) if k in self._at(b)[2]), None)
        return after is not None and any(k in self._at(a)[2] for a in range(max(self._first, after - self.lag - 1), n))
