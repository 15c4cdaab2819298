"""Track identities of online MCMCDA (ours; Oh, Russell and Sastry leave output labels open),
and what the sampler publishes each scan.

A track without an anchor takes the identity that most of its reports were last published
under; failing that, it gets one when it is first published (below). The chain often re-explains a target's last few reports as a new
track while the old one stays in the MAP, unreported; a scan or two later it joins them again.
So a track without an identity does not get published while a track with one, unreported for
more than ``coast`` and at most d̄ scans, could be its target: the newcomer is within
``gate_sigmas`` σ of where the old track predicts it (σ² the two position variances summed), or
its first report lies in the old track's gate. The old track is shown instead, predicted. If it
stays unreported for over d̄ scans it can no longer continue, and the newcomer inherits its
identity; unless, with ``still_misses`` (real PIR), its target may be standing still where it was
last reported: then the old track keeps its identity while it may still go on from there. And a
track published for the first time takes the identity of the nearest published
track that has ended (left the MAP) whose last report its first one could follow, if any: the
chain found a new target more likely than a long gap, but for the user it is most likely the
same person. Failing that, it is re-identified: it takes the identity of the track last shown at
most ``reidentify`` s before, and before its first report, whose Kalman prediction that report
fits best within ``gate_sigmas`` (a person lost for longer than d̄ scans, in clutter or beside
someone else). Else it gets a fresh identity.

A published track that goes unreported is shown predicted for ``coast`` scans, except where
its prediction lies less than ``exit_depth`` inside the sensor field (:meth:`_left`): at the
field's edge a person no sensor reports has most likely left it.

With ``entry_depth`` set (off by default), a person is shown from their first report where
they most likely come in (:meth:`_entries`): a report of the scan that the MAP leaves false, near
or outside the field's edge, strong (``entry_gain``) and in no live track's gate.
"""

from __future__ import annotations

import math
from dataclasses import replace

from bintrack.bus_payloads import Track, TrackSet
from bintrack.trackers.multi.kalman_model import kf_predict
from bintrack.trackers.multi.mcmcda_window import ChainTrack
from bintrack.trackers.multi.track_expectation import Expectation


class TrackIdentity:
    """The identity policy's part of :class:`~bintrack.trackers.multi.mcmcda.OnlineMCMCDA`:
    labels for the MAP's tracks, the tracks it publishes and where it expects them.

    Its state: ``_owner`` (report → identity of the last labelled MAP track holding it),
    ``_last_seen`` (published identity → its track's last report, time and states when last
    shown) and ``_next_identity``; it reads the window and the MAP (``_tracks``)."""

    def _new_identity(self) -> int:
        identity = self._next_identity
        self._next_identity += 1
        return identity

    def _label(self) -> None:
        """Give each MAP track without an anchor the identity most of its reports last had. An
        identity held by a track that can no longer be extended (unreported for over d̄ scans,
        and not one that may go on where its target stood still, ``still_misses``) passes to
        such a track; the old holder gets an identity nobody has seen."""
        c = self.config
        holders = {}
        for t in self._tracks:
            if t.anchor is not None:
                t.label = t.anchor.identity
                holders[t.label] = t
        # a track that may still go on where its target stood still (still_misses) keeps its identity
        taken = {label for label, t in holders.items() if self._scan - self._end_of(t)[0] <= c.max_misses
                 or (c.still_misses and not t.reports and self._may_follow(t.anchor.scan, t.anchor.x[0], t.anchor.y[0]))}
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

    def _predicted(self, track: ChainTrack, t: float):
        """(state x, state y, reports in all) of ``track``, filtered and predicted to time ``t`` (s)."""
        sx, sy, last_scan, last_t, count, rest = self._start(track)
        for rep in rest:
            sx, sy, _ = self._advance(sx, sy, last_t, rep, last_scan)
            last_scan, last_t = rep.scan, rep.t
        q = self.config.process_noise
        return kf_predict(sx, t - last_t, q), kf_predict(sy, t - last_t, q), count + len(rest)

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
            own = [self._reports[r].scan for r in track.reports if not self._reports[r].shared]
            out.append(Expectation(x=sx[0], y=sy[0], sigma=math.sqrt(max(sx[2], sy[2])), vx=sx[1], vy=sy[1],
                                   reports=count, unreported=self._scan + 1 - end[0],
                                   unreported_own=self._scan + 1 - own[-1] if own else None))
        out.sort(key=lambda e: -e.reports)
        return out

    def _stitch(self, track: ChainTrack, in_use: set[int], now: float) -> int:
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
            px = kf_predict(sx, first.t - t, self.config.process_noise)
            py = kf_predict(sy, first.t - t, self.config.process_noise)
            d2 = (first.x - px[0]) ** 2 / (px[2] + first.rx) + (first.y - py[0]) ** 2 / (py[2] + first.ry)
            if d2 <= self.config.gate_sigmas ** 2:
                fits.append((d2, label))
        return min(fits)[1] if fits else self._new_identity()

    def _left(self, last_scan: int, sx, sy) -> bool:
        """Whether a track last reported at ``last_scan`` and predicted at (``sx``, ``sy``) has
        most likely left the sensor field: unreported in this scan, and predicted less than
        ``exit_depth`` inside the field. It is then not shown predicted."""
        depth, c = self.field_depth, self.config
        return (last_scan < self._scan and c.exit_depth is not None and depth is not None
                and depth(sx[0], sy[0]) < c.exit_depth)

    def _entries(self, t: float, in_use: set[int]) -> list[Track]:
        """This scan's reports published as people entering (``entry_depth``): free in the
        MAP, not shared, near or outside the field's edge and in no live track's gate. Each
        gets the identity a track first published with it would (:meth:`_stitch`; none of
        ``in_use``), which the track the chain later makes of it takes (:meth:`_label`)."""
        c, depth = self.config, self.field_depth
        if c.entry_depth is None or depth is None:
            return []
        held = {r for track in self._tracks for r in track.reports}
        candidates = [rid for rid in self._scans[-1][2] if rid not in held and not self._reports[rid].shared
                      and self._reports[rid].weight >= c.entry_gain
                      and depth(self._reports[rid].x, self._reports[rid].y) < c.entry_depth]
        if not candidates:
            return []
        live = [(track, end) for track, end in zip(self._tracks, map(self._end_of, self._tracks))
                if end is not None and self._scan - end[0] <= c.max_misses]
        ends = [end for _, end in live if end[0] < self._scan]
        near = [self._predicted(track, t)[:2] for track, _ in live]
        out = []
        for rid in candidates:
            rep = self._reports[rid]
            if (any(self._follows(*end, rid) for end in ends)
                    or any((rep.x - sx[0]) ** 2 + (rep.y - sy[0]) ** 2
                           <= c.gate_sigmas ** 2 * (max(sx[2], sy[2]) + max(rep.rx, rep.ry)) for sx, sy in near)):
                continue
            self._owner[rid] = identity = self._stitch(ChainTrack((rid,)), in_use, t)
            in_use.add(identity)
            # shown like any track: a track the chain begins after it without this report may continue it
            sx, sy = self._initial(rep)
            self._last_seen[identity] = ((rep.scan, rep.t, rep.x, rep.y, max(rep.rx, rep.ry)), t, sx, sy)
            out.append(Track(track=identity, x=rep.x, y=rep.y))
        return out

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
            if self._scan - end[0] <= c.coast and not self._left(end[0], sx, sy):
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
        out += self._entries(t, in_use)
        out.sort(key=lambda tr: tr.track)
        return TrackSet(t=t, tracker=self.name, tracks=out)
