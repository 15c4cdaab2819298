"""Sensor agent: raw samples of its sensors → transitions (papers 000, 001).

``python -m bintrack.services.sensor_agent [--sensors ID,…] [--region NAME]`` hosts any number
of a deployment's sensors (all by default; those placed in a region with ``--region``), handled
in arrival order by the one subscriber's handler (the clock tick after a sample is acknowledged
once the sample is handled). With ``--region`` it subscribes to its own sensors' raw keys, the
clock and the end of stream only, and holds a tick until the raw samples replay counts for its
region before it are in (:mod:`~bintrack.live.tick_order`). With a deployment that has
regions, its progress reports say in ``sent_to`` how many transitions it sent of the sensors
each region's base station takes. A sensor publishes a ``Transition`` on ``sensor/<id>/transition``
only when its status changes, and answers its ``sensor/<id>/state`` queryable with its status, last ``seq`` and, for a query
``…/state?since=N``, the recent transitions after seq N so a receiver can repair a gap.
"""

from __future__ import annotations

import argparse
import sys

import zenoh

from bintrack.live.checkpoint import SensorAgentCheckpoint
from bintrack.live.raw_intake import RawIntake
from bintrack.live.recent_catchup import RecentCatchUp
from bintrack.live.sensor_hosting import HISTORY_SPAN, HostedSensors
from bintrack.live.service import Service, log, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.tick_order import TickOrder
from bintrack.bus_payloads import Clock, EndOfStream, RawSample
from bintrack.message_codec import encode, is_resent
from bintrack.transition_detector import TransitionDetector


