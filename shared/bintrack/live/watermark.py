"""The watermark of a service that runs a tracker: the event time before which every input has
arrived (an adaptive watermark, DESIGN §5).

It is the least of the latest clock tick less ``--lateness`` and what the upstream services'
progress reports allow (:class:`UpstreamWatermark`), which follows their instances through
their liveliness tokens. It only moves forward: :meth:`Watermark.advance` says where to
release the tracker to, once, when it moved.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable

from bintrack.keys import ParsedKey

log = logging.getLogger("bintrack")

DEPARTED_HOLD = 2.0  # s of event time an upstream instance that went away still holds the watermark
# s of wall time it holds at least: after a router restart the tokens come back over each link of
# the mesh in turn, and at --speed 0 the replay (which saw them all back) runs the hold's event
# time out in a fraction of a second. up restarts a router after 0.5 s and the sessions reconnect
# within about 1 s; at --speed 1 the event-time hold alone lasts longer than this
DEPARTED_GRACE = 3.0
# s of wall time an instance whose token is still declared may stay silent, its last report more
# than the hold and the lead behind the clock, before it is taken for gone: a router of the mesh
# can keep the token of an instance behind a cut link after the others dropped it (a stale route;
# eclipse-zenoh/zenoh#2602), and a consumer behind that router would wait for it for ever.
# Under flow control a connected instance never lags the clock that far.
SILENT_AFTER = 10.0


class Watermark:
    """One service's watermark (s of event time): the clock, its lateness, the upstream's
    progress, and ``released``, how far the tracker was released to.

    ``lead()`` is the event time the replays announced may be in flight (their ticks' step
    times ``--max-ahead``; see :mod:`bintrack.live.control_guard`)."""

    def __init__(self, services: Iterable[str], lateness: float, lead: Callable[[], float],
                 released: float = -math.inf, who: str = "bintrack"):
        self.upstream = UpstreamWatermark(services, DEPARTED_HOLD, who=who)
        self.lateness = lateness
        self.lead = lead
        self.last_tick = -math.inf
        self.released = released

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """Follow the upstream instances' tokens (a :class:`~bintrack.live.presence.Presence` listener)."""
        if parsed.kind == "alive":
            self.upstream.on_liveliness(parsed.service, parsed.instance, present)

    def tick(self, t: float) -> None:
        """A clock tick at ``t`` (s) arrived."""
        self.last_tick = max(self.last_tick, t)

    def reported(self, service: str, instance: str, t: float) -> None:
        """An upstream instance has published everything before ``t`` (s)."""
        self.upstream.reported(service, instance, t)

    def current(self) -> float:
        """The event time (s) before which every input has arrived."""
        return min(self.last_tick - self.lateness, self.upstream.bound(self.last_tick, self.lead()))

    def advance(self) -> float | None:
        """The new watermark (s) if it moved past ``released`` (which it then becomes), else None."""
        watermark = self.current()
        if watermark <= self.released:
            return None
        self.released = watermark
        return watermark


