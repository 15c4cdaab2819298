"""Base station: the network's results.

``python -m bintrack.services.basestation --tracker NAME``:

* for a tracker the peer agents run (the baselines, arc, sector) it orders the peers'
  ``LocalEstimate``s by event time (watermark = the least of the clock tick − ``--lateness`` and
  the peer agents' released watermarks, ties by node id)
  and publishes each as the single-target ``TrackSet`` (track 0) on ``tracks``;
* for a base-station tracker it runs the tracker itself on the network's transitions (in event
  time, gaps repaired like a peer agent) and publishes what it gives: ``fusion/reports`` and
  ``tracks`` (mcmcda), ``laser/objects`` (adaptive-basis), ``motion/velocity`` (velocity-plane,
  svm, ppr, motion-rw).

With ``--region NAME`` (a region of the deployment's ``regions``) it takes only the transitions
of that region's sensors and of those within a border band two sensing ranges wide
(``--band``), and publishes on ``region/<NAME>/{fusion/reports,tracks}`` (local track ids) with
``region/<NAME>/progress`` after each tick and a ``region/<NAME>/alive`` token; the ``merge``
service makes the network's ``tracks`` of the regions'.

The ``tracks`` queryable returns the latest ``TrackSet`` (``tracks?after=T``: the recent ones
after T, for a recorder that restarted or lost its router).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import deque
from dataclasses import replace
from operator import attrgetter

import zenoh

from bintrack.argtypes import non_negative_float, positive_float
from bintrack.live.bus import add_bus_arguments, log, service_main
from bintrack.live.tracks_queryable import answer_tracks_query
from bintrack.errors import CommandError
from bintrack.messages import (Clock, LineObjectEstimate, LocalEstimate, Message, PositionReports, Track, TrackSet,
                               VelocityEstimate)
from bintrack.ordering import ReorderBuffer
from bintrack.regions import RegionMap
from bintrack.pipeline import SINGLE_TARGET_TRACK
from bintrack.trackers.tracker_arguments import add_tracker_arguments, tracker_options
from bintrack.trackers import TRACKER_NAMES, check_options, make_tracker, runs_on_peers
from bintrack.live.transition_intake import TransitionConsumer


TRACKS_HISTORY = 1024  # recent track sets kept for the ``tracks?after=T`` queryable
RECENT_PER_KEY = 64  # payloads remembered per node to drop the ones a restarted peer agent sends again


class Basestation(TransitionConsumer):
    name = "basestation"

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.latest: TrackSet | None = None
        self.history: deque[TrackSet] = deque(maxlen=TRACKS_HISTORY)
        network, region = deployment, self.args.region
        if region is not None:
            if runs_on_peers(self.args.tracker):
                raise CommandError(f"--region needs a base-station tracker (mcmcda), not {self.args.tracker}")
            try:
                deployment = RegionMap(network).sub_deployment(region, self.args.band)
            except ValueError as exc:
                raise CommandError(str(exc)) from None
            self.tracks_key, self.reports_key = self.keys.region_tracks(region), self.keys.region_reports(region)
            self._declared.append(self.session.liveliness().declare_token(self.keys.region_alive(region)))
            log.info("%s: region %s, %d of the %d sensors (border band included)", self.name, region,
                     len(deployment.sensors), len(network.sensors))
        else:
            self.tracks_key, self.reports_key = self.keys.tracks(), self.keys.fusion_reports()
        self.serve(self.tracks_key, self.on_tracks_query)
        if not runs_on_peers(self.args.tracker):
            options = tracker_options(self.args)
            try:
                check_options(self.args.tracker, options)
                # live, the peer agents run the estimates' tracker
                tracker = make_tracker(self.args.tracker, deployment, replace(options, estimates=None))
            except ValueError as exc:
                raise CommandError(str(exc)) from None
            peers = ("peer_agent",) if self.args.estimates is not None else ()
            self.start_intake(deployment, tracker, upstream=("sensor_agent", *peers), network=network)
            if self.args.estimates is not None:
                self.subscribe(self.keys.estimate(), self.on_peer_report)
            return
        self.sensors = deployment.by_id()
        self.estimates: ReorderBuffer[LocalEstimate] = ReorderBuffer(tiebreak=attrgetter("node"))
        self.recent_estimates: dict[str, deque[bytes]] = {}  # per node, its last estimates' payloads
        self.subscribe(self.keys.estimate(), self.on_estimate)
        self.subscribe(self.keys.clock(), self.on_estimate_clock)
        self.follow_upstream(("peer_agent",))
        self.follow_end_of_stream(["peer_agent"], lambda t: self.emit(self.relayed(self.estimates.release_all())))

    def valid_estimate(self, sample: zenoh.Sample, tracker: str) -> LocalEstimate | None:
        """The decoded estimate of ``sample`` if it is of a known node, on its own key and by
        ``tracker``; else None, reported."""
        estimate = self.decode(LocalEstimate, sample)
        if estimate is None:
            return None
        key = str(sample.key_expr)
        if estimate.node not in self.sensors or key != self.keys.estimate(estimate.node):
            self.bad.report(key, f"estimate of unknown or mismatched node {estimate.node!r}")
            return None
        if estimate.tracker != tracker:
            self.bad.report(key, f"estimate of tracker {estimate.tracker!r}, this base station runs {tracker!r}")
            return None
        return estimate

    def on_estimate(self, sample: zenoh.Sample) -> None:
        estimate = self.valid_estimate(sample, self.args.tracker)
        if estimate is None:
            return
        recent = self.recent_estimates.setdefault(estimate.node, deque(maxlen=RECENT_PER_KEY))
        payload = sample.payload.to_bytes()
        if payload in recent:  # sent again by a peer agent that restarted from its checkpoint
            self.bad.report(str(sample.key_expr), f"duplicate: estimate at t={estimate.t} seen already")
            return
        if self.estimates.push(estimate):
            recent.append(payload)
        else:
            self.bad.report(str(sample.key_expr),
                            f"late: t={estimate.t} is behind the watermark {self.released:g} s (lateness {self.args.lateness} s)")

    def on_peer_report(self, sample: zenoh.Sample) -> None:
        """A peer's estimate, to join the fused reports of its scan (mcmcda --estimates)."""
        estimate = self.valid_estimate(sample, self.args.estimates)
        if estimate is not None and not self.driver.tracker.add_estimate(estimate):
            self.bad.report(str(sample.key_expr), f"late: estimate at t={estimate.t} is behind the scans already tracked")

    def on_estimate_clock(self, sample: zenoh.Sample) -> None:
        tick = self.read(Clock, sample)
        if tick is None:
            return
        self.last_tick = max(self.last_tick, tick.t)
        self.release(report=False)
        self.report_released()

    def advance(self, watermark: float) -> list[Message]:
        if runs_on_peers(self.args.tracker):  # relaying the peers' estimates, in event-time order
            return self.relayed(self.estimates.release(watermark))
        return super().advance(watermark)

    def relayed(self, estimates: list[LocalEstimate]) -> list[TrackSet]:
        """Each estimate as the single-target track set."""
        return [TrackSet(t=e.t, tracker=self.args.tracker,
                         tracks=[Track(track=SINGLE_TARGET_TRACK, x=e.x, y=e.y, vx=e.vx, vy=e.vy)])
                for e in estimates]

    def emit(self, outputs: list[Message]) -> None:
        for out in outputs:
            if isinstance(out, TrackSet):
                self.latest = out
                self.history.append(out)
                self.publish(self.tracks_key, out)
            elif isinstance(out, PositionReports):
                self.publish(self.reports_key, out)
            elif isinstance(out, LineObjectEstimate):
                self.publish(self.keys.laser_objects(), out)
                self.log_tracker_warnings()
            elif isinstance(out, VelocityEstimate):
                self.publish(self.keys.motion_velocity(), out)

    def report_progress(self, t: float, sent: int | None = None, released: float | None = None) -> None:
        if self.args.region is not None and math.isfinite(self.released):
            # the merge's watermark: advance(w) emitted the scans strictly before the watermark
            # w released to (the tick less the lateness, held back by upstream progress)
            final = math.nextafter(self.released, -math.inf)
            self.publish(self.keys.region_progress(self.args.region), Clock(t=final))
        super().report_progress(t, sent, released)

    def log_tracker_warnings(self) -> None:
        """Log each warning the tracker has raised (adaptive-basis: a frame misfit) once."""
        warnings = getattr(self.driver.tracker, "warnings", ())
        for warning in warnings[getattr(self, "_warned", 0):]:
            log.warning("%s", warning)
        self._warned = len(warnings)

    def checkpoint_extra(self):
        return self.latest

    def restore_extra(self, extra) -> None:
        self.latest = extra

    def on_tracks_query(self, query: zenoh.Query) -> None:
        answer_tracks_query(query, self.tracks_key, self.latest, self.history)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.basestation", description=__doc__.splitlines()[0])
    parser.add_argument("--tracker", required=True, choices=TRACKER_NAMES, help="the tracker whose results to publish")
    parser.add_argument("--lateness", type=non_negative_float, default=0.0,
                        help="extra event-time hold behind the clock tick, s; the watermark also waits for the "
                        "upstream agents' progress, which keeps results exact without it (default: %(default)s)")
    parser.add_argument("--speed", type=positive_float,
                        help="mcmcda: the fastest target; motion-rw: the initial speed guess; units/s")
    parser.add_argument("--region", metavar="NAME", help="serve this region of the deployment's regions only")
    parser.add_argument("--band", type=positive_float, metavar="D",
                        help="with --region: width of the border band whose sensors are taken too, units "
                        "(default: two of each sensor's sensing ranges)")
    add_tracker_arguments(parser)
    parser.add_argument("--id", help="instance id (default: host-pid)")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(Basestation, build_parser))
