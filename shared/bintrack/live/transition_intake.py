"""A service that consumes the network's transitions in event-time order (peer agents and the
base station's own trackers).

It hears ``sensor/*/transition``, repairs ``seq`` gaps from the sensors' ``state`` queryables
(and transitions a sensor agent says it sent that never arrived), follows restarted sensor
agents, and feeds a :class:`~bintrack.pipeline.TrackerDriver` whose watermark is the least of
the clock tick minus ``--lateness`` and the upstream services' reported progress (an adaptive
watermark: exact with no fixed hold); a subclass publishes what the tracker returns (``emit``).
"""

from __future__ import annotations

import math

import zenoh

from bintrack.live.bus import Service, log
from bintrack.keys import parse_key
from bintrack.messages import Clock, Deployment, Message, MessageError, SensorState, Transition, decode
from bintrack.pipeline import TrackerDriver
from bintrack.trackers import Tracker
from bintrack.live.sequence_checks import SequenceCheck, SourceCheck, UpstreamWatermark

DEPARTED_HOLD = 2.0  # s of event time an upstream instance that went away still holds the watermark
RELEASED_NONE = -1.7976931348623157e308  # a progress report's "released nothing yet" (finite: inf is no JSON)


class TransitionConsumer(Service):
    """Base of services that run a tracker on the network's transitions."""

    def start_intake(self, deployment: Deployment, tracker: Tracker, upstream: tuple[str, ...] = ("sensor_agent",),
                     network: Deployment | None = None) -> None:
        """Subscribe to transitions, agents' progress and the clock, and drive ``tracker``; at the
        end of the stream, finish once every service of ``upstream`` is done. ``network``: the
        whole deployment when ``deployment`` is a region's part of it (the other sensors'
        transitions are then counted as received, not taken)."""
        self.sensors = deployment.by_id()
        self.network_sensors = set(self.sensors) if network is None else {s.id for s in network.sensors}
        self.driver = TrackerDriver(tracker)
        self.sequence = SequenceCheck()
        self.sources = SourceCheck()
        self.fetched: set[tuple[str | None, int | None]] = set()  # fetched from state; may still arrive
        self.newest: dict[str, float] = {}  # event time of the newest transition taken, per sensor
        self.restarts: set[str | None] = set()  # sources seen counting from 1 again (logged once)
        checkpoint = self.load_checkpoint()
        if checkpoint is not None:
            try:
                (tick, self.driver, self.sequence, self.sources, self.fetched, self.newest, self.restarts,
                 extra) = checkpoint
                self.restore_extra(extra)
            except (TypeError, ValueError) as exc:  # a checkpoint of another version
                log.warning("%s: checkpoint not of this version (%s); starting afresh", self.name, exc)
                self.driver, self.sequence, self.sources = TrackerDriver(tracker), SequenceCheck(), SourceCheck()
                self.fetched, self.newest, self.restarts = set(), {}, set()
            else:
                log.info("%s: resumed at the clock tick t=%g s; %d transitions sent since fetched from the sensors' "
                         "state", self.name, tick, self.fetch_since_received())
        self.transition_keys = {sensor: self.keys.transition(sensor) for sensor in self.network_sensors}
        self.subscribe(self.keys.transition(), self.on_transition)
        self.subscribe(self.keys.progress("sensor_agent"), self.on_agent_progress)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.follow_upstream(upstream)
        self.follow_end_of_stream(upstream, self.on_finish)

    def follow_upstream(self, services: tuple[str, ...]) -> None:
        """Bound the watermark by the progress of the live instances of ``services`` (their
        liveliness tokens followed here); a peer agent's progress is read by
        :meth:`on_upstream_progress`, a sensor agent's by :meth:`on_agent_progress`."""
        self.upstream_mark = UpstreamWatermark(services, DEPARTED_HOLD)
        self.last_tick = -math.inf
        driver = getattr(self, "driver", None)  # after a restart: where the checkpoint had released to
        self.released = driver.buffer.released_until if driver is not None else -math.inf

        def on_alive(sample: zenoh.Sample) -> None:
            try:
                parsed = parse_key(str(sample.key_expr))
            except ValueError:
                return
            if parsed.kind == "alive":
                self.upstream_mark.on_liveliness(parsed.service, parsed.instance, sample.kind == zenoh.SampleKind.PUT)
                self.release()

        self._declared.append(self.session.liveliness().declare_subscriber(
            self.keys.alive(), self.inbox.callback(on_alive), history=True))
        for service in services:
            if service != "sensor_agent":
                self.subscribe(self.keys.progress(service), self.on_upstream_progress)

    def on_upstream_progress(self, sample: zenoh.Sample) -> None:
        report = self.read(Clock, sample)
        if report is None:
            return
        parsed = parse_key(str(sample.key_expr))
        self.upstream_mark.reported(parsed.service, parsed.instance,
                                    report.t if report.released is None else report.released)
        self.release()

    def watermark(self) -> float:
        """The event time (s) before which every transition has arrived."""
        lead = max(self.guard.steps.values(), default=0.0)  # what the replays announced: ticks in flight
        return min(self.last_tick - self.args.lateness, self.upstream_mark.bound(self.last_tick, lead))

    def release(self, report: bool = True) -> None:
        """Advance the tracker to the watermark if it moved, publish what it gives and, with
        ``report``, tell the services downstream (a progress report with ``released``)."""
        watermark = self.watermark()
        if watermark <= self.released:
            return
        self.released = watermark
        self.emit(self.advance(watermark))
        if report:
            self.report_released()

    def report_released(self) -> None:
        """Progress: the last clock tick handled, and the watermark released to."""
        self.report_progress(self.last_tick, released=self.released if math.isfinite(self.released) else RELEASED_NONE)

    def advance(self, watermark: float) -> list[Message]:
        """The tracker's outputs up to ``watermark`` (s)."""
        return self.driver.advance(watermark)

    def emit(self, outputs: list[Message]) -> None:
        """Publish the tracker's outputs."""
        raise NotImplementedError

    def fetch_since_received(self) -> int:
        """Fetch from the sensors' state every transition sent after the last one received in
        order: of each sensor (by ``seq``, from the lowest last seq of all sensors on; the
        duplicates are left out) and of each known sensor agent; how many were taken."""
        before = len(self.fetched)
        since = min((self.sequence.last.get(sensor, 0) for sensor in self.sensors), default=0)
        self.fetch_missed(f"{self.keys.state()}?since={since}")
        for source, received in self.sources.contiguous().items():
            self.fetch_missed(f"{self.keys.state()}?source={source};after={received}")
        return len(self.fetched) - before

    async def on_router_back(self) -> None:
        if hasattr(self, "sources"):
            log.info("%s: %d transitions sent during the outage fetched from the sensors' state",
                     self.name, self.fetch_since_received())

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
        if transition.sensor not in self.sensors:
            self.sources.accept(transition)  # another region's sensor: its agent's count stays whole
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
        if not old or transition.t <= self.newest.get(transition.sensor, -math.inf):
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
            log.warning("%s: seq gap before %d of %s could not be repaired now (no state reply)%s", self.name,
                        transition.seq, transition.sensor,
                        "; asked again at its agent's next progress report" if transition.source else "")

    def taken(self, transition: Transition) -> bool:
        """Whether ``transition`` was taken already: by its agent's count where it carries one
        (exact in any order: a transition lost before a later one of its sensor that was taken
        is fetched afterwards), else by its sensor's ``seq``."""
        if transition.source is not None and transition.source_seq is not None:
            return self.sources.seen(transition)
        return self.sequence.classify(transition) == "duplicate"

    def on_agent_progress(self, sample: zenoh.Sample) -> None:
        """A sensor agent says how far it has handled its samples and how many transitions it
        has sent: fetch any that did not arrive, then move the watermark."""
        report = self.read(Clock, sample)
        if report is None:
            return
        source = parse_key(str(sample.key_expr)).instance
        if report.sent is not None:
            first = self.sources.first_missing(source, report.sent)
            if first is not None:
                selector = f"{self.keys.state()}?source={source};after={first - 1}"
                if not self.fetch_missed(selector, upto=report.sent):
                    log.warning("%s: %s sent transitions that were lost and could not be fetched", self.name, source)
        self.upstream_mark.reported("sensor_agent", source, report.t)
        self.release()

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
            if not self.taken(transition):
                self.take(transition)
                self.fetched.add((transition.source, transition.source_seq))
        return replied

    def take(self, transition: Transition) -> None:
        self.sources.accept(transition)
        if transition.sensor not in self.sensors:
            return  # another region's sensor: received (its agent's count is whole), not tracked
        self.sequence.accept(transition)
        self.newest[transition.sensor] = max(transition.t, self.newest.get(transition.sensor, -math.inf))
        if not self.driver.push(transition):
            self.bad.report(self.keys.transition(transition.sensor),
                            f"late: t={transition.t} is behind the watermark {self.released:g} s (lateness {self.args.lateness} s)")

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.read(Clock, sample)
        if tick is None:
            return
        self.last_tick = max(self.last_tick, tick.t)
        self.release(report=False)
        # after the outputs went out, before acknowledging: a restart resumes at this tick and
        # fetches the transitions after it from the sensors' state queryables. A tracker's state
        # can take tens of ms to save (all of a peer agent's trackers), so it is throttled.
        self.save_checkpoint_throttled(tick.t, lambda: (tick.t, self.driver, self.sequence, self.sources, self.fetched,
                                                        self.newest, self.restarts, self.checkpoint_extra()))
        self.report_released()

    def on_finish(self, t: float) -> None:
        self.emit(self.driver.finish())
        if self.fetched:
            log.info("%s: %d transitions that never arrived were fetched from the sensors' state",
                     self.name, len(self.fetched))

