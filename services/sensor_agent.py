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
import asyncio
import sys
import time
from collections import Counter

import zenoh

from bintrack.formats import check_value
from bintrack.keys import ParsedKey, parse_key
from bintrack.live.checkpoint import SensorAgentCheckpoint
from bintrack.live.recent_catchup import take_recent
from bintrack.live.sensor_hosting import HISTORY_SPAN, HostedSensors
from bintrack.live.service import Service, log, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.bus_payloads import Clock, EndOfStream, RawSample
from bintrack.message_codec import encode, is_resent
from bintrack.transition_detector import TransitionDetector

RETRY = 0.5  # s between asks for replay's recent samples
CATCH_UP_TRIES = 20  # asks for them, 0.1 s apart, once replay is back after a cut


class SensorAgent(Service):
    name = "sensor_agent"

    def __init__(self, args):
        super().__init__(args)
        self.sensors = {}  # the deployment's sensors by id
        self.hosts: HostedSensors | None = None
        self.raw_keys: dict[str, str] = {}
        self.acked = float("-inf")  # the last clock tick acknowledged
        self.acked_sent: int | None = None  # the raw samples replay had published by that tick
        self.since_ack = 0  # raw samples (of every sensor) received after it
        self.last_raw_t = float("-inf")  # event time of the last raw sample received, s
        self.replay_gone: float | None = None  # monotonic time replay's token went (out of reach), while it is
        self.resent = Counter()  # raw samples a restarted replay sent again: new (True) or already here (False)

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.sensors = deployment.by_id()
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
            hosted = self.args.sensors.split(",") if self.args.sensors else list(self.sensors)
        unknown = [s for s in hosted if s not in self.sensors]
        if unknown:
            log.error("%s: --sensors names ids not in the deployment: %s", self.name, ", ".join(unknown))
            self.exit_status = 2
            self.stop()
            return
        self.hosts = HostedSensors(self.keys, self.instance, TransitionDetector(deployment, hosted), hosted,
                                   self.put, self.bad.report, self.args.lose)
        checkpoint = self.checkpoints.load(SensorAgentCheckpoint)
        if checkpoint is not None and set(checkpoint.sensors) == set(self.hosts.sensors):
            await self._resume(checkpoint)
        self.raw_keys = {sid: self.keys.raw(sid) for sid in self.sensors}
        self.subscribe(self.keys.raw(), self.on_raw)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.subscribe(self.keys.eos(), self.on_eos)
        self.serve(self.keys.state(), self.on_state)
        self.follow_presence(self.on_presence)

    async def _resume(self, checkpoint: SensorAgentCheckpoint) -> None:
        """Take the state saved at the last clock tick acknowledged (statuses, counters, and the
        transitions sent in the last RESUME_SPAN s, which a receiver may still fetch: a kill
        loses what was still in flight), then the raw samples replay published after that tick
        (its ``recent`` queryable): what this sensor agent had when it died, and what it missed
        while it was down (replay holds the clock meanwhile)."""
        self.hosts.restore(checkpoint)
        self.acked = checkpoint.tick
        taken = await self._take_recent(newer=False)
        log.info("%s: resumed at the tick t=%g s with %d transitions sent; %d raw samples since taken from replay",
                 self.name, checkpoint.tick, self.hosts.sent, taken)

    async def _take_recent(self, newer: bool) -> int:
        """Handle the raw samples replay published after the last tick acknowledged (its
        ``recent`` queryable); with ``newer`` only those later than the sensor's last sample
        (the others arrived). How many were taken."""
        while True:  # until replay answers (after a router outage it may not be back yet)
            replies = await asyncio.to_thread(self.query, f"{self.keys.recent()}?after={self.acked!r}", 2.0)
            catch_up = take_recent(replies, self.hosts, newer)
            if catch_up.complete or self.stopping.is_set():
                return catch_up.taken
            log.info("%s: waiting for replay's recent samples", self.name)
            await asyncio.sleep(RETRY)

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """Replay's token went (its link, or a router between, is down) or came back (then catch up)."""
        if parsed.kind != "alive" or parsed.service != "replay" or self.hosts is None:
            return
        if not present:
            self.replay_gone = self.replay_gone or time.monotonic()
        elif self.replay_gone is not None:
            self.catch_up()

    def catch_up(self) -> None:
        """Replay is back after it was out of reach (its token, or a sample or tick of its, came
        again): before anything it publishes next is handled, take the raw samples it published
        meanwhile from its ``recent`` queryable (a reply takes milliseconds: the loop waits on
        purpose) and say how many were taken, and how many were lost: neither received nor held
        by replay any more."""
        away, self.replay_gone, last = time.monotonic() - self.replay_gone, None, self.last_raw_t
        for _ in range(CATCH_UP_TRIES):  # a token may come back before the queryable (eclipse-zenoh/zenoh#588)
            catch_up = take_recent(self.query(f"{self.keys.recent()}?after={self.acked!r}", 1.0), self.hosts, newer=True)
            if catch_up.complete or self.stopping.is_set():
                break
            time.sleep(0.1)
        lost = catch_up.lost(self.acked_sent, self.since_ack)
        log.warning("%s: replay was out of reach for %.1f s; of the raw samples it published after t=%g s, %d arrived "
                    "and %d were still held (%d of them this agent's, taken)%s", self.name, away, self.acked,
                    self.since_ack, catch_up.held, catch_up.taken,
                    "; replay did not answer: how many were lost is unknown" if lost is None else "; none was lost"
                    if lost == 0 else f"; {lost} raw samples of all sensors, published after t={last!r} s and before "
                    f"t={catch_up.first_held!r} s, were lost")

    async def on_router_back(self) -> None:
        if self.hosts is not None and self.hosts.sensors:
            taken = await self._take_recent(newer=True)
            log.info("%s: %d raw samples published during the outage taken from replay", self.name, taken)

    def on_raw(self, sample: zenoh.Sample) -> None:
        raw = self.read(RawSample, sample)
        if raw is None:
            return
        if self.replay_gone is not None:  # replay's samples came back before its token did
            self.catch_up()
        self.since_ack += 1
        self.last_raw_t = raw.t
        key = str(sample.key_expr)
        expected = self.raw_keys.get(raw.sensor)
        if expected is None:
            if parse_key(key).sensor != raw.sensor:
                self.bad.report(key, f"payload names sensor {raw.sensor!r}")
            else:
                self.bad.report(key, f"unknown sensor id {raw.sensor!r}")
            return
        if key != expected:
            self.bad.report(key, f"payload names sensor {raw.sensor!r}")
            return
        problem = check_value(self.sensors[raw.sensor], raw.value)
        if problem:
            self.bad.report(key, problem)
            return
        hosted = self.hosts.sensors.get(raw.sensor)
        if hosted is None:  # another agent's sensor
            return
        if sample.attachment is not None and is_resent(sample.attachment.to_bytes()):
            # sent again by a restarted replay: new only if later than what this sensor has
            if raw.t <= hosted.last_t:
                self.resent[False] += 1
                return
            self.resent[True] += 1
        hosted.handle(raw)

    def on_clock(self, sample: zenoh.Sample) -> None:
        """A clock tick is acknowledged at once: every sample before it has been handled."""
        message = self.read(Clock, sample)
        if message is None:
            return
        if self.replay_gone is not None:
            self.catch_up()
        self.hosts.forget_before(message.t - HISTORY_SPAN)
        if self.resent:
            log.info("%s: of the raw samples a restarted replay sent again, %d were new and %d already handled",
                     self.name, self.resent[True], self.resent[False])
            self.resent.clear()
        self.acked, self.acked_sent, self.since_ack = message.t, message.sent, 0
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
        also those this instance (ID) sent after its source_seq N (nothing if ID is another)."""
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
                state = hosted.state(since, after)
                if source is None or state.missed:
                    query.reply(key, encode(state))


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
