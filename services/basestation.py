"""Base station: the network's results.

``python -m bintrack.services.basestation --tracker NAME``:

* for a tracker the peer agents run (the baselines, arc, sector) it orders the peers'
  ``LocalEstimate``s by event time (watermark = the least of the clock tick − ``--lateness`` and
  the peer agents' released watermarks, ties by node id)
  and publishes each as the single-target ``TrackSet`` (track 0) on ``tracks``;
* for a base-station tracker it runs the tracker itself on the network's transitions (in event
  time, gaps repaired like a peer agent) and publishes what it gives: ``fusion/reports`` and
  ``tracks`` (mcmcda), ``laser/objects`` (adaptive-basis), ``motion/velocity`` (velocity-plane,
  svm, ppr, motion-rw). With ``--lag N`` (mcmcda) each scan's ``tracks`` come N scans late,
  smoothed (:mod:`bintrack.trackers.multi.fixed_lag`); the reports still at once.

With ``--region NAME`` (a region of the deployment's ``regions``) it takes only the transitions
of that region's sensors and of those within a border band three sensing ranges wide
(``--band``), subscribing to those sensors' transitions only (with the default band; the
agents count them for it, DESIGN §11), and publishes on ``region/<NAME>/{fusion/reports,tracks}``
(local track ids) with ``region/<NAME>/progress`` after each tick and a ``region/<NAME>/alive``
token; the ``merge`` service makes the network's ``tracks`` of the regions'.

The ``tracks`` queryable returns the latest ``TrackSet`` (``tracks?after=T``: the recent ones
after T, for a recorder that restarted or lost its router).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

import zenoh

from bintrack.argtypes import non_negative_float, positive_float
from bintrack.errors import CommandError
from bintrack.live.estimate_check import estimate_problem
from bintrack.live.service import log, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.track_history import TrackHistory
from bintrack.live.transition_intake import TransitionConsumer
from bintrack.bus_payloads import Clock, LineObjectEstimate, LocalEstimate, PositionReports, TrackSet, VelocityEstimate
from bintrack.message_base import Message
from bintrack.services.estimate_relay import EstimateRelay
from bintrack.trackers import TRACKER_NAMES, check_options, make_tracker, runs_on_peers
from bintrack.trackers.tracker_arguments import add_tracker_arguments, tracker_options


class Basestation(TransitionConsumer):
    """The base station of a tracker it runs itself (mcmcda, adaptive-basis, the closer/farther
    estimators), on the transitions of the network or of one region."""

    name = "basestation"

    def __init__(self, args):
        super().__init__(args)
        self.tracks = TrackHistory(self.keys.tracks())  # a region's keys once the region is known good
        self.reports_key = self.keys.fusion_reports()
        self.nodes: set[str] = set()
        self.warned = 0  # tracker warnings logged so far

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        network, region = deployment, self.args.region
        options = tracker_options(self.args)
        try:
            check_options(self.args.tracker, options, regional=region is not None)
        except ValueError as exc:
            raise CommandError(str(exc)) from None
        if region is not None:
            from bintrack.regions import RegionMap  # shapely: loaded only for a region

            try:
                deployment = RegionMap(network).sub_deployment(region, self.args.band)
            except ValueError as exc:
                raise CommandError(str(exc)) from None
            self.tracks.key, self.reports_key = self.keys.region_tracks(region), self.keys.region_reports(region)
            self._declared.append(self.session.liveliness().declare_token(self.keys.region_alive(region)))
            log.info("%s: region %s, %d of the %d sensors (border band included)", self.name, region,
                     len(deployment.sensors), len(network.sensors))
        self.serve(self.tracks.key, self.tracks.answer)
        try:
            # live, the peer agents run the estimates' tracker
            tracker = make_tracker(self.args.tracker, deployment, replace(options, estimates=None))
        except ValueError as exc:
            raise CommandError(str(exc)) from None
        if options.lag is not None:
            log.info("%s: each scan's tracks given %d scans late, smoothed (--lag)", self.name, options.lag)
        peers = ("peer_agent",) if self.args.estimates is not None else ()
        # a region's base station hears only the transitions it takes, ordered by the agents' counts of
        # them, which are made for the default band (DESIGN §11); else the network's, in arrival order
        narrow = region is not None and self.args.band is None and not peers
        self.start_intake(deployment, tracker, upstream=("sensor_agent", *peers), network=network,
                          order_by=region if narrow else None)
        if self.args.estimates is not None:
            self.nodes = set(deployment.by_id())
            self.subscribe(self.keys.estimate(), self.on_peer_report)

    def on_peer_report(self, sample: zenoh.Sample) -> None:
        """A peer's estimate, to join the fused reports of its scan (mcmcda --estimates)."""
        estimate = self.decode(LocalEstimate, sample)
        if estimate is None:
            return
        key = str(sample.key_expr)
        problem = estimate_problem(estimate, key, self.keys, self.nodes, self.args.estimates)
        if problem:
            self.bad.report(key, problem)
            return
        tracker = self.driver.tracker
        late = tracker.late_estimates
        tracker.update(estimate)  # it joins the reports of its scan: no output until that scan
        if tracker.late_estimates > late:
            self.bad.report(key, f"late: estimate at t={estimate.t} is behind the scans already tracked")

    def emit(self, outputs: list[Message]) -> None:
        for out in outputs:
            if isinstance(out, TrackSet):
                self.tracks.add(out)
                self.publish(self.tracks.key, out)
                self.sent += 1
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
            # and says how many scans it published up to there: the merge holds the report until
            # it has them all (a put just after the router came back can be dropped)
            final = math.nextafter(self.released, -math.inf)
            self.publish(self.keys.region_progress(self.args.region), Clock(t=final, sent=self.sent))
        super().report_progress(t, sent, released)

    def log_tracker_warnings(self) -> None:
        """Log each warning the tracker has raised (adaptive-basis: a frame misfit) once."""
        warnings = getattr(self.driver.tracker, "warnings", ())
        for warning in warnings[self.warned:]:
            log.warning("%s", warning)
        self.warned = len(warnings)

    def checkpoint_extra(self):
        # the track sets served too (a recorder restarted with this service fetches them), and
        # how many were published (the merge counts a region's scans by it)
        return self.tracks.latest, list(self.tracks.recent), self.sent

    def restore_extra(self, extra) -> None:
        if not isinstance(extra, tuple):  # a checkpoint of an earlier version: the latest only
            self.tracks.latest = extra
            return
        self.tracks.restore(*extra[:2])
        if len(extra) > 2:
            self.sent = extra[2]


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
                        "(default: three of each sensor's sensing ranges)")
    add_tracker_arguments(parser)
    parser.add_argument("--id", help="instance id (default: host-pid)")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    args = build_parser().parse_args()
    sys.exit(service_main(EstimateRelay if runs_on_peers(args.tracker) else Basestation, build_parser))
