"""What replay publishes and when, as pure objects (no Zenoh, no wall clock of its own).

:func:`schedule` turns the items of a source (dataset events or recorded samples, each with
its event time) into a sequence of actions: :class:`Publish` an item, :class:`Tick` the clock,
:class:`End` of stream. Flow control is expressed in the actions: a tick carries the event
time every consumer must have acknowledged before it goes out, so at most ``max_ahead`` ticks
are unacknowledged. :class:`Pacer` says how long to wait on the wall clock for a given speed;
:class:`Consumers` tracks who must acknowledge what. The replay service only executes these.

Ticks of a dataset are on a grid: t0 + k·period with t0 the first event time floored to the
period; tick T is published once every event with t < T is (an event at exactly T follows
it). The last tick of a pass is the first grid point past the last event. A recording brings
its own ticks; a final one is added when none lies past its last item. With ``loop`` every
pass after the first is shifted in event time by (last tick − start of the pass + period), so
event time keeps increasing and the grid continues.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Iterator
from dataclasses import dataclass
from typing import Generic, TypeVar

from bintrack.errors import BintrackError

T = TypeVar("T")


class NothingToReplay(BintrackError, ValueError):
    """A pass of the source had no item to publish."""


@dataclass(frozen=True)
class Publish(Generic[T]):
    """Publish ``item`` at event time ``t`` (s, shifted); ``shift`` (s) is what the pass adds to
    the item's own times (0 in the first pass)."""

    t: float
    item: T
    shift: float


@dataclass(frozen=True)
class Tick:
    """Publish a clock tick at event time ``t`` (s), once every consumer has reported progress
    ≥ ``ack`` (s); ``ack`` is None when no acknowledgement is due yet."""

    t: float
    ack: float | None


@dataclass(frozen=True)
class End:
    """Publish end of stream at event time ``t`` (s, the pass's last item), once every consumer
    has acknowledged the pass's final tick ``ack`` (s). ``last`` is False when another pass follows."""

    t: float
    ack: float
    last: bool


@dataclass(frozen=True)
class Gap:
    """Jump over empty event time from the tick at ``t`` (s) to the next tick at ``to`` (s): a
    gap between two items longer than ``max_gap``; pacing does not wait through it."""

    t: float
    to: float


Action = Publish | Tick | End | Gap

MAX_GAP = 60.0
"""s of event time between two items beyond which replay jumps over the gap instead of ticking
through it (the trackers treat a silence this long as empty time, ``MAX_SILENCE``)"""

TICK_WALL = 0.05
"""s of wall clock between ticks by default: a live estimate waits at most about this long"""
TICK_FASTEST = 0.5
"""s of event time between ticks by default at ``--speed 0``, and the most at any speed"""


def default_clock_period(speed: float) -> float:
    """The default event time between clock ticks (s) at ``speed`` × real time: a tick every
    TICK_WALL s of wall clock, but never less than TICK_WALL nor more than TICK_FASTEST s of
    event time apart; TICK_FASTEST at speed 0 (as fast as flow control allows).

    A tick is a flow-control round trip through every service, and at speed 0 the 0.05 s grid
    cost more than the samples (1.7 samples per tick on a 40-person grid). Results do not
    depend on the period (trackers run in event time); latency at speed 0 has no meaning. 0.5 s
    is the scan period of the PIR grids (paper 004): coarser ticks only batch whole scans, and
    gave little more in ``benchmarks/bus.py``."""
    if not (speed >= 0 and math.isfinite(speed)):
        raise ValueError(f"speed must be a finite number >= 0, got {speed!r}")
    if speed == 0:
        return TICK_FASTEST
    return min(max(TICK_WALL * speed, TICK_WALL), TICK_FASTEST)


