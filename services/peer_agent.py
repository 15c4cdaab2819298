"""Peer agent: hosts the nodes' trackers (arc, sector and the paper-001 baselines).

``python -m bintrack.services.peer_agent --tracker NAME [--sensors ID,…]`` hears the
transitions of the network, repairs ``seq`` gaps from the sensors' ``state`` queryables, feeds
the tracker in event-time order (watermark = clock tick − ``--lateness``, ties by sensor id)
and publishes each hosted node's ``LocalEstimate`` on ``peer/<node>/estimate``.
"""

from __future__ import annotations

import argparse
import math
import sys

import zenoh

from bintrack.argtypes import positive_float
from bintrack.bus import Service, add_bus_arguments, log, service_main
from bintrack.messages import Clock, LocalEstimate, MessageError, SensorState, Transition, decode
from bintrack.pipeline import TrackerDriver
from bintrack.trackers import TRACKER_NAMES, make_tracker
from bintrack.keys import parse_key
from bintrack.transitions import SequenceCheck, SourceCheck


class PeerAgent(Service):
    name = "peer_agent"

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.sensors = deployment.by_id()
        self.hosted = set(self.args.sensors.split(",")) if self.args.sensors else None
        self.driver = TrackerDriver(make_tracker(self.args.tracker, deployment, speed=self.args.speed))
        self.sequence = SequenceCheck()
        self.sources = SourceCheck()
        self.fetched: set[tuple[str | None, int | None]] = set()  # fetched from state; may still arrive
        self.latest: dict[str, float] = {}  # event time of the newest transition taken, per sensor
        self.restarts: set[str | None] = set()  # sources seen counting from 1 again (logged once)
        self.subscribe(self.keys.transition(), self.on_transition)
        self.subscribe(self.keys.progress("sensor_agent"), self.on_agent_progress)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.follow_end_of_stream(["sensor_agent"], self.on_finish)

    def on_transition(self, sample: zenoh.Sample) -> None:
        transition = self.decode(Transition, sample)
        if transition is None:
            return
        key = str(sample.key_expr)
        if transition.sensor not in self.sensors or key != self.keys.transition(transition.sensor):
            self.bad.report(key, f"transition of unknown or mismatched sensor {transition.sensor!r}")
            return
        self.follow_restart(transition)
        kind = self.sequence.classify(transition)
        if kind == "duplicate" or self.sources.seen(transition):
            if (transition.source, transition.source_seq) in self.fetched:
                self.fetched.discard((transition.source, transition.source_seq))  # fetched before it arrived
            else:
                self.bad.report(key, f"duplicate: seq {transition.seq} seen already")
            return
        if kind == "gap":
            self.repair(transition)
        self.take(transition)

    def follow_restart(self, transition: Transition) -> None:
        """A restarted sensor agent counts ``seq`` (and, under the same id, ``source_seq``) from
        1 again: its transitions look old to the counters although they are newer in event
        time than anything taken of their sensor. Forget the old counts, so that they are taken
        (a genuine duplicate is never newer than what was taken)."""
        old = self.sequence.classify(transition) == "duplicate" or self.sources.seen(transition)
        if not old or transition.t <= self.latest.get(transition.sensor, -math.inf):
            return
        self.sequence.last.pop(transition.sensor, None)
        if self.sources.seen(transition):
            self.sources.forget(transition.source)
        if transition.source not in self.restarts:
            self.restarts.add(transition.source)
            log.info("%s: %s counts its transitions from 1 again (a sensor agent restarted); following it",
                     self.name, transition.source or transition.sensor)

    def repair(self, transition: Transition) -> None:
        """Fetch the transitions lost before ``transition`` from its sensor's state queryable."""
        since = self.sequence.last.get(transition.sensor, 0)
        selector = f"{self.keys.state(transition.sensor)}?since={since}"
        if not self.fetch_missed(selector, before=transition):
            log.warning("%s: seq gap before %d of %s could not be repaired (no state reply)", self.name,
                        transition.seq, transition.sensor)

    def on_agent_progress(self, sample: zenoh.Sample) -> None:
        """A sensor agent says how many transitions it has sent: fetch any that did not arrive."""
        report = self.decode(Clock, sample)
        if report is None or report.sent is None:
            return
        source = parse_key(str(sample.key_expr)).instance
        first = self.sources.first_missing(source, report.sent)
        if first is not None:
            selector = f"{self.keys.state()}?source={source};after={first - 1}"
            if not self.fetch_missed(selector, upto=report.sent):
                log.warning("%s: %s sent transitions that were lost and could not be fetched", self.name, source)

    def fetch_missed(self, selector: str, before: Transition | None = None, upto: int | None = None) -> bool:
        """Take the ``missed`` transitions of every state reply to ``selector``, oldest first:
        those before ``before`` (same sensor), or with source_seq ≤ ``upto``.

        The get blocks the loop on purpose: the fetched transitions must be taken before the
        next clock tick moves the watermark past them. A reply takes milliseconds; only a
        sensor agent that is gone costs the timeout.
        """
        missed: list[Transition] = []
        replied = False
        for payload in self.query(selector, timeout=2.0):
            try:
                state = decode(SensorState, payload)
            except MessageError as exc:
                self.bad.report(selector, exc.reason)
                continue
            replied = True
            missed.extend(state.missed)
        for transition in sorted(missed, key=lambda tr: (tr.sensor, tr.seq)):
            if before is not None and (transition.sensor != before.sensor or transition.seq >= before.seq):
                continue
            if upto is not None and transition.source_seq > upto:
                continue
            if self.sequence.classify(transition) != "duplicate" and not self.sources.seen(transition):
                self.take(transition)
                self.fetched.add((transition.source, transition.source_seq))
        return replied

    def take(self, transition: Transition) -> None:
        self.sequence.accept(transition)
        self.sources.accept(transition)
        self.latest[transition.sensor] = max(transition.t, self.latest.get(transition.sensor, -math.inf))
        if not self.driver.push(transition):
            self.bad.report(self.keys.transition(transition.sensor),
                            f"late: t={transition.t} is behind the watermark (lateness {self.args.lateness} s)")

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.decode(Clock, sample)
        if tick is None:
            return
        self.emit(self.driver.advance(tick.t - self.args.lateness))
        self.report_progress(tick.t)

    def on_finish(self, t: float) -> None:
        self.emit(self.driver.finish())
        if self.fetched:
            log.info("%s: %d transitions that never arrived were fetched from the sensors' state",
                     self.name, len(self.fetched))

    def emit(self, outputs) -> None:
        for estimate in outputs:
            if isinstance(estimate, LocalEstimate) and (self.hosted is None or estimate.node in self.hosted):
                self.publish(self.keys.estimate(estimate.node), estimate)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.peer_agent", description=__doc__.splitlines()[0])
    parser.add_argument("--tracker", required=True, choices=TRACKER_NAMES, help="tracker the nodes run")
    parser.add_argument("--sensors", metavar="ID,…", help="nodes whose estimates this agent publishes (default: all)")
    parser.add_argument("--speed", type=positive_float, help="target speed, units/s, for trackers that use one")
    parser.add_argument("--lateness", type=positive_float, default=1.0,
                        help="event-time lateness bound of transitions, s (default: %(default)s)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(PeerAgent, build_parser))
