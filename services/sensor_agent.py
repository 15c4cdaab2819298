"""Sensor agent: raw samples of its sensors → transitions (papers 000, 001).

``python -m bintrack.services.sensor_agent [--sensors ID,…] [--region NAME]`` hosts any number
of a deployment's sensors (all by default; those placed in a region with ``--region``), handled
in arrival order by the one subscriber's handler (the clock tick after a sample is acknowledged
once the sample is handled). A sensor publishes a ``Transition`` on ``sensor/<id>/transition``
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
from bintrack.bus_payloads import Clock, EndOfStream, RawSample
from bintrack.message_codec import encode
from bintrack.transition_detector import TransitionDetector


class SensorAgent(Service):
    name = "sensor_agent"

    def __init__(self, args):
        super().__init__(args)
        self.hosts: HostedSensors | None = None
        self.intake: RawIntake | None = None  # the raw samples it hands to them
        self.replay: RecentCatchUp | None = None  # what it knows of replay's raw samples

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        sensors = deployment.by_id()
        if self.args.region is not None:
            from bintrack.regions import RegionMap  # shapely: loaded only for a region

            try:
                hosted = RegionMap(deployment).own_sensors(self.args.region)
            except ValueError as exc:
                log.error("%s: --region: %s", self.name, exc)
                self.exit_status = 2
                self.stop()
                return
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
        self.replay = RecentCatchUp(self.name, self.keys.recent(), self.hosts, self.query, self.stopping)
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
        transitions sent in the last RESUME_SPAN s, which a receiver may still fetch: a kill
        loses what was still in flight), then the raw samples replay published after that tick
        (its ``recent`` queryable): what this sensor agent had when it died, and what it missed
        while it was down (replay holds the clock meanwhile)."""
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
        self.intake.take(str(sample.key_expr), raw, None if sample.attachment is None else sample.attachment.to_bytes())

    def on_clock(self, sample: zenoh.Sample) -> None:
        """A clock tick is acknowledged at once: every sample before it has been handled."""
        message = self.read(Clock, sample)
        if message is None:
            return
        self.replay.acknowledge(message)
        self.hosts.forget_before(message.t - HISTORY_SPAN)
        self.intake.say_resent()
        self.hosts.trim(message.t)
        if self.checkpoints.path is not None:
            self.checkpoints.save(self.hosts.checkpoint(message.t))
        self.report_progress(message.t, sent=self.hosts.sent)

    def on_eos(self, sample: zenoh.Sample) -> None:
        message = self.read(EndOfStream, sample)
        if message is not None:
            self.report_done(message.t)

    def on_state(self, query: zenoh.Query) -> None:
        """``…/state``; ``?since=N``: also the transitions after seq N; ``?source=ID;after=N``:
        also those this instance (ID) sent after its source_seq N: then every hosted sensor
        answers, so that the asker knows this agent was reached (nothing if ID is another)."""
        try:
            since, after = (None if text is None else int(text) for text in (query.parameters.get("since"),
                                                                              query.parameters.get("after")))
        except ValueError:
            query.reply_err(b"since and after must be integers")
            return
        source = query.parameters.get("source")
        if source is not None and source != self.instance:
            return
        for sensor_id, hosted in self.hosts.sensors.items():
            key = self.keys.state(sensor_id)
            if zenoh.KeyExpr(key).intersects(query.key_expr):
                query.reply(key, encode(hosted.state(since, after)))


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
