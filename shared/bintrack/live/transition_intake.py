"""A service that consumes the network's transitions in event-time order (peer agents and the
base station's own trackers).

It hears ``sensor/*/transition``, has every one taken once (:class:`~bintrack.live.gap_repair.GapRepair`),
and feeds a :class:`~bintrack.pipeline.TrackerDriver` up to its
:class:`~bintrack.live.watermark.Watermark`: the least of the clock tick minus ``--lateness`` and
the upstream services' reported progress (exact with no fixed hold); a subclass publishes what
the tracker returns (``emit``). A region's base station hears only the transitions it takes and
orders by the agents' counts (``order_by`` in :meth:`TransitionConsumer.start_intake`, DESIGN §11).
"""

from __future__ import annotations

import math

import zenoh

from bintrack.keys import parse_key
from bintrack.live.checkpoint import IntakeCheckpoint
from bintrack.live.count_order import CountOrder
from bintrack.live.gap_repair import GapRepair
from bintrack.live.service import Service, log
from bintrack.live.watermark import Watermark
from bintrack.bus_payloads import Clock, Transition
from bintrack.deployment_model import Deployment
from bintrack.message_base import Message
from bintrack.pipeline import TrackerDriver
from bintrack.trackers import Tracker

RELEASED_NONE = -1.7976931348623157e308  # a progress report's "released nothing yet" (finite: inf is no JSON)
FINAL_FETCH = 1.0  # s of wall time the end of stream waits for counted transitions before fetching them