class SensorAgent(Service):
    name = "sensor_agent"

    def __init__(self, args):
        super().__init__(args)
        self.hosts: HostedSensors | None = None
        self.intake: RawIntake | None = None  # the raw samples it hands to them
        self.replay: RecentCatchUp | None = None  # what it knows of replay's raw samples
        self.order: TickOrder | None = None  # a region's agent: its ticks held until their raw samples are in

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        sensors = deployment.by_id()
        regions = None
        if self.args.region is not None or deployment.regions:
            from bintrack.regions import RegionMap  # shapely: loaded only for regions

            try:
                regions = RegionMap(deployment)
                own = regions.own_sensors(self.args.region) if self.args.region is not None else None
            except ValueError as exc:
                log.error("%s: --region: %s", self.name, exc)
                self.exit_status = 2
                self.stop()
                return
        if self.args.region is not None:
            hosted = own
            if self.args.sensors:
                hosted = [s for s in hosted if s in set(self.args.sensors.split(","))]
        else:
            hosted = self.args.sensors.split(",") if self.args.sensors else list(sensors)
        unknown = [s for s in hosted if s not in sensors]
        if unknown:
            log.error("%s: --sensors names ids not in the deployment: %s", self.name, ", ".join(unknown))
            self.exit_status = 2
            self.stop()
            return
        self.hosts = HostedSensors(self.keys, self.instance, TransitionDetector(deployment, hosted), hosted,
                                   self.put, self.bad.report, self.args.lose)
        if deployment.regions:
            self.hosts.count_for(regions.takers(hosted))
        self.replay = RecentCatchUp(self.name, self.keys.recent(), self.hosts, self.query, self.stopping)
        if self.args.region is not None and hosted and hosted == own:
            # its region's keys only: a router forwards it nothing of the other regions (DESIGN §11)
            self.order = TickOrder(self.args.region)
            self.replay.caught_up = self.order.caught_up
            self.narrow([*(self.keys.raw(sid) for sid in hosted), self.keys.clock(), self.keys.eos()])
        checkpoint = self.checkpoints.load(SensorAgentCheckpoint)
        if checkpoint is not None and set(checkpoint.sensors) == set(self.hosts.sensors):
            await self._resume(checkpoint)
        self.intake = RawIntake(self.name, self.keys, sensors, self.hosts, self.bad.report)
        self.subscribe(self.keys.raw(), self.on_raw)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.subscribe(self.keys.eos(), self.on_eos)
        self.serve(self.keys.state(), self.on_state)
        self.follow_presence(self.replay.on_presence)

    async def _resume(self, checkpoint: SensorAgentCheckpoint) -> None:
        """Take the state saved at the last clock tick acknowledged (statuses, counters, and the
        transitions sent lately, which a receiver may still fetch: a kill loses what was still
        in flight, and a consumer killed with it resumes from an older checkpoint), then the raw
        samples replay published after that tick (its ``recent`` queryable): what this sensor
        agent had when it died, and what it missed while it was down (replay holds the clock
        meanwhile)."""
        self.hosts.restore(checkpoint)
        self.replay.acked = checkpoint.tick
        taken = await self.replay.take(newer=False)
        log.info("%s: resumed at the tick t=%g s with %d transitions sent; %d raw samples since taken from replay",
                 self.name, checkpoint.tick, self.hosts.sent, taken)

    async def on_router_back(self) -> None:
        if self.hosts is not None and self.hosts.sensors:
            taken = await self.replay.take(newer=True)
            log.info("%s: %d raw samples published during the outage taken from replay", self.name, taken)

    def on_raw(self, sample: zenoh.Sample) -> None:
        raw = self.read(RawSample, sample)
        if raw is None:
            return
        self.replay.raw_arrived(raw.t)
        attachment = None if sample.attachment is None else sample.attachment.to_bytes()
        if self.order is not None and (attachment is None or not is_resent(attachment)):  # (replay counts it once)
            if not self.order.arrived(raw.sensor, raw.t):
                return  # taken from replay's recent samples before it came
            self.intake.take(str(sample.key_expr), raw, attachment)
            if self.order.held:
                self.acknowledge_ready()
            return
        self.intake.take(str(sample.key_expr), raw, attachment)

    def on_clock(self, sample: zenoh.Sample) -> None:
        """A clock tick is acknowledged once every sample before it has been handled: at once,
        or for a region's agent once its region's samples replay counts before it are in."""
        message = self.read(Clock, sample)
        if message is None:
            return
        if self.order is None or message.sent_to is None:
            self.acknowledge(message)
            return
        self.order.tick(message)
        if self.order.short():
            self.fill()
        self.acknowledge_ready()

    def fill(self) -> None:
        """A tick still lacks raw samples although the next came: take them from replay."""
        received = self.order.count(self.order.held[0])
        catch_up = self.replay.fill()
        if not catch_up.complete:
            log.warning("%s: raw samples before the tick at t=%g s did not arrive and replay does not answer yet; "
                        "the tick is held", self.name, self.order.held[0].t)
            return
        log.info("%s: %d raw samples before the tick at t=%g s had not arrived by the next tick; %d taken from "
                 "replay's recent samples", self.name, self.order.need(self.order.held[0]) - received,
                 self.order.held[0].t, catch_up.taken)

    def acknowledge_ready(self) -> None:
        for tick in self.order.ready():
            self.acknowledge(tick)

    def acknowledge(self, message: Clock) -> None:
        """Acknowledge the clock tick ``message``: every raw sample before it is handled."""
        self.replay.acknowledge(message)
        self.hosts.forget_before(message.t - HISTORY_SPAN)
        self.intake.say_resent()
        self.hosts.trim(message.t, self.guard.lead)
        if self.checkpoints.path is not None:
            self.checkpoints.save(self.hosts.checkpoint(message.t))
        self.report_progress(message.t, sent=self.hosts.sent,
                             sent_to=None if self.hosts.sent_to is None else dict(self.hosts.sent_to))

    def on_eos(self, sample: zenoh.Sample) -> None:
        message = self.read(EndOfStream, sample)
        if message is not None:
            self.report_done(message.t)

    def on_state(self, query: zenoh.Query) -> None:
        """``…/state``; ``?since=N``: also the transitions after seq N; ``?source=ID;after=N``:
        also those this instance (ID) sent after its source_seq N: then every hosted sensor
        answers, each reply saying how many there are, so that the asker knows this agent was
        reached and got all of it (nothing if ID is another)."""
        try:
            since, after = (None if text is None else int(text) for text in (query.parameters.get("since"),
                                                                              query.parameters.get("after")))
        except ValueError:
            query.reply_err(b"since and after must be integers")
            return
        source = query.parameters.get("source")
        if source is not None and source != self.instance:
            return
        asked = [(key, hosted) for sensor_id, hosted in self.hosts.sensors.items()
                 if zenoh.KeyExpr(key := self.keys.state(sensor_id)).intersects(query.key_expr)]
        answers = len(asked) if source is not None else None
        for key, hosted in asked:
            query.reply(key, encode(hosted.state(since, after, answers)))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.sensor_agent", description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", metavar="ID,…", help="sensor ids to host (default: every sensor of the deployment)")
    parser.add_argument("--region", metavar="NAME",
                        help="host the sensors placed in this region of the deployment's regions (with --sensors: "
                        "those of them in it)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("--lose", type=int, default=0, metavar="N",
                        help="testing: do not publish every Nth transition (a lossy link); receivers repair the gaps")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(SensorAgent, build_parser))
