"""The network's picture from its regions' tracks (DESIGN §9): one ``TrackSet`` per scan with
global identities, a target in a border band shown once, an identity kept when its target
crosses into the next region, and a lost region's tracks marked stale. Pure: push-style, event
time, no I/O.

Each region's base station tracks its own sensors and those of a border band around it, so a
target near a border is tracked by two (or four) base stations at once, under their own local
ids. At each scan the merge

1. links the tracks of different regions that are the same target: pairs of tracks of two
   regions closer than ``gate``, nearest first, at most one track per region in a group;
2. shows each group once, as the track of the region that owns the group's mean position
   (else the first region's);
3. gives each group a global identity: the one a member carried when last shown (so when the
   target crosses a border, the neighbour's track, linked to it while both saw the target,
   carries it on), else that of a track of another region that ended within ``handover``
   seconds and whose position predicted by its velocity lies within ``gate``, else a new one.
   A new identity made where a region that was cut off (stale) could be tracking the target
   (within ``reach`` of it) is provisional: once that region is back and links its own track to
   the target, the target carries that region's identity again (the identity is kept across the
   cut). The region's scans of the cut, which come in after their time was merged, are still
   read for this: where one of its tracks lay on a provisional target at the same scan, the
   target takes the track's identity from then on (the target walked out of the region while it
   was cut off).

A region whose base station is gone (:meth:`RegionMerge.lost`) is not waited for; its last
tracks stay in the output with ``stale`` set until it is back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bintrack.bus_payloads import Track, TrackSet
from bintrack.regions import RegionMap


@dataclass(frozen=True)
class MergeConfig:
    """``gate``: metres within which two regions' tracks are one target; ``handover``: seconds
    an ended track can be continued by another region's new one; ``reach``: metres outside its
    region beyond which a region's track is left out (deep in the border band it is placed
    from a part of the sensors only)."""

    gate: float = 5.0
    handover: float = 5.0
    reach: float = 8.0


@dataclass
class _Shown:
    t: float
    track: Track


@dataclass
class RegionMerge:
    """Region ``TrackSet``s (local ids) → the network's ``TrackSet`` per scan (global ids).

    Feed :meth:`add` (a region's scan), :meth:`progress` (the region's scans up to t are all
    in), :meth:`lost`/:meth:`back` (its base station's presence); each returns the merged scans
    that became complete, in event-time order.
    """

    regions: RegionMap
    config: MergeConfig = MergeConfig()
    live: set[str] = field(default_factory=set)
    stale: set[str] = field(default_factory=set)
    final: dict[str, float] = field(default_factory=dict)  # region → its scans up to here are in
    pending: dict[float, dict[str, TrackSet]] = field(default_factory=dict)
    ids: dict[tuple[str, int], int] = field(default_factory=dict)  # (region, local id) → global id
    seen: dict[tuple[str, int], float] = field(default_factory=dict)  # (region, local id) → last scan in
    shown: dict[int, _Shown] = field(default_factory=dict)  # global id → when and where last shown
    last: dict[str, TrackSet] = field(default_factory=dict)  # region → its latest merged-in scan
    emitted_up_to: float = -math.inf
    next_id: int = 0
    tracker: str = "mcmcda"
    # identities made for a track within reach of a stale region: that region's own identity for
    # the target takes over once it is back and shows it (live, or in its late scans)
    provisional: set[int] = field(default_factory=set)
    # the merged scans of the last ``RECALL`` seconds while a region was stale: its late scans
    # are read against them
    recent: dict[float, TrackSet] = field(default_factory=dict)

    def __setstate__(self, state: dict) -> None:
        state.setdefault("provisional", set())  # a checkpoint from before provisional identities
        state.setdefault("recent", {})
        self.__dict__.update(state)

    def __post_init__(self):
        scale = self.regions.deployment.metres_per_unit
        self._gate = self.config.gate / scale
        self._reach = self.config.reach / scale

    # -- inputs ----------------------------------------------------------------------------

    def add(self, region: str, tracks: TrackSet) -> list[TrackSet]:
        """A region's scan (local ids); nothing comes out until :meth:`progress` says it is complete."""
        self.regions.check(region)
        self.tracker = tracks.tracker
        if tracks.t > self.emitted_up_to:
            self.pending.setdefault(_key(tracks.t), {})[region] = tracks
        else:
            self._reconcile(region, tracks)
        return []

    def progress(self, region: str, t: float) -> list[TrackSet]:
        """Region ``region`` has published every scan at or before event time ``t`` (s)."""
        self.regions.check(region)
        self.final[region] = max(t, self.final.get(region, -math.inf))
        self.live.add(region)
        self.stale.discard(region)
        return self._release(self._watermark())

    def lost(self, region: str) -> list[TrackSet]:
        """Region ``region``'s base station is gone: stop waiting for it; its tracks turn stale."""
        self.live.discard(region)
        self.stale.add(region)
        return self._release(self._watermark())

    def back(self, region: str) -> None:
        """Region ``region``'s base station is there (again): its scans are waited for."""
        self.regions.check(region)
        self.live.add(region)
        self.stale.discard(region)

    def finish(self) -> list[TrackSet]:
        """Every scan still held (end of stream)."""
        return self._release(math.inf)

    # -- merging ---------------------------------------------------------------------------

    def _watermark(self) -> float:
        return min((self.final.get(r, -math.inf) for r in self.live), default=-math.inf)

    def _release(self, watermark: float) -> list[TrackSet]:
        out = []
        for t in sorted(k for k in self.pending if k <= watermark):
            scans = self.pending.pop(t)
            out.append(self._merge(t, scans))
            self.emitted_up_to = t
            if self.stale:
                self.recent[t] = out[-1]
            for old in [k for k in self.recent if k < t - RECALL]:
                del self.recent[old]
        return out

    def _reconcile(self, region: str, late: TrackSet) -> None:
        """Region ``region``'s scan ``late``, come in after its time was merged (it was cut off):
        a provisional target shown at that scan within ``gate`` of one of the region's tracks
        takes the track's identity, nearest pairs first, unless that identity is shown elsewhere."""
        merged = self.recent.get(_key(late.t))
        if merged is None:
            return
        in_use = {tr.track for tr in self._shown_last() if not tr.stale}
        pairs = []
        for track in late.tracks:
            gid = self.ids.get((region, track.track))
            if gid is None or gid in self.provisional or gid in in_use \
                    or self.regions.distance(region, track.x, track.y) > self._reach:
                continue
            for shown in merged.tracks:
                if shown.track in self.provisional and not shown.stale:
                    d = math.hypot(shown.x - track.x, shown.y - track.y)
                    if d <= self._gate:
                        pairs.append((d, shown.track, gid))
        taken: set[int] = set()
        for _, provisional, gid in sorted(pairs):
            if provisional in self.provisional and gid not in taken:
                self._rename(provisional, gid)
                taken.add(gid)

    def _rename(self, old: int, new: int) -> None:
        """Identity ``old`` (provisional) is ``new`` from now on."""
        self.provisional.discard(old)
        for member, gid in self.ids.items():
            if gid == old:
                self.ids[member] = new
        if old in self.shown:
            shown = self.shown.pop(old)
            self.shown[new] = _Shown(shown.t, shown.track.model_copy(update={"track": new}))

    def _shown_last(self) -> list[Track]:
        """The tracks of the latest merged scan."""
        return [s.track for s in self.shown.values() if s.t == self.emitted_up_to]

    def _merge(self, t: float, scans: dict[str, TrackSet]) -> TrackSet:
        for region, scan in scans.items():
            self.last[region] = scan
        members = [(region, track) for region in sorted(scans) if region not in self.stale
                   for track in scans[region].tracks if self.regions.distance(region, track.x, track.y) <= self._reach]
        groups = self._group(members)
        used: set[int] = set()
        shown: list[Track] = []
        chosen = [(group, *self._representative(group)) for group in groups]
        # groups whose shown track has its identity first, so a newcomer never takes one in use
        chosen.sort(key=lambda c: ((c[1], c[2].track) not in self.ids,
                                   min(self.ids.get((r, tr.track), math.inf) for r, tr in c[0])))
        # a border-band track no other region has comes last, and only where nothing is shown near it
        chosen.sort(key=lambda c: len(c[0]) == 1 and not self._in_own(c[1], c[2]))
        for group, region, best in chosen:
            if len(group) == 1 and not self._in_own(region, best) and any(
                    math.hypot(best.x - tr.x, best.y - tr.y) <= self._gate for tr in shown):
                continue
            gid = self._identity(t, group, best, region, used)
            used.add(gid)
            self.ids[(region, best.track)] = gid
            for r, tr in group:
                self.seen[(r, tr.track)] = t
            track = best.model_copy(update={"track": gid, "region": region})
            self.shown[gid] = _Shown(t, track)
            shown.append(track)
        for region in sorted(self.stale):
            shown.extend(self._stale_tracks(region, used))
        self._forget(t)
        return TrackSet(t=t, tracker=self.tracker, tracks=sorted(shown, key=lambda tr: tr.track))

    def _group(self, members: list[tuple[str, Track]]) -> list[list[tuple[str, Track]]]:
        """Tracks of different regions within the gate, nearest pairs first, one per region in a group."""
        parent = list(range(len(members)))
        regions_of = [{members[i][0]} for i in range(len(members))]

        def find(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        pairs = []
        for i, (ri, ti) in enumerate(members):
            for j in range(i + 1, len(members)):
                rj, tj = members[j]
                if ri != rj:
                    d = math.hypot(ti.x - tj.x, ti.y - tj.y)
                    if d <= self._gate:
                        pairs.append((d, i, j))
        for _, i, j in sorted(pairs):
            a, b = find(i), find(j)
            if a != b and not regions_of[a] & regions_of[b]:
                parent[b] = a
                regions_of[a] |= regions_of[b]
        groups: dict[int, list[tuple[str, Track]]] = {}
        for i, member in enumerate(members):
            groups.setdefault(find(i), []).append(member)
        return list(groups.values())

    def _representative(self, group: list[tuple[str, Track]]) -> tuple[str, Track]:
        """The member of the region that owns the group's mean position, else the one nearest
        to its own region."""
        x = sum(tr.x for _, tr in group) / len(group)
        y = sum(tr.y for _, tr in group) / len(group)
        owner = self.regions.owner(x, y)
        for region, track in group:
            if region == owner:
                return region, track
        return min(group, key=lambda m: self.regions.distance(m[0], m[1].x, m[1].y))

    def _in_own(self, region: str, track: Track) -> bool:
        """The track lies in its own region, or where the region owning its position is not live."""
        owner = self.regions.owner(track.x, track.y)
        return owner == region or owner not in self.live

    def _identity(self, t: float, group, best: Track, region: str, used: set[int]) -> int:
        own = self.ids.get((region, best.track))
        if own in self.provisional:
            # made while the region owning the target was cut off: that region, back, keeps its own
            settled = sorted(gid for r, tr in group if (gid := self.ids.get((r, tr.track))) is not None
                             and gid not in self.provisional and gid not in used)
            if settled:
                self.provisional.discard(own)
                return settled[0]
        if own is not None and own not in used:
            return own  # an identity, once given to a region's track, stays with it
        # hand-over: the identity of the track of another region it was linked with, the latest shown
        known = sorted({self.ids[(r, tr.track)] for r, tr in group if (r, tr.track) in self.ids} - used,
                       key=lambda gid: (-self.shown[gid].t if gid in self.shown else math.inf, gid))
        if known:
            return known[0]
        # hand-over without overlap: a track of another region that ended lately, where it would be now
        best_gid, best_d = None, self._gate
        for gid, last in self.shown.items():
            dt = t - last.t
            if gid in used or last.t >= t or dt > self.config.handover or last.track.region == region:
                continue
            px = last.track.x + (last.track.vx or 0.0) * dt
            py = last.track.y + (last.track.vy or 0.0) * dt
            d = math.hypot(px - best.x, py - best.y)
            if d <= best_d:
                best_gid, best_d = gid, d
        if best_gid is not None:
            return best_gid
        if any(self.regions.distance(r, best.x, best.y) <= self._reach for r in self.stale):
            self.provisional.add(self.next_id)
        self.next_id += 1
        return self.next_id - 1

    def _stale_tracks(self, region: str, used: set[int]) -> list[Track]:
        """The tracks region ``region`` last owned, stale; those no live region now shows."""
        scan = self.last.get(region)
        if scan is None:
            return []
        out = []
        for track in scan.tracks:
            gid = self.ids.get((region, track.track))
            if gid is None or gid in used or self.shown.get(gid) is None or self.shown[gid].track.region != region:
                continue
            out.append(self.shown[gid].track.model_copy(update={"stale": True}))
        return out

    def _forget(self, t: float) -> None:
        """Drop what can no longer be continued (shown tracks past the hand-over time), except
        what a stale region still shows."""
        for gid in [g for g, s in self.shown.items()
                    if t - s.t > self.config.handover and s.track.region not in self.stale]:
            del self.shown[gid]
        for member in [m for m, seen in self.seen.items() if t - seen > self.config.handover and m[0] not in self.stale]:
            del self.seen[member]
            self.ids.pop(member, None)


RECALL = 30.0  # s: how far back a region's late scans are read (a sensor agent's catch-up holds 30 s)


def _key(t: float) -> float:
    return round(t, 9)
