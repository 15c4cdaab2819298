"""Peer agent: hosts the nodes' trackers (arc, sector and the paper-001 baselines).

``python -m bintrack.services.peer_agent --tracker NAME [--sensors ID,…] [--region NAME]`` hears the
transitions of the network, repairs ``seq`` gaps from the sensors' ``state`` queryables, feeds
the tracker in event-time order (watermark = the least of the clock tick − ``--lateness`` and the
sensor agents' progress, ties by sensor id)
and publishes each hosted node's ``LocalEstimate`` on ``peer/<node>/estimate``; its queryable
there answers ``?after=T`` with the recent estimates after T (for a restarted relay).
"""

from __future__ import annotations

import argparse
import sys
from collections import deque

import zenoh

from bintrack.argtypes import non_negative_float, positive_float
from bintrack.live.checkpoint import CHECKPOINT_SPAN, resume_span
from bintrack.live.service import service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.bus_payloads import LocalEstimate
from bintrack.errors import CommandError
from bintrack.trackers.tracker_arguments import add_tracker_arguments, tracker_options
from bintrack.trackers import PEER_TRACKERS, make_tracker
from bintrack.live.transition_intake import TransitionConsumer
from bintrack.message_codec import encode

# s of event time of estimates kept for a restarted relay at least (resume_span when replay's lead
# asks for more): a relay's --lateness holds its released watermark back further
ESTIMATE_SPAN = 4 * CHECKPOINT_SPAN


class EstimateHistory:
    """The estimates published lately, oldest first: what a restarted relay may ask for."""

    def __init__(self):
        self.recent: deque[LocalEstimate] = deque()

    def add(self, estimate: LocalEstimate, lead: float) -> None:
        """Keep ``estimate``; forget those more than ESTIMATE_SPAN s, or
        :func:`~bintrack.live.checkpoint.resume_span` of replay's ``lead`` (s), older."""
        self.recent.append(estimate)
        oldest = estimate.t - max(ESTIMATE_SPAN, resume_span(lead))
        while self.recent and self.recent[0].t < oldest:
            self.recent.popleft()

    def after(self, t: float) -> list[LocalEstimate]:
        return [e for e in self.recent if e.t > t]


class PeerAgent(TransitionConsumer):
    name = "peer_agent"

    def __init__(self, args):
        super().__init__(args)
        self.estimates = EstimateHistory()  # kept in the checkpoint: a relay restarted with us asks for them

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.hosted = set(self.args.sensors.split(",")) if self.args.sensors else None
        network = deployment
        if self.args.region is not None:
            from bintrack.regions import RegionMap  # shapely: loaded only for a region

            regions = RegionMap(deployment)
            try:
                own = set(regions.own_sensors(self.args.region))
            except ValueError as exc:
                raise CommandError(f"--region: {exc}") from None
            self.hosted = own if self.hosted is None else self.hosted & own
            # a node's neighbours are within two sensing ranges: that band's transitions are needed
            deployment = regions.sub_deployment(self.args.region)
        try:
            tracker = make_tracker(self.args.tracker, deployment, tracker_options(self.args))
        except ValueError as exc:
            raise CommandError(str(exc)) from None
        self.start_intake(deployment, tracker, network=network)
        self.serve(self.keys.estimate(), self.answer_estimates)

    def emit(self, outputs) -> None:
        for estimate in outputs:
            if isinstance(estimate, LocalEstimate) and (self.hosted is None or estimate.node in self.hosted):
                self.estimates.add(estimate, self.guard.lead)
                self.publish(self.keys.estimate(estimate.node), estimate)
                self.sent += 1

    def answer_estimates(self, query: zenoh.Query) -> None:
        """``peer/*/estimate?after=T``: each estimate kept (:class:`EstimateHistory`) published after T
        (s), in order: what a restarted relay asks for."""
        try:
            after = float(query.parameters.get("after", "-inf"))
        except ValueError:
            query.reply_err(b"after must be a number of seconds")
            return
        for estimate in self.estimates.after(after):
            key = self.keys.estimate(estimate.node)
            if zenoh.KeyExpr(key).intersects(query.key_expr):
                query.reply(key, encode(estimate))

    def checkpoint_extra(self):
        return list(self.estimates.recent)

    def restore_extra(self, extra) -> None:
        self.estimates.recent.extend(extra or ())


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.peer_agent", description=__doc__.splitlines()[0])
    parser.add_argument("--tracker", required=True, choices=PEER_TRACKERS, help="tracker the nodes run")
    parser.add_argument("--sensors", metavar="ID,…", help="nodes whose estimates this agent publishes (default: all)")
    parser.add_argument("--region", metavar="NAME",
                        help="publish the estimates of the nodes placed in this region (with --sensors: those of "
                        "them in it); takes the transitions of the nodes within two sensing ranges of it")
    parser.add_argument("--speed", type=positive_float, help="target speed, units/s, for trackers that use one")
    add_tracker_arguments(parser)
    parser.add_argument("--lateness", type=non_negative_float, default=0.0,
                        help="extra event-time hold behind the clock tick, s; the watermark also waits for the "
                        "sensor agents' progress, which keeps results exact without it (default: %(default)s)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(PeerAgent, build_parser))
