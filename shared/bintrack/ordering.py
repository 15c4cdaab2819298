"""Event-time ordering with bounded lateness (DESIGN §5).

Messages may arrive in any order within the lateness bound; they are released sorted by
(event time, sensor id) once the watermark passes them, so arrival order on the bus does not
change results. The offline runner uses the same buffer with its watermark at each event's
time, so offline and live runs see the same sequence.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from operator import attrgetter
from typing import Generic, TypeVar

T = TypeVar("T")


class ReorderBuffer(Generic[T]):
    """Holds messages until the watermark passes their event time, then releases them sorted.

    ``push`` returns False (and keeps nothing) for a message older than what was already
    released: it came later than the lateness bound allowed.
    """

    def __init__(self, tiebreak: Callable[[T], str] = attrgetter("sensor")):
        """``tiebreak(message)`` orders messages of equal event time (default: the sensor id)."""
        self._tiebreak = tiebreak
        self._heap: list[tuple[float, str, int, T]] = []
        self._counter = itertools.count()
        self.released_until = float("-inf")
        self.late = 0

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, message: T) -> bool:
        if message.t < self.released_until:
            self.late += 1
            return False
        heapq.heappush(self._heap, (message.t, self._tiebreak(message), next(self._counter), message))
        return True

    def release(self, watermark: float) -> list[T]:
        """Every held message with event time < ``watermark`` (s), sorted by (t, sensor)."""
        out = []
        while self._heap and self._heap[0][0] < watermark:
            out.append(heapq.heappop(self._heap)[3])
        self.released_until = max(self.released_until, watermark)
        return out

    def release_all(self) -> list[T]:
        """Everything held, sorted (end of stream)."""
        out = [heapq.heappop(self._heap)[3] for _ in range(len(self._heap))]
        if out:
            self.released_until = max(self.released_until, out[-1].t)
        return out
