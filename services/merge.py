"""Merge: the network's ``tracks`` from its regions' base stations (DESIGN §9).

``python -m bintrack.services.merge`` hears ``region/*/tracks`` (local ids) and
``region/*/progress`` and publishes on ``tracks`` — the key the client, ``watch``, the recorder
and the map subscribe to — one ``TrackSet`` per scan with global identities, each target shown
once and kept under its identity across region borders
(:class:`~bintrack.trackers.multi.region_merge.RegionMerge`). It follows each region's base
station by its ``region/<r>/alive`` token: when one goes it logs it at once, stops waiting for
that region and keeps its last tracks in the output with ``stale: true``; when it is back it is
waited for again. The ``tracks`` queryable returns the latest merged ``TrackSet``
(``tracks?after=T``: the recent ones after T).

With ``--state-dir`` it keeps a checkpoint (the merge's state: identities, pending scans); a
restarted merge resumes from it and asks each region's base station for the scans published
after the last one it merged (``region/<r>/tracks?after=T``) before it takes progress reports
again, so its output, identities included, is what it would have been without the restart.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys

import zenoh

from bintrack.argtypes import positive_float
from bintrack.keys import ParsedKey, parse_key
from bintrack.live.checkpoint import MergeCheckpoint
from bintrack.live.service import Service, log, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.region_departures import RegionDepartures
from bintrack.live.region_scan_counts import RegionScanCounts, ReportCheck
from bintrack.live.track_history import TrackHistory, fetch_region_tracks
from bintrack.bus_payloads import Clock, TrackSet
from bintrack.regions import RegionMap
from bintrack.trackers.multi.region_merge import MergeConfig, RegionMerge


class Merge(Service):
    name = "merge"

    def __init__(self, args):
        super().__init__(args)
        self.regions: RegionMap | None = None
        self.merge: RegionMerge | None = None
        self.tracks = TrackHistory(self.keys.tracks())
        self.departures = RegionDepartures(self.name)
        self.sent = 0  # track sets published, in each progress report
        self.check = ReportCheck(self.name, RegionScanCounts(), self.fetch_from)  # its count of the regions' scans

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.regions = RegionMap(deployment)
        self.merge = RegionMerge(self.regions, MergeConfig(gate=self.args.gate, handover=self.args.handover))
        resumed = self.resume()
        self.serve(self.tracks.key, self.tracks.answer)
        self.subscribe(self.keys.region_tracks(), self.on_region_tracks)
        if resumed:
            # the scans published while it was gone, before any progress report can release them
            log.info("%s: resumed after t=%g s; %d region scans published since fetched from the base stations",
                     self.name, self.merge.emitted_up_to, await self.fetch_all())
        self.subscribe(self.keys.region_progress(), self.on_region_progress)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.follow_presence(self.on_presence)
        self.follow_end_of_stream(["basestation"], self.finish)
        log.info("%s: merging regions %s", self.name, ", ".join(self.regions.names))

    def resume(self) -> bool:
        """Take back the checkpoint of an earlier instance, if there is one; whether there was."""
        saved = self.checkpoints.load(MergeCheckpoint)
        if saved is None:
            return False
        if sorted(saved.merge.regions.names) != sorted(self.regions.names):
            log.warning("%s: checkpoint not of this deployment (another deployment's regions); starting afresh",
                        self.name)
            return False
        self.merge = saved.merge
        self.check.counts = saved.counts or self.check.counts
        self.tracks.restore(saved.latest, saved.history)
        return True

    def fetch_region_tracks(self, after: float, regions=None) -> list[tuple[str, TrackSet]]:
        """The scans later than ``after`` (s) that the base stations of ``regions`` (default:
        all) still hold (:func:`~bintrack.live.track_history.fetch_region_tracks`); blocking."""
        return fetch_region_tracks(self.query, self.keys, regions or self.regions.names, after, self.bad.report)

    async def fetch_all(self) -> int:
        """Fetch every region's scans after the last merged one (off the loop); how many came."""
        fetched = await asyncio.to_thread(self.fetch_region_tracks, self.merge.emitted_up_to)
        for region, tracks in fetched:
            self.add(region, tracks)
        return len(fetched)

    async def on_router_back(self) -> None:
        if self.merge is not None:
            log.info("%s: %d region scans published during the outage fetched from the base stations", self.name,
                     await self.fetch_all())

    def region_of(self, sample: zenoh.Sample) -> str | None:
        key = str(sample.key_expr)
        return self.known_region(key, parse_key(key).region)

    def known_region(self, key: str, region: str | None) -> str | None:
        """``region`` if the deployment has it, else None (reported as bad input on ``key``)."""
        if region not in self.regions.shapes:
            self.bad.report(key, f"unknown region {region!r}")
            return None
        return region

    def on_region_tracks(self, sample: zenoh.Sample) -> None:
        region = self.region_of(sample)
        tracks = self.decode(TrackSet, sample) if region is not None else None
        if tracks is None:
            return
        self.departures.scan(region, tracks.t, self.merge.emitted_up_to)
        self.add(region, tracks)

    def add(self, region: str, tracks: TrackSet) -> None:
        """A scan of ``region`` heard (live or fetched): counted, and held until its time is released."""
        self.check.counts.heard(region, tracks.t)
        self.emit(self.merge.add(region, tracks))

    def finish(self, t: float) -> None:
        self.check.finish()
        self.departures.finish()
        self.emit(self.merge.finish())

    def on_region_progress(self, sample: zenoh.Sample) -> None:
        region = self.region_of(sample)
        tick = self.decode(Clock, sample) if region is not None else None
        if tick is not None:
            if self.departures.reports(region):
                self.fetch_missed(region)
            if tick.sent is None or self.check.complete(region, tick.t, tick.sent):
                self.emit(self.merge.progress(region, tick.t))

    def fetch_from(self, region: str) -> int:
        """Fetch the scans of ``region`` after the last merged scan from its base station (a
        reply takes milliseconds: the loop waits on purpose); how many came."""
        fetched = self.fetch_region_tracks(self.merge.emitted_up_to, [region])
        for _, tracks in fetched:
            self.add(region, tracks)
        return len(fetched)

    def fetch_missed(self, region: str) -> None:
        """Region ``region``'s base station is back: what it published while its link was down is
        fetched before its progress can release the scans."""
        log.warning("%s: region %s's base station is back; %d of its scans fetched", self.name, region,
                    self.fetch_from(region))

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """A region's base station's ``region/<r>/alive`` token came or went."""
        if parsed.kind != "region_alive":
            return
        region = self.known_region(self.keys.region_alive(parsed.region), parsed.region)
        if region is None:
            return
        if present:
            if self.departures.back(region, region in self.merge.stale):
                self.fetch_missed(region)
            self.merge.back(region)
            return
        self.went(region)

    def went(self, region: str) -> None:
        latest = self.tracks.latest
        self.departures.went(region, sum(1 for tr in (latest.tracks if latest else ()) if tr.region == region))

    def on_clock(self, sample: zenoh.Sample) -> None:
        """A tick: a region gone for DEPARTED_HOLD s of event time past the first tick after it
        went (plus what the replays may have in flight) is given up, its tracks marked stale. Until
        then the merge waits for it: replay holds event time while a restarted one comes back."""
        tick = self.decode(Clock, sample)
        if tick is None:
            return
        lead = self.guard.lead
        declared = {r: self.merge.final.get(r, -math.inf) for r in self.merge.live}
        for region in self.departures.silent(declared, tick.t, lead):
            self.went(region)
        for region in self.departures.tick(tick.t, lead):
            self.emit(self.merge.lost(region))
        for region, t in self.check.retry(self.merge.live):
            self.emit(self.merge.progress(region, t))
        self.check.counts.forget_before(self.merge.emitted_up_to)
        self.report_progress(tick.t, sent=self.sent)

    def emit(self, merged: list[TrackSet]) -> None:
        for tracks in merged:
            self.tracks.add(tracks)
            self.publish(self.tracks.key, tracks)
            self.sent += 1
        if merged:
            self.checkpoints.save_throttled(merged[-1].t, lambda: MergeCheckpoint(
                self.merge, self.tracks.latest, list(self.tracks.recent), self.check.counts))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.merge", description=__doc__.splitlines()[0])
    parser.add_argument("--gate", type=positive_float, default=MergeConfig.gate,
                        help="two regions' tracks closer than this are one target, m (default: %(default)s)")
    parser.add_argument("--handover", type=positive_float, default=MergeConfig.handover,
                        help="a track that ended this recently can be continued by another region's, s "
                        "(default: %(default)s)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(Merge, build_parser))
