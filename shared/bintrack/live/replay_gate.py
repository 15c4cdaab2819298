"""When a live source (replay, or the MQTT bridge) may go on: the services it waits for are live,
the router is there, and every consumer has acknowledged what a tick or the end of stream owes
(flow control, DESIGN §3); and when it may end: every awaited service has reported done after
the last end of stream."""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable

from bintrack.bus_payloads import Clock, EndOfStream
from bintrack.keys import ParsedKey, parse_key
from bintrack.live.replay_schedule import Consumers, Pacer, Publish

PROGRESS_INTERVAL = 5.0  # s of wall clock between "waiting for" lines
SAY_AGAIN = 2.0  # s of wall clock between two repeats of the last tick (or end of stream) while one is owed
REPLAY = "replay"

log = logging.getLogger("bintrack")


def wanted_services(wait_for: list[str]) -> list[str]:
    """The services a source waits for, from its ``--wait-for`` options (each a name, NAME*N,
    or a comma-separated list of them), once each, in order."""
    return list(dict.fromkeys(name.strip() for item in wait_for for name in item.split(",") if name.strip()))


class ReplayGate:
    """Who a live source waits for. ``wanted``: the ``--wait-for`` services (``NAME`` or
    ``NAME*N``, N live instances); ``router_lost()`` whether the session has lost its router;
    ``stopping`` is set when the source stops; ``hold``: whether event time is held while one of
    them is gone once they were all there (``started``), or only the start waits for them;
    ``source``: the source's service name (its own instances consume nothing; its log lines)."""

    def __init__(self, wanted: list[str], router_lost: Callable[[], bool], stopping: asyncio.Event,
                 hold: bool = True, source: str = REPLAY):
        self.source = source
        self.wanted = wanted
        self.hold = hold
        self.started = False
        self.wanted_missing = list(wanted)  # those of them with no live instance
        self.router_lost = router_lost
        self.stopping = stopping
        self.alive: set[tuple[str, str]] = set()
        self.consumers = Consumers()
        self.done: dict[tuple[str, str], float] = {}  # the end of stream (s) each consumer reported done
        self.arrivals = 0  # instances of awaited services that became live
        self.last_tick: float | None = None  # the last tick published (s)
        self.pacer: Pacer | None = None
        self.tick_again: Callable[[], None] | None = None  # puts the last tick again (set by the player)
        self.pauses = 0
        self.changed = asyncio.Event()

    def follow(self, service) -> ReplayGate:
        """Hear ``service``'s (a :class:`~bintrack.live.service.Service`) liveliness tokens and the
        services' progress and done reports, a bad payload counted by ``service``; returns self."""

        def on_progress(sample) -> None:
            message = service.read(Clock, sample)
            if message is not None:
                parsed = parse_key(str(sample.key_expr))
                self.reported(parsed.service, parsed.instance, message.t)

        def on_done(sample) -> None:
            message = service.decode(EndOfStream, sample)
            if message is not None:
                parsed = parse_key(str(sample.key_expr))
                self.reported_done(parsed.service, parsed.instance, message.t)

        service.follow_presence(self.on_presence)
        service.subscribe(service.keys.progress(), on_progress)
        service.subscribe(service.keys.done(), on_done)
        return self

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """A service's token came or went (a Presence listener): every live service but a
        source of this kind consumes the clock and owes its acknowledgements."""
        if parsed.kind != "alive":
            return
        entry = (parsed.service, parsed.instance)
        if present:
            self.alive.add(entry)
            if parsed.service != self.source:
                self.consumers.appeared(entry, self.last_tick)
            if parsed.service in self.awaited():
                self.arrivals += 1
        else:
            self.alive.discard(entry)
            self.consumers.vanished(entry)
        self.wanted_missing = self._short_of(self.alive)
        self.changed.set()

    def _short_of(self, instances: set[tuple[str, str]]) -> list[str]:
        """The --wait-for services (NAME, or NAME*N: N instances) with too few of ``instances``."""
        short = []
        for wanted in self.wanted:
            name, _, count = wanted.partition("*")
            if sum(service == name for service, _ in instances) < (int(count) if count.isdigit() else 1):
                short.append(wanted)
        return short

    def reported(self, service: str, instance: str, t: float) -> None:
        """A consumer's progress report: it has handled the ticks up to ``t`` (s)."""
        self.consumers.reported((service, instance), t)
        self.changed.set()

    def reported_done(self, service: str, instance: str, t: float) -> None:
        """A consumer's done report: it has handled the end of stream at ``t`` (s)."""
        self.done[(service, instance)] = t
        self.changed.set()

    def awaited(self) -> set[str]:
        """The names of the --wait-for services."""
        return {wanted.partition("*")[0] for wanted in self.wanted}

    def owing_done(self, t: float) -> list[str]:
        """The live instances of awaited services that have not reported done at ``t`` (s)."""
        names = self.awaited()
        return sorted(f"{s}/{i}" for s, i in self.alive if s in names and self.done.get((s, i)) != t)

    def unfinished(self, t: float) -> list[str]:
        """As :meth:`missing` after the end of stream at ``t`` (s): an instance that reported done
        at ``t`` and left (a recorder ends with the stream) counts as there."""
        over = {entry for entry, when in self.done.items() if when == t}
        short = self._short_of(self.alive | over) if self.hold else []
        return short + ["the router"] if self.router_lost() else short

    def missing(self) -> list[str]:
        """The --wait-for services with no live instance (none once started, without ``hold``),
        and the router if it is lost."""
        missing = self.wanted_missing if self.hold or not self.started else []
        return missing + ["the router"] if self.router_lost() else missing

    def clear(self) -> bool:
        """Whether a sample may go out at once (nothing missing)."""
        return not self.missing()

    async def until(self, condition: Callable[[], bool], waiting_for: Callable[[], str],
                    timeout: float | None = None, repeat: Callable[[], None] | None = None) -> bool:
        """Wait until ``condition()`` holds (True), replay stops or ``timeout`` s pass (False);
        says what it waits for every few seconds, and calls ``repeat()`` every SAY_AGAIN s."""
        start = last_said = said_at = time.monotonic()
        wake = 1.0 if repeat is None else min(1.0, SAY_AGAIN)
        while not condition():
            if self.stopping.is_set():
                return False
            now = time.monotonic()
            if timeout is not None and now - start >= timeout:
                return False
            if now - last_said >= PROGRESS_INTERVAL:
                log.info("%s: waiting for %s", self.source, waiting_for())
                last_said = now
            if repeat is not None and now - said_at >= SAY_AGAIN:
                repeat()
                said_at = now
            self.changed.clear()
            try:
                await asyncio.wait_for(self.changed.wait(), wake if timeout is None else min(wake, start + timeout - now))
            except TimeoutError:
                pass
        return True

    async def all_present(self, timeout: float | None = None) -> bool:
        """Wait until nothing is :meth:`missing` (True), saying which services it waits for;
        False if stopping or after ``timeout`` s."""
        return await self.until(lambda: not self.missing(), lambda: "services " + ", ".join(self.missing()), timeout)

    async def hold_while_missing(self, t: float) -> bool:
        """While an awaited service has no live instance (it died, or lost the router), hold the
        clock at ``t`` (s); True once all are back (False if stopping)."""
        if not self.missing():
            return True
        gone = ", ".join(self.missing())
        self.pauses += 1
        log.warning("%s: %s gone; holding event time at t=%.3f s until it is back", self.source, gone, t)
        started = time.monotonic()
        if not await self.all_present():
            return False
        held = time.monotonic() - started
        self.pacer.hold(held)
        log.info("%s: %s back after %.1f s; resuming at t=%.3f s", self.source, gone, held, t)
        return True

    async def ready_for(self, action, skip_ack: bool) -> bool:
        """Wait until every awaited service is live and, for a tick or the end, has acknowledged
        what it must; False if stopping. (A consumer that dies no longer owes its
        acknowledgement, so liveness is checked again after it.)"""
        while True:
            if not await self.hold_while_missing(action.t):
                return False
            if not isinstance(action, Publish) and action.ack is not None and not skip_ack:
                if not await self.acknowledged(action.ack):
                    return False
            if not self.missing():
                return True

    async def window_open(self, sent: deque[float]) -> bool:
        """Until the tick after ``sent`` (the last ticks out, s, at most ``--max-ahead``) may go:
        every awaited service live and, once ``sent`` is full, its oldest acknowledged (the last
        tick said again while that is overdue); False if stopping. (A live source's pace with no
        schedule of its own: the MQTT bridge's.)"""
        while True:
            if self.missing() and not await self.all_present():
                return False
            if len(sent) == sent.maxlen and not await self.acknowledged(sent[0]):
                return False
            if not self.missing():
                return True

    async def acknowledged(self, ack: float) -> bool:
        """Wait until every consumer has acknowledged the tick at ``ack`` (s); False if stopping.
        While one is overdue, the last tick is said again every SAY_AGAIN s (``tick_again``): a
        consumer whose router was cut may have lost the ticks after its last acknowledgement, and
        it acknowledges them all with a later one (a tick it has is a no-op)."""
        return await self.until(lambda: not self.consumers.owing(ack),
                                lambda: f"progress >= {ack:g} s from "
                                + ", ".join(f"{s}/{i}" for s, i in self.consumers.owing(ack)), repeat=self.tick_again)

    async def linger(self, t: float, say_again: Callable[[], None]) -> bool:
        """After the last end of stream, at ``t`` (s): wait until every awaited service is live
        (with ``hold``) and each live instance has reported done at ``t``. One that comes back
        meanwhile (restarted after the end went out) is told again at once, and the others
        every SAY_AGAIN s (a finished service then reports done again, for the restarted one
        downstream). True when all are done, False if stopping."""

        def owing() -> list[str]:
            return self.unfinished(t) + self.owing_done(t)

        while True:
            arrivals = self.arrivals
            if not await self.until(lambda: not owing() or self.arrivals != arrivals,
                                    lambda: f"done at t={t:g} s from " + ", ".join(owing()), repeat=say_again):
                return False
            if not owing():
                return True
            log.info("%s: end of stream at t=%g s said again, for %s (back after it went out)", self.source, t,
                     ", ".join(owing()))
            say_again()
