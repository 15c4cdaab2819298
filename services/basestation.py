"""Base station: the network's tracks (and, as their issues land, fusion and MCMCDA).

``python -m bintrack.services.basestation --tracker NAME``: for a tracker the peer agents run
(the baselines, arc, sector) it orders the peers' ``LocalEstimate``s by event time
(watermark = clock tick − ``--lateness``, ties by node id) and publishes each as the
single-target ``TrackSet`` (track 0) on ``tracks``; the ``tracks`` queryable returns the latest.
"""

from __future__ import annotations

import argparse
import sys
from operator import attrgetter

import zenoh

from bintrack.argtypes import positive_float
from bintrack.bus import Service, add_bus_arguments, service_main
from bintrack.messages import Clock, LocalEstimate, Track, TrackSet, encode
from bintrack.ordering import ReorderBuffer
from bintrack.pipeline import SINGLE_TARGET_TRACK
from bintrack.trackers import TRACKER_NAMES


class Basestation(Service):
    name = "basestation"

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.sensors = deployment.by_id()
        self.estimates: ReorderBuffer[LocalEstimate] = ReorderBuffer(tiebreak=attrgetter("node"))
        self.latest: TrackSet | None = None
        self.subscribe(self.keys.estimate(), self.on_estimate)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.serve(self.keys.tracks(), self.on_tracks_query)
        self.follow_end_of_stream(["peer_agent"], lambda t: self.emit(self.estimates.release_all()))

    def on_estimate(self, sample: zenoh.Sample) -> None:
        estimate = self.decode(LocalEstimate, sample)
        if estimate is None:
            return
        key = str(sample.key_expr)
        if estimate.node not in self.sensors or key != self.keys.estimate(estimate.node):
            self.bad.report(key, f"estimate of unknown or mismatched node {estimate.node!r}")
            return
        if estimate.tracker != self.args.tracker:
            self.bad.report(key, f"estimate of tracker {estimate.tracker!r}, this base station runs {self.args.tracker!r}")
            return
        if not self.estimates.push(estimate):
            self.bad.report(key, f"late: t={estimate.t} is behind the watermark (lateness {self.args.lateness} s)")

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.decode(Clock, sample)
        if tick is None:
            return
        self.emit(self.estimates.release(tick.t - self.args.lateness))
        self.report_progress(tick.t)

    def emit(self, estimates: list[LocalEstimate]) -> None:
        for e in estimates:
            self.latest = TrackSet(t=e.t, tracker=self.args.tracker,
                                   tracks=[Track(track=SINGLE_TARGET_TRACK, x=e.x, y=e.y, vx=e.vx, vy=e.vy)])
            self.publish(self.keys.tracks(), self.latest)

    def on_tracks_query(self, query: zenoh.Query) -> None:
        if self.latest is not None:
            query.reply(self.keys.tracks(), encode(self.latest))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.basestation", description=__doc__.splitlines()[0])
    parser.add_argument("--tracker", required=True, choices=TRACKER_NAMES, help="the tracker whose results to publish")
    parser.add_argument("--lateness", type=positive_float, default=2.0,
                        help="event-time lateness bound of estimates, s (default: %(default)s; "
                        "at least the peer agents' lateness plus one clock period)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(Basestation, build_parser))
