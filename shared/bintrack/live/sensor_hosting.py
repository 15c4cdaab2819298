"""The sensors one sensor agent hosts: raw samples in arrival order → transitions (papers 000,
001), each sensor's recent transitions for gap repair, and what a checkpoint keeps of them."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from typing import NamedTuple

from bintrack.formats import Event
from bintrack.keys import Keys
from bintrack.live.checkpoint import SensorAgentCheckpoint, resume_span
from bintrack.bus_payloads import RawSample, SensorState, Transition
from bintrack.message_codec import decode, encode_transition
from bintrack.transition_detector import TransitionDetector

HISTORY = 256  # transitions kept per sensor for gap repair …
HISTORY_SPAN = 60.0  # … and no older than this, s of event time behind the clock (memory stays flat)
TRANSITION_FIELDS = tuple(Transition.model_fields)  # an earlier checkpoint's layout of a sent transition: version, then Sent's


class Sent(NamedTuple):
    """A transition this agent sent: the fields of ``Transition`` but its version. The model is
    built only for a ``state`` reply; the hot path packs these fields directly."""

    t: float
    sensor: str
    value: int
    previous: int
    seq: int
    source: str
    source_seq: int

    def message(self) -> Transition:
        return Transition(**self._asdict())


class HostedSensor:
    """One sensor: its samples in arrival order → transitions, and its recent history."""

    def __init__(self, sensor_id: str, detector: TransitionDetector, hosts: "HostedSensors"):
        self.id = sensor_id
        self.detector = detector
        self.hosts = hosts
        self.history: deque[Sent] = deque(maxlen=HISTORY)
        self.last_t = float("-inf")
        self.key = hosts.keys.transition(sensor_id)
        self.takers: tuple[str, ...] = ()  # the regions that take it (each counts its transitions)

    def handle(self, sample: RawSample) -> None:
        hosts = self.hosts
        if sample.t < self.last_t:
            hosts.report(hosts.keys.raw(self.id), f"out of order: t={sample.t} after t={self.last_t}")
            return
        self.last_t = sample.t
        change = self.detector.change(Event(sample.t, self.id, sample.value))
        if change is None:
            return
        hosts.sent += 1
        for region in self.takers:
            hosts.sent_to[region] += 1
        transition = Sent(sample.t, self.id, sample.value, change[0], change[1], hosts.instance, hosts.sent)
        payload = encode_transition(*transition)
        self.remember(transition)
        hosts.recent.append(transition)
        hosts.recent_payloads.append(payload)
        if hosts.lose and hosts.sent % hosts.lose == 0:
            return  # --lose: a lossy link for tests; the receivers must repair the gap
        hosts.put(self.key, payload)

    def remember(self, transition: Sent) -> None:
        """Keep ``transition`` for gap repair (the trail says when to forget it)."""
        self.history.append(transition)
        self.hosts.trail.append(transition)

    def state(self, since: int | None, after_source_seq: int | None, answers: int | None = None) -> SensorState:
        """Status and seq; ``missed``: transitions with seq > ``since`` or source_seq > ``after_source_seq``;
        ``answers``: how many replies the query gets from this agent (a query by source)."""
        value, seq = self.detector.status(self.id)
        missed = [tr.message() for tr in self.history
                  if (since is not None and tr.seq > since)
                  or (after_source_seq is not None and tr.source_seq > after_source_seq)]
        return SensorState(t=self.last_t if self.last_t > float("-inf") else 0.0, sensor=self.id,
                           value=value, seq=seq, missed=missed, answers=answers)


class HostedSensors:
    """The hosted sensors of agent ``instance``: ``put(key, payload)`` sends a transition,
    ``report(key, reason)`` counts a bad input; ``lose`` drops every lose-th transition (tests)."""

    def __init__(self, keys: Keys, instance: str, detector: TransitionDetector, hosted: list[str],
                 put: Callable[[str, bytes], None], report: Callable[[str, str], None], lose: int = 0):
        self.keys = keys
        self.instance = instance
        self.put = put
        self.report = report
        self.lose = lose
        self.sent = 0
        self.sent_to: dict[str, int] | None = None  # with regions: the transitions sent that each region takes
        self.recent: deque[Sent] = deque()  # the transitions sent lately (see trim)
        self.recent_payloads: deque[bytes] = deque()  # … as sent (encoded): what a checkpoint keeps
        self.trail: deque[Sent] = deque()  # every sensor's history, oldest first (to trim them)
        self.sensors = {sid: HostedSensor(sid, detector, self) for sid in hosted}

    def count_for(self, takers: dict[str, tuple[str, ...]]) -> None:
        """Count the transitions sent per region that takes them (``takers``: sensor → regions),
        for the progress reports' ``sent_to`` (DESIGN §11)."""
        self.sent_to = {}
        for sid, hosted in self.sensors.items():
            hosted.takers = takers.get(sid, ())
            for region in hosted.takers:
                self.sent_to.setdefault(region, 0)

    def forget_before(self, t: float) -> None:
        """Drop the histories older than event time ``t`` (s): each transition is looked at once."""
        while self.trail and self.trail[0].t < t:
            history = self.sensors[self.trail.popleft().sensor].history
            while history and history[0].t < t:
                history.popleft()

    def checkpoint(self, tick: float) -> SensorAgentCheckpoint:
        """What to keep at the clock tick ``tick`` (s) acknowledged."""
        detector = next(iter(self.sensors.values())).detector if self.sensors else None
        return SensorAgentCheckpoint(tick, self.sent, detector, {sid: h.last_t for sid, h in self.sensors.items()},
                                     list(self.recent_payloads),
                                     None if self.sent_to is None else dict(self.sent_to))

    def trim(self, tick: float, lead: float) -> None:
        """Forget the sent transitions a checkpoint need not keep: those older than ``tick`` (s)
        less what a consumer restarted with this agent may need when replay runs ``lead`` s
        ahead (:func:`~bintrack.live.checkpoint.resume_span`; at most HISTORY_SPAN, all a
        state query could give)."""
        oldest = tick - min(resume_span(lead), HISTORY_SPAN)
        while self.recent and self.recent[0].t < oldest:
            self.recent.popleft()
            self.recent_payloads.popleft()

    def restore(self, saved: SensorAgentCheckpoint) -> None:
        """Take back the statuses, counters and recent transitions of ``saved``."""
        self.sent = saved.sent
        saved_to = getattr(saved, "sent_to", None)  # (a checkpoint from before regions counted: none)
        if self.sent_to is not None and saved_to is not None:
            self.sent_to.update((region, n) for region, n in saved_to.items() if region in self.sent_to)
        for kept in saved.recent:
            if isinstance(kept, bytes):
                message = decode(Transition, kept)
                transition = Sent(**{name: getattr(message, name) for name in Sent._fields})
            else:  # a checkpoint of an earlier version: (schema version, *Sent)
                fields = dict(zip(TRANSITION_FIELDS, kept))
                transition = Sent(**{name: fields[name] for name in Sent._fields})
                kept = encode_transition(*transition)
            self.recent.append(transition)
            self.recent_payloads.append(kept)
            self.sensors[transition.sensor].remember(transition)
        for sid, last_t in saved.sensors.items():
            hosted = self.sensors[sid]
            hosted.detector, hosted.last_t = saved.detector, last_t
