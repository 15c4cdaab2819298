"""A region's sensor agent acknowledges a clock tick only once the raw samples before it are in
(order by counts, DESIGN §11).

It subscribes to its own sensors' raw keys and to the clock, a subscriber each, so a tick may
arrive before raw samples replay published ahead of it. Each tick says in ``sent_to`` how many
raw samples of each region's sensors replay has published; the agent counts those it received
and holds the tick until it has as many. A tick still short when the next one comes is a gap:
the samples are taken from replay's ``recent`` queryable, whose answer gives the count of all
published so far; a sample taken so that arrives afterwards is dropped, not handled twice.
"""

from __future__ import annotations

from collections import deque

from bintrack.bus_payloads import Clock
from bintrack.live.recent_catchup import CatchUp

FORGET_TAKEN = 60.0  # s of event time behind the last tick after which a sample taken from replay is forgotten


class TickOrder:
    """The clock ticks of region ``region``'s sensor agent, held until its raw samples are in.

    Tick T counts the samples replay published before it, those with event time < T (it
    publishes T after them and before any later one); a sample may arrive after a later tick
    or before T itself, so the agent counts, per tick, the samples it holds of an event time
    before it."""

    def __init__(self, region: str):
        self.region = region
        self.below = 0  # samples of the region's sensors held before the last tick acknowledged
        self.ahead: list[float] = []  # event times (s) of those held since, at or after it
        self.complete = 0  # replay's count in its last recent answer taken: every one of those is in
        self.held: deque[Clock] = deque()  # ticks waiting for their samples, oldest first
        self.taken: set[tuple[str, float]] = set()  # (sensor, t) taken from replay before they arrived

    def need(self, tick: Clock) -> int:
        """How many of the region's raw samples replay had published before ``tick``."""
        return 0 if tick.sent_to is None else tick.sent_to.get(self.region, 0)

    def count(self, tick: Clock) -> int:
        """How many of those are held."""
        return self.below + sum(1 for t in self.ahead if t < tick.t)

    def satisfied(self, tick: Clock) -> bool:
        need = self.need(tick)
        return need <= self.complete or self.count(tick) >= need

    def arrived(self, sensor: str, t: float) -> bool:
        """A raw sample of the region's sensor ``sensor`` at ``t`` (s) arrived: whether it is new
        (False: it was taken from replay already; drop it)."""
        if self.taken and (sensor, t) in self.taken:
            self.taken.discard((sensor, t))
            return False
        self.ahead.append(t)
        return True

    def caught_up(self, catch_up: CatchUp) -> None:
        """Replay's ``recent`` answer was taken: every sample it counts is in."""
        if catch_up.published_to is not None:
            self.complete = max(self.complete, catch_up.published_to.get(self.region, 0))
            self.taken.update(catch_up.taken_samples)
            self.ahead.extend(t for _, t in catch_up.taken_samples)

    def tick(self, tick: Clock) -> None:
        self.held.append(tick)

    def short(self) -> bool:
        """Whether the oldest tick held still lacks samples although a later tick came: a gap."""
        return len(self.held) > 1 and not self.satisfied(self.held[0])

    def ready(self) -> list[Clock]:
        """The ticks whose samples are all in, oldest first (no longer held)."""
        out = []
        while self.held and self.satisfied(self.held[0]):
            tick = self.held.popleft()
            self.below = max(self.need(tick), self.count(tick))
            self.ahead = [t for t in self.ahead if t >= tick.t]
            out.append(tick)
        if out and self.taken:  # samples taken from replay whose copies never came (lost on the way)
            horizon = out[-1].t - FORGET_TAKEN
            self.taken = {entry for entry in self.taken if entry[1] >= horizon}
        return out
