"""Whether a stream's event times are plausible: a recording of people walking spans hours or
days, not decades; a span beyond that is a clock jump or a stray row, warned about in one line."""

from __future__ import annotations

from collections.abc import Iterable

MAX_SILENCE = 60.0
"""s of event time without any transition after which the time that follows is empty: a tracker
that works on a grid of scans or periods (mcmcda, the motion trackers) goes on for this long
after the last transition, as if it could still come, then skips to the next transition in O(1)
— a gap of days in the events (a clock jump, a stray row) costs no more than a minute of scans.
Tracks do not survive such a gap: it is far longer than any track may go unreported."""

PLAUSIBLE_SPAN = 30 * 86400.0
"""s of event time a stream may span without a warning (30 days)"""


class TimeSpan:
    """The first and last event times (s) of a stream and its longest silence (s, and the time
    it follows), fed with :meth:`add` in time order."""

    def __init__(self):
        self.first: float | None = None
        self.last: float | None = None
        self.silence = 0.0
        self.silence_after: float | None = None
        self.count = 0

    @classmethod
    def of(cls, times: Iterable[float]) -> TimeSpan:
        span = cls()
        for t in times:
            span.add(t)
        return span

    def add(self, t: float) -> None:
        self.count += 1
        if self.first is None:
            self.first = t
        elif t - self.last > self.silence:
            self.silence, self.silence_after = t - self.last, self.last
        self.last = t

    def warning(self, what: str) -> str | None:
        """One line if the times span more than ``PLAUSIBLE_SPAN``, else None."""
        if self.first is None or self.last - self.first <= PLAUSIBLE_SPAN:
            return None
        return (f"{what} spans {self.last - self.first:.3g} s of event time (t = {self.first:g} to {self.last:g} s; "
                f"the longest silence, {self.silence:.3g} s, follows t = {self.silence_after:g} s); silences over "
                f"{MAX_SILENCE:g} s are passed over as empty time")
