"""A region's base station takes a sensor agent's progress report only once it holds the
transitions the report counts for its region (order by counts, DESIGN §11).

It subscribes to the transitions of the sensors it takes and to the agents' reports, a
subscriber each, so a report may arrive before transitions it covers. A report says how many
transitions the agent has sent (``sent``: its ``source_seq`` so far) and, in ``sent_to``, how
many of them each region takes. The base station counts those it holds by ``source_seq`` and
moves its watermark past a report only once it holds as many with ``source_seq`` ≤ ``sent``. A
report still short when the agent's next one comes is a gap, fetched from the sensors' state.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field


@dataclass
class Report:
    """An agent's progress report held: its tick ``t`` (s), ``sent``, and ``need``, the
    transitions of ``sent`` this region takes."""

    t: float
    sent: int
    need: int


@dataclass
class SourceCount:
    """What region's base station holds of one agent's transitions."""

    settled: int = 0  # source_seq up to which every transition it takes is held (or named lost)
    settled_count: int = 0  # how many of those it takes
    beyond: set[int] = field(default_factory=set)  # source_seqs held after ``settled``
    reports: deque[Report] = field(default_factory=deque)  # reports held, oldest first

    def count(self, upto: int) -> int:
        """Transitions held with source_seq ≤ ``upto`` (≥ ``settled``)."""
        return self.settled_count + sum(1 for n in self.beyond if n <= upto)


class CountOrder:
    """Region ``region``'s view of each sensor agent's counts (kept in the intake's checkpoint)."""

    def __init__(self, region: str):
        self.region = region
        self.sources: dict[str, SourceCount] = {}

    def held(self, source: str, source_seq: int) -> None:
        """A transition of ``source`` that this region takes is held."""
        counts = self.sources.setdefault(source, SourceCount())
        if source_seq > counts.settled:
            counts.beyond.add(source_seq)

    def report(self, source: str, t: float, sent: int, sent_to: dict[str, int]) -> None:
        """``source`` reported the tick ``t`` (s) with ``sent`` transitions, ``sent_to`` per region."""
        counts = self.sources.setdefault(source, SourceCount())
        if sent < counts.settled:  # it restarted with no checkpoint: counting from 1 again
            counts = self.sources[source] = SourceCount()
        counts.reports.append(Report(t, sent, sent_to.get(self.region, 0)))

    def short(self, source: str, final: bool = False) -> Report | None:
        """The oldest report of ``source`` if it is still short although a later one came (or,
        with ``final``, no later one will): a gap to fetch."""
        counts = self.sources.get(source)
        if counts is None or not counts.reports or (len(counts.reports) < 2 and not final):
            return None
        first = counts.reports[0]
        return first if counts.count(first.sent) < first.need else None

    def ready(self, source: str, force: bool = False) -> list[tuple[float, int, int]]:
        """(t, sent, missing) of the reports of ``source`` whose transitions are all held,
        oldest first, no longer held; with ``force`` the oldest goes too, ``missing`` saying how
        many it lacks (fetched and not answered: lost)."""
        counts = self.sources.get(source)
        out = []
        while counts is not None and counts.reports:
            first = counts.reports[0]
            held = counts.count(first.sent)
            if held < first.need and not force:
                break
            force = False
            counts.reports.popleft()
            counts.settled, counts.settled_count = max(counts.settled, first.sent), max(held, first.need)
            counts.beyond = {n for n in counts.beyond if n > counts.settled}
            out.append((first.t, first.sent, max(0, first.need - held)))
        return out

    def waiting(self) -> list[str]:
        """The agents with reports held."""
        return [source for source, counts in self.sources.items() if counts.reports]

    def forget(self, source: str) -> None:
        """``source`` counts from 1 again (restarted without its checkpoint)."""
        self.sources.pop(source, None)