class TransitionConsumer(Service):
    """Base of services that run a tracker on the network's transitions (or, relaying, on the
    upstream's outputs: then only :meth:`follow_upstream` is used)."""

    def __init__(self, args):
        super().__init__(args)
        self.watermark: Watermark | None = None
        self.driver: TrackerDriver | None = None
        self.intake: GapRepair | None = None
        self.transition_keys: dict[str, str] = {}
        self.sent = 0  # outputs published (counted by ``emit``), in each progress report
        self.end = None  # its EndOfStream
        self.final_fetch = None  # the timer that fetches what the agents counted and is missing at the end
        self.uncounted: set[str] = set()  # agents whose reports carry no counts per region (logged once)

    def start_intake(self, deployment: Deployment, tracker: Tracker, upstream: tuple[str, ...] = ("sensor_agent",),
                     network: Deployment | None = None, order_by: str | None = None) -> None:
        """Subscribe to transitions, agents' progress and the clock, and drive ``tracker``; at the
        end of the stream, finish once every service of ``upstream`` is done. ``network``: the
        whole deployment when ``deployment`` is a region's part of it (the other sensors'
        transitions are then counted as received, not taken). ``order_by``: a region's name:
        subscribe to the transitions of ``deployment``'s sensors only and order them by the
        agents' counts for that region."""
        sensors = set(deployment.by_id())
        network_sensors = sensors if network is None else {s.id for s in network.sensors}
        self.driver = TrackerDriver(tracker)
        state = None
        saved = self.checkpoints.load(IntakeCheckpoint)
        if saved is not None:
            self.driver, state = saved.driver, saved.intake
            self.restore_extra(saved.extra)
        self.intake = GapRepair(self.name, self.keys, sensors, self.push, self.query, self.bad.report, state)
        if order_by is not None:
            if self.intake.state.order is None:
                self.intake.state.order = CountOrder(order_by)
            self.narrow([*(self.keys.transition(sid) for sid in sorted(sensors)), self.keys.clock(), self.keys.eos(),
                         # the agents' progress and done in one subscriber: an agent's last progress before its done
                         f"{self.keys.prefix}/control/*/sensor_agent/*"])
        if saved is not None:
            log.info("%s: resumed at the clock tick t=%g s; %s", self.name, saved.tick,
                     self.intake.fetch_since_received())
        self.transition_keys = {sensor: self.keys.transition(sensor) for sensor in network_sensors}
        self.subscribe(self.keys.transition(), self.on_transition)
        self.subscribe(self.keys.progress("sensor_agent"), self.on_agent_progress)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.follow_upstream(upstream)
        self.end = self.follow_end_of_stream(upstream, self.on_finish)

    def follow_upstream(self, services: tuple[str, ...]) -> None:
        """Bound the watermark by the progress of the live instances of ``services`` (their
        liveliness tokens followed here); a peer agent's progress is read by
        :meth:`on_upstream_progress`, a sensor agent's by :meth:`on_agent_progress`."""
        # after a restart: where the checkpoint had released to
        released = self.driver.buffer.released_until if self.driver is not None else -math.inf
        # the lead: what the replays announced may be in flight (see control_guard)
        self.watermark = Watermark(services, self.args.lateness, lambda: self.guard.lead,
                                   released, who=self.name)
        self.follow_presence(self.on_presence)
        for service in services:
            if service != "sensor_agent":
                self.subscribe(self.keys.progress(service), self.on_upstream_progress)

    def on_presence(self, parsed, present: bool) -> None:
        if parsed.kind == "alive":
            self.watermark.on_presence(parsed, present)
            self.release()

    def on_upstream_progress(self, sample: zenoh.Sample) -> None:
        report = self.read(Clock, sample)
        if report is None:
            return
        parsed = parse_key(str(sample.key_expr))
        self.watermark.reported(parsed.service, parsed.instance, report.t if report.released is None else report.released)
        self.release()

    @property
    def released(self) -> float:
        """The event time (s) the tracker was released to."""
        return self.watermark.released

    def release(self, report: bool = True) -> None:
        """Advance the tracker to the watermark if it moved, publish what it gives and, with
        ``report``, tell the services downstream (a progress report with ``released``)."""
        watermark = self.watermark.advance()
        if watermark is None:
            return
        self.emit(self.advance(watermark))
        if report:
            self.report_released()

    def report_released(self) -> None:
        """Progress: the last clock tick handled, and the watermark released to."""
        released = self.watermark.released
        self.report_progress(self.watermark.last_tick, sent=self.sent,
                             released=released if math.isfinite(released) else RELEASED_NONE)

    def advance(self, watermark: float) -> list[Message]:
        """The tracker's outputs up to ``watermark`` (s)."""
        return self.driver.advance(watermark)

    def emit(self, outputs: list[Message]) -> None:
        """Publish the tracker's outputs (counting the main ones in ``sent``)."""
        raise NotImplementedError

    async def on_router_back(self) -> None:
        if self.watermark is not None:
            self.watermark.upstream.reconnected()
        if self.intake is not None:
            log.info("%s: after the outage, %s", self.name, self.intake.fetch_since_received())

    def checkpoint_extra(self):
        """What a subclass adds to the checkpoint taken at each clock tick."""
        return None

    def restore_extra(self, extra) -> None:
        """Take back what :meth:`checkpoint_extra` gave."""

    def on_transition(self, sample: zenoh.Sample) -> None:
        transition = self.decode(Transition, sample)
        if transition is None:
            return
        key = str(sample.key_expr)
        if key != self.transition_keys.get(transition.sensor):
            self.bad.report(key, f"transition of unknown or mismatched sensor {transition.sensor!r}")
            return
        self.intake.receive(transition, key)
        order = self.intake.state.order
        if order is not None and transition.source is not None:
            counts = order.sources.get(transition.source)
            if counts is not None and counts.reports:
                self.settle(transition.source)

    def push(self, transition: Transition) -> None:
        """Hand a transition taken to the tracker (late ones are counted)."""
        if not self.driver.push(transition):
            self.bad.report(self.keys.transition(transition.sensor),
                            f"late: t={transition.t} is behind the watermark {self.released:g} s (lateness {self.args.lateness} s)")

    def on_agent_progress(self, sample: zenoh.Sample) -> None:
        """A sensor agent says how far it has handled its samples and how many transitions it
        has sent: fetch any that did not arrive, then move the watermark (not before they are)."""
        report = self.read(Clock, sample)
        if report is None:
            return
        source = parse_key(str(sample.key_expr)).instance
        order = self.intake.state.order
        if order is not None and report.sent is not None:
            if report.sent_to is not None:
                order.report(source, report.t, report.sent, report.sent_to)
                self.settle(source)
                return
            if source not in self.uncounted:
                self.uncounted.add(source)
                log.warning("%s: %s reports no counts per region; its transitions are taken in arrival order",
                            self.name, source)
        elif report.sent is not None and not self.intake.agent_sent(source, report.sent):
            return  # transitions it sent are still to be fetched: the watermark waits for them
        self.watermark.reported("sensor_agent", source, report.t)
        self.release()

    def settle(self, source: str, final: bool = False) -> None:
        """Move the watermark past the reports of ``source`` whose transitions are all held."""
        ticks = self.intake.settle(source, final)
        for t in ticks or ():
            self.watermark.reported("sensor_agent", source, t)
        if ticks:
            self.release()
            if self.end is not None and self.end.eos is not None:
                self.end.check()

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.read(Clock, sample)
        if tick is None:
            return
        self.watermark.tick(tick.t)
        self.release(report=False)
        # after the outputs went out, before acknowledging: a restart resumes at this tick and
        # fetches the transitions after it from the sensors' state queryables. A tracker's state
        # can take tens of ms to save (all of a peer agent's trackers), so it is throttled.
        self.checkpoints.save_throttled(tick.t, lambda: IntakeCheckpoint(tick.t, self.driver, self.intake.state,
                                                                         self.checkpoint_extra()))
        self.report_released()

    def on_finish(self, t: float) -> bool:
        """Flush the tracker at the end of the stream (False: not yet, transitions an agent
        counted are still on their way; fetched after FINAL_FETCH s)."""
        order = self.intake.state.order
        if order is not None and order.waiting():
            if self.final_fetch is None:
                self.final_fetch = self.loop.call_later(FINAL_FETCH, self.fetch_counted)
            return False
        self.emit(self.driver.finish())
        if self.intake.state.fetched:
            log.info("%s: %d transitions that never arrived were fetched from the sensors' state",
                     self.name, len(self.intake.state.fetched))
        return True

    def fetch_counted(self) -> None:
        """The end of the stream came and agents' reports still lack transitions: fetch them."""
        self.final_fetch = None
        for source in self.intake.state.order.waiting():
            self.settle(source, final=True)
        self.end.check()
