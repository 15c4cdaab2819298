"""A sensor agent's catch-up from replay's ``control/recent`` answer (its restart, its router's
return, replay's return after a cut link): the hosted sensors' raw samples it lacks, and the
count of those replay published that it neither received nor could still be given."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from bintrack.bus_payloads import Clock, RawSample
from bintrack.keys import ParsedKey
from bintrack.live.sensor_hosting import HostedSensors
from bintrack.message_codec import MessageError, decode_view

RETRY = 0.5  # s between asks for replay's recent samples
CATCH_UP_TRIES = 20  # asks for them, 0.1 s apart, once replay is back after a cut

log = logging.getLogger("bintrack")


@dataclass
class CatchUp:
    """What one ``recent`` answer gave: ``taken`` samples handled by hosted sensors, ``held``
    samples in it (all sensors'), the event time of the first, s, and ``published``, replay's
    count of raw samples so far (None if the answer did not say), and whether it was complete."""

    taken: int = 0
    held: int = 0
    first_held: float = math.inf
    published: int | None = None
    complete: bool = False
    published_to: dict[str, int] | None = None  # with regions: replay's count per region so far
    taken_samples: list[tuple[str, float]] = field(default_factory=list)  # (sensor, t) of those taken

    def lost(self, published_by_tick: int | None, arrived: int) -> int | None:
        """Raw samples published after the tick whose count was ``published_by_tick`` that
        neither ``arrived`` (after that tick) nor were held: what arrived is a prefix of what
        was published since, what replay holds a suffix. None if a count is unknown."""
        if self.published is None or published_by_tick is None:
            return None
        return max(0, self.published - published_by_tick - arrived - self.held)


def take_recent(replies: list[bytes], hosts: HostedSensors, newer: bool) -> CatchUp:
    """Hand the hosted sensors' samples of ``replies`` (a ``recent`` answer, in order) to them:
    with ``newer`` only those later than the sensor's last sample (the others arrived), else
    also one at its last sample's time (a restart resumes at a tick)."""
    out = CatchUp()
    for payload in replies:
        try:
            raw = decode_view(RawSample, payload)
        except MessageError:
            try:
                tick = decode_view(Clock, payload)
                out.published, out.published_to, out.complete = tick.sent, tick.sent_to, True
            except MessageError:
                pass
            continue
        out.held += 1
        out.first_held = min(out.first_held, raw.t)
        hosted = hosts.sensors.get(raw.sensor)
        if hosted is not None and (raw.t > hosted.last_t or (not newer and raw.t == hosted.last_t)):
            hosted.handle(raw)
            out.taken += 1
            out.taken_samples.append((raw.sensor, raw.t))
    return out


class RecentCatchUp:
    """What sensor agent ``name`` knows of replay's raw samples: the last clock tick it
    acknowledged, what arrived since, and whether replay is out of reach; and its catch-ups
    from replay's ``recent`` queryable on ``recent_key`` into ``hosts``.
    ``query(selector, timeout)`` is a blocking get; ``stopping`` ends the asking."""

    def __init__(self, name: str, recent_key: str, hosts: HostedSensors,
                 query: Callable[[str, float], list[bytes]], stopping: asyncio.Event):
        self.name = name
        self.recent_key = recent_key
        self.hosts = hosts
        self.query = query
        self.stopping = stopping
        self.acked = float("-inf")  # the last clock tick acknowledged
        self.acked_sent: int | None = None  # the raw samples replay had published by that tick
        self.since_ack = 0  # raw samples (of every sensor) received after it
        self.last_raw_t = float("-inf")  # event time of the last raw sample received, s
        self.replay_gone: float | None = None  # monotonic time replay's token went (out of reach), while it is
        self.caught_up: Callable[[CatchUp], None] = lambda catch_up: None  # told each answer taken

    async def take(self, newer: bool) -> int:
        """Handle the raw samples replay published after the last tick acknowledged (its
        ``recent`` queryable); with ``newer`` only those later than the sensor's last sample
        (the others arrived). How many were taken."""
        while True:  # until replay answers (after a router outage it may not be back yet)
            replies = await asyncio.to_thread(self.query, f"{self.recent_key}?after={self.acked!r}", 2.0)
            catch_up = take_recent(replies, self.hosts, newer)
            if catch_up.complete or self.stopping.is_set():
                self.caught_up(catch_up)
                return catch_up.taken
            log.info("%s: waiting for replay's recent samples", self.name)
            await asyncio.sleep(RETRY)

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """Replay's token went (its link, or a router between, is down) or came back (then catch up)."""
        if parsed.kind != "alive" or parsed.service != "replay":
            return
        if not present:
            self.replay_gone = self.replay_gone or time.monotonic()
        elif self.replay_gone is not None:
            self.catch_up()

    def raw_arrived(self, t: float) -> None:
        """A raw sample at event time ``t`` (s) arrived (replay's samples may come back before its token)."""
        if self.replay_gone is not None:
            self.catch_up()
        self.since_ack += 1
        self.last_raw_t = t

    def fill(self) -> CatchUp:
        """Take the hosted sensors' samples replay published after the last tick acknowledged
        that did not arrive (a narrowed agent's tick still short when the next came); blocking,
        as :meth:`catch_up`."""
        catch_up = take_recent(self.query(f"{self.recent_key}?after={self.acked!r}", 2.0), self.hosts, newer=True)
        if catch_up.complete:
            self.caught_up(catch_up)
        return catch_up

    def acknowledge(self, tick: Clock) -> None:
        """The clock tick ``tick`` is acknowledged: every sample before it has been handled."""
        if self.replay_gone is not None:
            self.catch_up()
        self.acked, self.acked_sent, self.since_ack = tick.t, tick.sent, 0

    def catch_up(self) -> None:
        """Replay is back after it was out of reach (its token, or a sample or tick of its, came
        again): before anything it publishes next is handled, take the raw samples it published
        meanwhile from its ``recent`` queryable (a reply takes milliseconds: the loop waits on
        purpose) and say how many were taken, and how many were lost: neither received nor held
        by replay any more."""
        away, self.replay_gone, last = time.monotonic() - self.replay_gone, None, self.last_raw_t
        for _ in range(CATCH_UP_TRIES):  # a token may come back before the queryable (eclipse-zenoh/zenoh#588)
            catch_up = take_recent(self.query(f"{self.recent_key}?after={self.acked!r}", 1.0), self.hosts, newer=True)
            if catch_up.complete or self.stopping.is_set():
                break
            time.sleep(0.1)
        self.caught_up(catch_up)
        lost = catch_up.lost(self.acked_sent, self.since_ack)
        log.warning("%s: replay was out of reach for %.1f s; of the raw samples it published after t=%g s, %d arrived "
                    "and %d were still held (%d of them this agent's, taken)%s", self.name, away, self.acked,
                    self.since_ack, catch_up.held, catch_up.taken,
                    "; replay did not answer: how many were lost is unknown" if lost is None else "; none was lost"
                    if lost == 0 else f"; {lost} raw samples of all sensors, published after t={last!r} s and before "
                    f"t={catch_up.first_held!r} s, were lost")
