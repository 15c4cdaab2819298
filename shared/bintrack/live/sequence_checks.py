"""Per-sensor ``seq`` and per-agent ``source_seq`` checks: how a receiver sees a lost transition
(DESIGN §3)."""

from __future__ import annotations

import math

from bintrack.messages import Transition


class SequenceCheck:
    """A receiver's view of each sensor's ``seq``: new, duplicate, or after a gap."""

    def __init__(self):
        self.last: dict[str, int] = {}

    def classify(self, transition: Transition) -> str:
        """'new' (the next seq), 'duplicate' (seen already) or 'gap' (some were lost)."""
        last = self.last.get(transition.sensor, 0)
        if transition.seq <= last:
            return "duplicate"
        return "new" if transition.seq == last + 1 else "gap"

    def accept(self, transition: Transition) -> None:
        self.last[transition.sensor] = max(self.last.get(transition.sensor, 0), transition.seq)


class SourceCheck:
    """Which transitions of each sensor-agent instance (``source``, ``source_seq``) arrived.

    A sensor agent's progress report says how many it has sent; the report comes after those
    transitions, so a shortfall means some were lost and ``first_missing`` says where to ask.
    """

    def __init__(self):
        self._contiguous: dict[str, int] = {}
        self._beyond: dict[str, set[int]] = {}

    def seen(self, transition: Transition) -> bool:
        if transition.source is None or transition.source_seq is None:
            return False
        n = transition.source_seq
        return n <= self._contiguous.get(transition.source, 0) or n in self._beyond.get(transition.source, ())

    def accept(self, transition: Transition) -> None:
        if transition.source is None or transition.source_seq is None:
            return
        source = transition.source
        beyond = self._beyond.setdefault(source, set())
        beyond.add(transition.source_seq)
        n = self._contiguous.get(source, 0)
        while n + 1 in beyond:
            n += 1
            beyond.discard(n)
        self._contiguous[source] = n

    def forget(self, source: str) -> None:
        """Start over for ``source``: an instance restarted under the same id counts from 1 again."""
        self._contiguous.pop(source, None)
        self._beyond.pop(source, None)

    def contiguous(self) -> dict[str, int]:
        """source → the highest ``source_seq`` up to which every transition of it was received."""
        return dict(self._contiguous)

    def first_missing(self, source: str, sent: int) -> int | None:
        """The lowest ``source_seq`` ≤ ``sent`` not received from ``source``, or None."""
        n = self._contiguous.get(source, 0)
        return n + 1 if n < sent else None


class UpstreamWatermark:
    """The event time before which every upstream service instance has published all it will
    (an adaptive watermark, DESIGN §5), from their progress reports.

    A sensor agent reports progress ``t`` after a clock tick once every sample before it is
    handled, so all its transitions with event time < ``t`` are out (and arrived, in publisher
    order, before the report; lost ones are fetched when the report comes). A tracker service
    reports what it has released. ``bound(tick)`` is the least report of the live instances of
    ``services`` (−inf for one that has not reported yet); an instance whose token went keeps
    its last report as a floor until it is back (a restart under the same id) or the clock
    advanced ``hold`` s plus the replay's lead past the first tick seen after the token went (it
    is gone for good), so that what it sends after a restart is not late. The replay holds event
    time while an awaited service is gone, but up to its lead (``--max-ahead`` clock periods, the
    ``lead`` given to :meth:`bound`) of ticks it sent before may still be on their way: they
    arrive on another path than the departure, so they must not use up the hold. Until an
    instance of each of ``services`` has been seen it is −inf: their first outputs may arrive
    after the first ticks, and a liveliness token comes on another path than the clock, so the
    clock alone must not release past them. Once every instance seen has gone for good it is
    +inf (the clock alone bounds).
    """

    def __init__(self, services, hold: float):
        self.services = frozenset(services)
        self.hold = hold
        self.alive: set[tuple[str, str]] = set()
        self.progress: dict[tuple[str, str], float] = {}
        # instance whose token went → the first tick (s) seen after it went (None: none yet)
        self.departed: dict[tuple[str, str], float | None] = {}
        self.unseen = set(self.services)  # services none of whose instances has been live yet

    def on_liveliness(self, service: str, instance: str, present: bool) -> None:
        entry = (service, instance)
        if service not in self.services:
            return
        if present:
            self.alive.add(entry)
            self.departed.pop(entry, None)
            self.unseen.discard(service)
        elif entry in self.alive:
            self.alive.discard(entry)
            self.departed[entry] = None  # its floor: its last report, −inf if it never reported

    def reported(self, service: str, instance: str, t: float) -> None:
        entry = (service, instance)
        self.progress[entry] = max(t, self.progress.get(entry, -math.inf))

    def bound(self, tick: float, lead: float = 0.0) -> float:
        """The watermark (s) the upstream allows when the latest clock tick is ``tick`` (s) and
        the replay may have sent ticks up to ``lead`` s of event time ahead of what its consumers
        acknowledged."""
        least = -math.inf if self.unseen else math.inf
        for entry in self.alive:
            least = min(least, self.progress.get(entry, -math.inf))
        for entry, since in list(self.departed.items()):
            if since is None:
                self.departed[entry] = since = tick
            if tick >= since + self.hold + lead:
                del self.departed[entry]
                self.progress.pop(entry, None)
            else:
                least = min(least, self.progress.get(entry, -math.inf))
        return least
