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
import sys
from collections import deque

import zenoh

from bintrack.argtypes import positive_float
from bintrack.keys import parse_key
from bintrack.live.bus import Service, add_bus_arguments, log, service_main
from bintrack.live.tracks_queryable import answer_tracks_query
from bintrack.messages import Clock, MessageError, TrackSet, decode
from bintrack.regions import RegionMap
from bintrack.trackers.multi.region_merge import MergeConfig, RegionMerge

TRACKS_HISTORY = 1024  # recent merged track sets kept for the ``tracks?after=T`` queryable


class Merge(Service):
    name = "merge"

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.regions = RegionMap(deployment)
        self.merge = RegionMerge(self.regions, MergeConfig(gate=self.args.gate, handover=self.args.handover))
        self.latest: TrackSet | None = None
        self.history: deque[TrackSet] = deque(maxlen=TRACKS_HISTORY)
        resumed = self.resume()
        self.serve(self.keys.tracks(), self.on_tracks_query)
        self.subscribe(self.keys.region_tracks(), self.on_region_tracks)
        if resumed:
            # the scans published while it was gone, before any progress report can release them
            fetched = await asyncio.to_thread(self.fetch_region_tracks, self.merge.emitted_up_to)
            for region, tracks in fetched:
                self.merge.add(region, tracks)
            log.info("%s: resumed after t=%g s; %d region scans published since fetched from the base stations",
                     self.name, self.merge.emitted_up_to, len(fetched))
        self.subscribe(self.keys.region_progress(), self.on_region_progress)
        self.subscribe(self.keys.clock(), self.on_clock)
        self._declared.append(self.session.liveliness().declare_subscriber(
            self.keys.region_alive(), self.inbox.callback(self.on_region_alive), history=True))
        self.follow_end_of_stream(["basestation"], lambda t: self.emit(self.merge.finish()))
        log.info("%s: merging regions %s", self.name, ", ".join(self.regions.names))

    def resume(self) -> bool:
        """Take back the checkpoint of an earlier instance, if there is one; whether there was."""
        saved = self.load_checkpoint()
        if saved is None:
            return False
        try:
            merge, latest, history = saved
            if not isinstance(merge, RegionMerge) or sorted(merge.regions.names) != sorted(self.regions.names):
                raise ValueError("another deployment's regions")
        except (TypeError, ValueError) as exc:
            log.warning("%s: checkpoint not of this version or deployment (%s); starting afresh", self.name, exc)
            return False
        self.merge, self.latest = merge, latest
        self.history.extend(history)
        return True

    def fetch_region_tracks(self, after: float) -> list[tuple[str, TrackSet]]:
        """(region, scan) of every scan later than ``after`` (s) that the regions' base stations
        still hold (their ``tracks?after=T`` queryables); blocking, call off the loop."""
        fetched = []
        for region in self.regions.names:
            key = self.keys.region_tracks(region)
            for payload in self.query(f"{key}?after={after!r}", timeout=2.0):
                try:
                    fetched.append((region, decode(TrackSet, payload)))
                except MessageError as exc:
                    self.bad.report(key, exc.reason)
        return fetched

    def region_of(self, sample: zenoh.Sample) -> str | None:
        key = str(sample.key_expr)
        region = parse_key(key).region
        if region not in self.regions.shapes:
            self.bad.report(key, f"unknown region {region!r}")
            return None
        return region

    def on_region_tracks(self, sample: zenoh.Sample) -> None:
        region = self.region_of(sample)
        tracks = self.decode(TrackSet, sample) if region is not None else None
        if tracks is not None:
            self.emit(self.merge.add(region, tracks))

    def on_region_progress(self, sample: zenoh.Sample) -> None:
        region = self.region_of(sample)
        tick = self.decode(Clock, sample) if region is not None else None
        if tick is not None:
            self.emit(self.merge.progress(region, tick.t))

    def on_region_alive(self, sample: zenoh.Sample) -> None:
        region = self.region_of(sample)
        if region is None:
            return
        if sample.kind == zenoh.SampleKind.PUT:
            if region in self.merge.stale:
                log.warning("%s: region %s's base station is back", self.name, region)
            self.merge.back(region)
            return
        shown = sum(1 for tr in (self.latest.tracks if self.latest else ()) if tr.region == region)
        log.warning("%s: region %s's base station is gone; its %d tracks are marked stale", self.name, region, shown)
        self.emit(self.merge.lost(region))

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.decode(Clock, sample)
        if tick is not None:
            self.report_progress(tick.t)

    def emit(self, merged: list[TrackSet]) -> None:
        for tracks in merged:
            self.latest = tracks
            self.history.append(tracks)
            self.publish(self.keys.tracks(), tracks)
        if merged:
            self.save_checkpoint_throttled(merged[-1].t, lambda: (self.merge, self.latest, list(self.history)))

    def on_tracks_query(self, query: zenoh.Query) -> None:
        answer_tracks_query(query, self.keys.tracks(), self.latest, self.history)


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
