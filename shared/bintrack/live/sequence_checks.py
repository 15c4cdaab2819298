"""Per-sensor ``seq`` and per-agent ``source_seq`` checks: how a receiver sees a lost transition
(DESIGN §3)."""

from __future__ import annotations

from bintrack.bus_payloads import Transition


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

    def settle(self, source: str, upto: int) -> None:
        """Every transition of ``source`` up to ``upto`` is accounted for (a region's base
        station, which hears a part of them only, knows by their count)."""
        n = max(self._contiguous.get(source, 0), upto)
        beyond = self._beyond.get(source, set())
        while n + 1 in beyond:
            n += 1
        self._contiguous[source] = n
        self._beyond[source] = {m for m in beyond if m > n}

    def contiguous(self) -> dict[str, int]:
        """source → the highest ``source_seq`` up to which every transition of it was received."""
        return dict(self._contiguous)

    def first_missing(self, source: str, sent: int) -> int | None:
        """The lowest ``source_seq`` ≤ ``sent`` not received from ``source``, or None."""
        n = self._contiguous.get(source, 0)
        return n + 1 if n < sent else None
