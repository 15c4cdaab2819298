"""The MQTT bridge as a pure object: messages in, raw samples and clock ticks out (no I/O).

:class:`BridgeCore` takes each MQTT message (topic, payload, retained flag, time of receipt)
and the wall clock, and gives what the bridge service publishes, in the order replay would:
the raw samples before each clock tick, sorted by (event time, sensor), then the tick.

* **Topics** map to sensors through the sensor table; an unknown topic is a fault.
* **Event time** of a message is its payload's own timestamp where it has one, else its
  time of receipt, less the sensor's clock offset and the table's epoch (s).
* **Ticks** lie on a grid of ``period`` s of event time. The watermark is the event time the
  bridge has seen (``clock="payload"``: the latest sample's; ``"wall"``: the wall clock's,
  for sensors whose clocks follow it) less ``lateness``; a tick is due once the watermark
  reaches it. Samples arrive in any order within that bound; one later than a tick already
  out is late (a fault, never published out of order).
* **Retained** messages (the broker's last state of a topic, sent on subscribing) give the
  state at start, :attr:`BridgeCore.initial`, and are never published as a detection.
* **Faults** (unknown topic, malformed payload, a value the sensor's kind cannot take, late,
  duplicate, flood) are returned as :class:`Fault` and counted in :attr:`BridgeCore.faults`;
  a redelivered QoS 1 message is a duplicate (counted, not published twice). A flood is a
  sensor sending more than ``max_rate`` messages per second of event time (a token bucket of
  ``max_rate`` tokens): the excess is dropped and counted.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass
from typing import Literal

from bintrack.formats import check_value
from bintrack.mqtt.payload_reader import PayloadError, PayloadReader
from bintrack.mqtt.sensor_table import SensorTable
from bintrack.ordering import ReorderBuffer

FAULT_KINDS = ("unknown topic", "malformed payload", "bad value", "late", "duplicate", "flood")
RECENT_RELEASED = 4096  # samples already published remembered to tell a redelivery from a late sample
MAX_TICKS_AT_ONCE = 10_000  # past this many due grid ticks (a long silence) the clock jumps to the last


@dataclass(frozen=True, slots=True)
class Sample:
    """A raw sample: ``sensor`` reported ``value`` at event time ``t`` (s)."""

    t: float
    sensor: str
    value: int


@dataclass(frozen=True, slots=True)
class Fault:
    """A message the bridge did not publish: its ``kind`` (one of FAULT_KINDS), topic and why."""

    kind: str
    topic: str
    reason: str


@dataclass(frozen=True, slots=True)
class End:
    """A message on the end topic: the stream ends (a played-back session)."""


@dataclass(frozen=True, slots=True)
class Retained:
    """A retained message read as the state at start of ``sensor``."""

    sensor: str
    value: int


class _Row:
    __slots__ = ("sensor", "reader", "offset", "model", "tokens", "filled_at")

    def __init__(self, sensor, reader, offset, model, rate):
        self.sensor, self.reader, self.offset, self.model = sensor, reader, offset, model
        self.tokens, self.filled_at = rate, -math.inf


class BridgeCore:
    """Messages → samples and ticks; see the module's text. ``period``, ``lateness`` in s of
    event time, ``max_rate`` messages per s of event time per sensor."""

    def __init__(self, table: SensorTable, *, period: float = 0.5, lateness: float = 1.0,
                 clock: Literal["payload", "wall"] = "wall", max_rate: float = 20.0, end_topic: str | None = None):
        if not (period > 0 and math.isfinite(period)):
            raise ValueError(f"clock period must be a positive number of seconds, got {period!r}")
        if not (lateness >= 0 and math.isfinite(lateness)):
            raise ValueError(f"lateness must be a number of seconds >= 0, got {lateness!r}")
        if not max_rate > 0:
            raise ValueError(f"max rate must be positive, got {max_rate!r}")
        self.period, self.lateness, self.clock, self.max_rate = period, lateness, clock, max_rate
        self.end_topic = end_topic
        self.epoch_us = table.epoch_us
        models = table.deployment().by_id()
        self._rows = {row.topic: _Row(row.id, PayloadReader(row.payload), row.clock_offset, models[row.id], max_rate)
                      for row in table.sensors}
        self.buffer: ReorderBuffer[Sample] = ReorderBuffer()
        self.faults: Counter[str] = Counter()
        self.initial: dict[str, int] = {}  # sensor → status at start, from retained messages
        self.received = 0  # messages handed to receive
        self.retained = 0  # retained messages among them
        self.released = 0  # samples released for publishing
        self.latest: float | None = None  # the latest event time of a sample taken (s)
        self.earliest: float | None = None  # the earliest, before the first tick
        self.last_tick: float | None = None
        self.ended = False  # a message on the end topic taken (the broker will not send it again)
        self.final_tick: float | None = None  # set at the end of the stream
        self.journal_seq = 0  # the last message taken (the service's numbering, for its journal)
        self._held: set[tuple[str, float, int]] = set()
        self._done: deque[tuple[str, float, int]] = deque()
        self._done_set: set[tuple[str, float, int]] = set()

    # -- messages -----------------------------------------------------------------------

    def event_time(self, stamp_us: int, offset: float) -> float:
        """Event time (s) of a sensor's time ``stamp_us`` (Unix µs) with clock ``offset`` (s);
        exact to the µs (integer µs over 10⁶ when the offset is 0)."""
        t = (stamp_us - self.epoch_us) / 1_000_000
        return t - offset if offset else t

    def receive(self, topic: str, payload: bytes, *, retained: bool, received_us: int,
                seq: int | None = None) -> Sample | Retained | Fault | End:
        """Take one message received at Unix time ``received_us`` (µs): the sample now held
        for publishing, the state at start it gave (``retained``), the fault, or the end."""
        if seq is not None:
            self.journal_seq = seq
        if topic == self.end_topic:
            self.ended = True
            return End()
        self.received += 1
        row = self._rows.get(topic)
        if row is None:
            return self._fault("unknown topic", topic, "no sensor of the table has this topic")
        try:
            value, stamp = row.reader.read(payload)
        except PayloadError as exc:
            return self._fault("malformed payload", topic, f"{row.sensor}: {exc}")
        problem = check_value(row.model, value)
        if problem:
            return self._fault("bad value", topic, f"{row.sensor}: {problem}")
        if retained:
            self.retained += 1
            self.initial[row.sensor] = value
            return Retained(row.sensor, value)
        t = self.event_time(received_us if stamp is None else stamp, row.offset)
        key = (row.sensor, t, value)
        if key in self._held or key in self._done_set:
            return self._fault("duplicate", topic, f"{row.sensor}: t={t:.6f} s value {value} again (a redelivery)")
        if t < self.buffer.released_until:
            return self._fault("late", topic, f"{row.sensor}: t={t:.6f} s is before the clock tick already out "
                               f"({self.buffer.released_until:.6f} s; lateness {self.lateness:g} s)")
        if t > row.filled_at:  # refill the sensor's token bucket by the event time since its last message
            row.tokens = min(self.max_rate, row.tokens + (t - row.filled_at) * self.max_rate)
            row.filled_at = t
        if row.tokens < 1:
            return self._fault("flood", topic, f"{row.sensor}: more than {self.max_rate:g} messages per s")
        row.tokens -= 1
        sample = Sample(t, row.sensor, value)
        self.buffer.push(sample)
        self._held.add(key)
        self.latest = t if self.latest is None else max(self.latest, t)
        self.earliest = t if self.earliest is None else min(self.earliest, t)
        return sample

    def summary(self) -> str:
        """One line: what came and what became of it."""
        return (f"{self.received} messages: {self.released} samples published, {self.retained} retained, "
                f"{len(self.initial)} sensors' state at start from retained messages ({sum(self.initial.values())} "
                f"detecting), faults {dict(self.faults)}")

    def _fault(self, kind: str, topic: str, reason: str) -> Fault:
        self.faults[kind] += 1
        return Fault(kind, topic, reason)

    # -- the clock ----------------------------------------------------------------------

    def watermark(self, now_us: int) -> float | None:
        """The event time (s) up to which every sample is taken to have arrived, at Unix time
        ``now_us`` (µs); None before anything says what event time it is."""
        if self.final_tick is not None:
            return self.final_tick
        if self.clock == "wall":
            return self.event_time(now_us, 0.0) - self.lateness
        return None if self.latest is None else self.latest - self.lateness

    def next_tick(self, now_us: int) -> tuple[float, list[Sample]] | None:
        """The next clock tick due at ``now_us`` (Unix µs) and the samples before it, sorted by
        (t, sensor), or None if none is due. The caller publishes the samples, then the tick."""
        mark = self.watermark(now_us)
        if mark is None:
            return None
        if self.last_tick is None:
            tick = math.floor((mark if self.earliest is None else self.earliest) / self.period) * self.period
        else:
            tick = self.last_tick + self.period
            if (mark - tick) / self.period > MAX_TICKS_AT_ONCE:
                tick = math.floor(mark / self.period) * self.period
        if tick > mark:
            return None
        return tick, self._release(tick)

    def _release(self, tick: float) -> list[Sample]:
        samples = self.buffer.release(tick)
        self.last_tick = tick
        self._settle(samples)
        return samples

    def _settle(self, samples: list[Sample]) -> None:
        for sample in samples:
            key = (sample.sensor, sample.t, sample.value)
            self._held.discard(key)
            self._done.append(key)
            self._done_set.add(key)
        while len(self._done) > RECENT_RELEASED:
            self._done_set.discard(self._done.popleft())
        self.released += len(samples)

    def end(self) -> tuple[float, float]:
        """End of stream (a message on the end topic): from now on every tick up to the final
        one is due, the first grid point past every sample and tick. (the final tick, the
        end's event time: the latest sample's, else the last tick's, else 0), s. Once set, the
        final tick stays (a bridge restarted from a checkpoint taken after the end keeps it)."""
        times = [t for t in (self.last_tick, self.latest) if t is not None]
        last = max(times) if times else 0.0
        if self.final_tick is None:
            self.final_tick = (math.floor(last / self.period) + 1) * self.period
        return self.final_tick, (self.latest if self.latest is not None else last)

    # -- checkpoint -----------------------------------------------------------------------

    def snapshot(self) -> dict:
        """What changes as messages come (for a checkpoint): plain data."""
        return {"buffer": self.buffer, "faults": dict(self.faults), "initial": dict(self.initial),
                "received": self.received, "retained": self.retained, "released": self.released, "latest": self.latest,
                "earliest": self.earliest, "last_tick": self.last_tick, "ended": self.ended,
                "final_tick": self.final_tick, "journal_seq": self.journal_seq,
                "held": set(self._held), "done": list(self._done),
                "buckets": {topic: (row.tokens, row.filled_at) for topic, row in self._rows.items()}}

    def restore(self, state: dict) -> None:
        """Take back a :meth:`snapshot` of an instance with the same table."""
        self.buffer = state["buffer"]
        self.faults = Counter(state["faults"])
        self.initial = dict(state["initial"])
        self.received, self.retained, self.released = state["received"], state["retained"], state["released"]
        self.latest, self.earliest, self.last_tick = state["latest"], state["earliest"], state["last_tick"]
        self.final_tick = state["final_tick"]
        self.ended = state.get("ended", self.final_tick is not None)  # (checkpoints before "ended" was kept)
        self.journal_seq = state["journal_seq"]
        self._held = set(state["held"])
        self._done = deque(state["done"])
        self._done_set = set(self._done)
        for topic, (tokens, filled_at) in state["buckets"].items():
            if topic in self._rows:
                self._rows[topic].tokens, self._rows[topic].filled_at = tokens, filled_at


class FaultLines:
    """Which faults get a log line: each one, with the running count of its kind, up to
    ``limit`` lines per kind; then one line saying the rest of that kind are only counted."""

    def __init__(self, limit: int = 100):
        self.limit = limit
        self._lines: Counter[str] = Counter()

    def describe(self, outcome, core: "BridgeCore") -> str | None:
        """The log line of a message's ``outcome`` in ``core``: a fault's (see :meth:`line`),
        or a retained state's that came after the first tick (a resubscription); else None."""
        if isinstance(outcome, Fault):
            return self.line(outcome, core.faults[outcome.kind])
        if isinstance(outcome, Retained) and core.last_tick is not None:
            return self.line(Fault("retained state", outcome.sensor, f"{outcome.value}, taken as the sensor's state, "
                                   "not as a detection"), core.retained)
        return None

    def line(self, fault: Fault, count: int) -> str | None:
        """The line for ``fault``, the ``count``-th of its kind, or None (only counted)."""
        shown = self._lines[fault.kind]
        if shown > self.limit:
            return None
        self._lines[fault.kind] += 1
        if shown == self.limit:
            return f"{fault.kind}: {count} so far; further ones are only counted (see the summary at the end)"
        return f"{fault.kind} #{count} on {fault.topic}: {fault.reason}"


class RecentSamples:
    """The raw samples published since the last few ticks, for a sensor agent that restarts
    (``control/recent?after=T``, as replay answers it): (tick before it s, key, payload)."""

    def __init__(self):
        self.items: deque[tuple[float, str, bytes]] = deque()

    def add(self, before: float, key: str, payload: bytes) -> None:
        self.items.append((before, key, payload))

    def forget_before(self, tick: float) -> None:
        while self.items and self.items[0][0] < tick:
            self.items.popleft()

    def after(self, t: float | str | None) -> list[bytes]:
        """The payloads published after the tick at ``t`` (s; text as in a query, None for
        all); ValueError if ``t`` is not a number."""
        t = float(t or "-inf")
        return [payload for tick, _, payload in self.items if tick >= t]