def schedule(passes: Callable[[], Iterable[tuple[float, T | None]]], *, period: float, max_ahead: int = 1,
             recorded_ticks: bool = False, loop: bool = False, max_gap: float = MAX_GAP) -> Iterator[Action]:
    """The replay's actions, in order.

    ``passes()`` gives one pass of the source as (event time s, item) pairs in time order;
    with ``recorded_ticks``, a pair whose item is None is a recorded clock tick at that time,
    otherwise ticks are made on the ``period`` grid (s). ``max_ahead`` ≥ 1 ticks may be
    unacknowledged. ``loop`` repeats the source forever, shifted in time. Where two items (or
    recorded ticks) are more than ``max_gap`` s apart, a dataset's grid stops at the first tick
    past the earlier one and a :class:`Gap` leads to the later one's tick. Raises
    :class:`NothingToReplay` when a pass has no item.
    """
    if not (period > 0 and math.isfinite(period)):
        raise ValueError(f"clock period must be a positive number of seconds, got {period!r}")
    if max_ahead < 1:
        raise ValueError(f"max_ahead must be at least 1, got {max_ahead!r}")
    published: deque[float] = deque(maxlen=max_ahead)
    shift = 0.0

    def tick(t: float) -> Tick:
        action = Tick(t + shift, published[0] if len(published) == max_ahead else None)
        published.append(t + shift)
        return action

    while True:
        start = last_item = last_tick = None
        grid = 0  # index of the next grid tick (dataset sources)
        previous = None  # the time of the last item or recorded tick
        for t, item in passes():
            if start is None:
                grid = math.floor(t / period)
                start = t if recorded_ticks else grid * period
            if previous is not None and t - previous > max_gap:
                if not recorded_ticks:
                    while grid * period <= previous + period:  # up to the first tick past the earlier item
                        last_tick = grid * period
                        yield tick(last_tick)
                        grid += 1
                    grid = max(grid, math.floor(t / period))
                    to = grid * period
                else:
                    to = t
                if last_tick is not None and to > last_tick:
                    yield Gap(last_tick + shift, to + shift)
            previous = t
            if recorded_ticks:
                if item is None:
                    if last_tick is None or t > last_tick:
                        last_tick = t
                        yield tick(t)
                    continue
            else:
                while grid * period <= t:
                    last_tick = grid * period
                    yield tick(last_tick)
                    grid += 1
            last_item = t
            yield Publish(t + shift, item, shift)
        if last_item is None:
            raise NothingToReplay("nothing to replay")
        if last_tick is None or last_tick <= last_item:
            final = (math.floor(last_item / period) + 1) * period
            last_tick = final if last_tick is None else max(final, last_tick + period)
            yield tick(last_tick)
        yield End(last_item + shift, last_tick + shift, not loop)
        if not loop:
            return
        shift += last_tick - start + period


class Pacer:
    """Wall-clock pacing at ``speed`` × real time: the first action's event time is due at once,
    a later event time t at (t − t_first)/speed seconds after it. ``speed`` 0 = no pacing."""

    def __init__(self, speed: float):
        if not (speed >= 0 and math.isfinite(speed)):
            raise ValueError(f"speed must be a finite number >= 0, got {speed!r}")
        self.speed = speed
        self._origin: tuple[float, float] | None = None

    def hold(self, seconds: float) -> None:
        """The clock was held ``seconds`` (wall clock): event time resumes where it stopped."""
        if self._origin is not None:
            t0, wall0 = self._origin
            self._origin = (t0, wall0 + seconds)

    def skip(self, seconds: float) -> None:
        """``seconds`` of event time were jumped over (a :class:`Gap`): they take no wall clock."""
        if self._origin is not None:
            t0, wall0 = self._origin
            self._origin = (t0 + seconds, wall0)

    def delay(self, t: float, now: float) -> float:
        """Seconds to wait, from wall-clock time ``now`` (s, monotonic), before event time ``t``
        (s) is due; 0 when it is due already (after a stall, replay catches up)."""
        if self.speed == 0:
            return 0.0
        if self._origin is None:
            self._origin = (t, now)
        t0, wall0 = self._origin
        return max(0.0, wall0 + (t - t0) / self.speed - now)


class Consumers:
    """The live consumers of a replay and the progress (event time, s) each has reported.

    A consumer owes the acknowledgement of a tick only if it was live when the tick was
    published: one that appears later is not waited for on ticks it never saw.
    """

    def __init__(self):
        self._joined_after: dict[Hashable, float] = {}
        self._progress: dict[Hashable, float] = {}

    def __len__(self) -> int:
        return len(self._joined_after)

    def appeared(self, consumer: Hashable, last_tick: float | None) -> None:
        """``consumer`` became live when ``last_tick`` (s, None before any) was the last tick out."""
        self._joined_after.setdefault(consumer, -math.inf if last_tick is None else last_tick)

    def vanished(self, consumer: Hashable) -> None:
        self._joined_after.pop(consumer, None)
        self._progress.pop(consumer, None)

    def reported(self, consumer: Hashable, t: float) -> None:
        """``consumer`` has processed every tick up to event time ``t`` (s)."""
        self._progress[consumer] = max(t, self._progress.get(consumer, -math.inf))

    def owing(self, ack: float) -> list[Hashable]:
        """The live consumers that have not yet acknowledged the tick at ``ack`` (s)."""
        return [c for c, joined_after in self._joined_after.items()
                if joined_after < ack and self._progress.get(c, -math.inf) < ack]