class UpstreamWatermark:
    """The event time before which every upstream service instance has published all it will
    (an adaptive watermark, DESIGN §5), from their progress reports.

    A sensor agent reports progress ``t`` after a clock tick once every sample before it is handled,
    so all its transitions with event time < ``t`` are out (and arrived, in publisher order, before
    the report; lost ones are fetched when the report comes). A tracker service reports what it has
    released. ``bound(tick)`` is the least report of the live instances of ``services`` (−inf for
    one that has not reported yet); an instance whose token went keeps its last report as a floor
    until it is back (a restart under the same id) or the clock advanced ``hold`` s plus the
    replay's lead past the first tick seen after the token went and ``grace`` s of wall time
    (``now``, s) have passed since (it is gone for good), so that what it sends after a restart, or
    once its token is back over a healed link, is not late. An instance whose token is still there
    but whose last report has stayed more than ``hold`` s plus the lead behind the clock for
    ``silent_after`` s of wall time is taken for gone as well (logged), until it reports again.
    The replay holds event time while an awaited service is gone, but up to its lead
    (``--max-ahead`` clock periods, the ``lead`` given to :meth:`bound`) of ticks it sent before
    may still be on their way: they arrive on another path than the departure, so they must not
    use up the hold. Until an instance of each of ``services``
    has been seen it is −inf: their first outputs may arrive after the first ticks, and a liveliness
    token comes on another path than the clock, so the clock alone must not release past them. Once
    every instance seen has gone for good it is +inf (the clock alone bounds).
    """

    def __init__(self, services, hold: float, grace: float = DEPARTED_GRACE,
                 now: Callable[[], float] = time.monotonic, who: str = "bintrack",
                 silent_after: float = SILENT_AFTER):
        self.services = frozenset(services)
        self.hold = hold
        self.grace = grace
        self.silent_after = silent_after
        self.now = now
        self.who = who
        self.alive: set[tuple[str, str]] = set()
        self.progress: dict[tuple[str, str], float] = {}
        # instance whose token went → [the first tick (s) seen after it went (None: none yet),
        # the wall time (s) it went]
        self.departed: dict[tuple[str, str], list] = {}
        self.unseen = set(self.services)  # services none of whose instances has been live yet
        self.lagging: dict[tuple[str, str], float] = {}  # live instance → wall time (s) it fell behind
        self.silent: set[tuple[str, str]] = set()  # taken for gone while their token is still declared

    def on_liveliness(self, service: str, instance: str, present: bool) -> None:
        entry = (service, instance)
        if service not in self.services:
            return
        if present:
            self.alive.add(entry)
            self.departed.pop(entry, None)
            self.silent.discard(entry)
            self.unseen.discard(service)
        elif entry in self.alive:
            self.alive.discard(entry)
            self.lagging.pop(entry, None)
            self.departed[entry] = [None, self.now()]  # its floor: its last report, −inf if it never reported
        else:
            self.silent.discard(entry)

    def reconnected(self) -> None:
        """This service's own router is back after a loss: the instances that went meanwhile
        are judged from now on (their hold and grace start again at the next tick), since
        their tokens come back over the mesh only after the link, and a wait spent cut off
        says nothing about whether they are gone. The same for the silent ones' timers."""
        now = self.now()
        for went in self.departed.values():
            went[:] = [None, now]
        self.lagging.clear()

    def reported(self, service: str, instance: str, t: float) -> None:
        entry = (service, instance)
        self.progress[entry] = max(t, self.progress.get(entry, -math.inf))
        if entry in self.silent:
            self.silent.discard(entry)
            self.alive.add(entry)
            log.info("%s: %s %s reports again (t=%g s); the watermark follows it", self.who, *entry, t)

    def bound(self, tick: float, lead: float = 0.0) -> float:
        """The watermark (s) the upstream allows when the latest clock tick is ``tick`` (s) and
        the replay may have sent ticks up to ``lead`` s of event time ahead of what its consumers
        acknowledged."""
        least = -math.inf if self.unseen else math.inf
        for entry in list(self.alive):
            if self._silent(entry, tick, lead):
                continue
            least = min(least, self.progress.get(entry, -math.inf))
        for entry, went in list(self.departed.items()):
            if went[0] is None:
                went[0] = tick
            since, went_at = went
            if tick >= since + self.hold + lead and self.now() - went_at >= self.grace:
                del self.departed[entry]
                self.progress.pop(entry, None)
                log.info("%s: %s %s gone for good at t=%g s; the watermark no longer waits for it", self.who,
                         *entry, tick)
            else:
                least = min(least, self.progress.get(entry, -math.inf))
        return least

    def _silent(self, entry: tuple[str, str], tick: float, lead: float) -> bool:
        """Whether live ``entry``, behind the clock ``tick`` (s) by more than the hold and ``lead``
        for ``silent_after`` s of wall time, is now taken for gone (it had reported before)."""
        report = self.progress.get(entry, -math.inf)
        if not math.isfinite(report) or tick - report <= self.hold + lead:
            self.lagging.pop(entry, None)
            return False
        since = self.lagging.setdefault(entry, self.now())
        if self.now() - since < self.silent_after:
            return False
        del self.lagging[entry]
        self.alive.discard(entry)
        self.progress.pop(entry, None)
        self.silent.add(entry)
        log.warning("%s: %s %s has not reported since t=%g s, %g s of wall time, though its token is still "
                    "declared (its router out of reach?); the watermark no longer waits for it", self.who, *entry,
                    report, self.silent_after)
        return True
