"""Raw samples → transitions: the pure core of a sensor agent (papers 000, 001).

A binary sensor reports only when its status changes; each sensor numbers its transitions
with ``seq`` from 1 so that a receiver can see a lost one. A line sensor's report is an
instant (the beam was crossed), so every report of it is a transition.
"""

from __future__ import annotations

from .formats import Event, idle_value
from .messages import Deployment, LineSensor, Transition


class TransitionDetector:
    """Turns a stream of samples (events.csv rows or ``RawSample``s) into ``Transition``s."""

    def __init__(self, deployment: Deployment, sensors: list[str] | None = None):
        by_id = deployment.by_id()
        ids = list(by_id) if sensors is None else sensors
        unknown = [s for s in ids if s not in by_id]
        if unknown:
            raise ValueError(f"unknown sensor ids: {', '.join(unknown)}")
        self._instant = {s for s in ids if isinstance(by_id[s], LineSensor)}
        self._status = {s: idle_value(by_id[s]) for s in ids}
        self._seq = dict.fromkeys(ids, 0)

    def update(self, event: Event) -> Transition | None:
        """The transition ``event`` causes, or None when it repeats the sensor's status."""
        previous = self._status[event.sensor]
        if event.value == previous and event.sensor not in self._instant:
            return None
        self._status[event.sensor] = event.value
        self._seq[event.sensor] += 1
        return Transition(
            t=event.t, sensor=event.sensor, value=event.value, previous=previous, seq=self._seq[event.sensor]
        )

    def status(self, sensor: str) -> tuple[int, int]:
        """(current status, seq of the last transition) of ``sensor``."""
        return self._status[sensor], self._seq[sensor]


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
