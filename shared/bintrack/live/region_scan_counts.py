"""The merge's count of each region's scans (DESIGN §11, order by counts): a region's progress
report says how many scans its base station has published up to the report's time, and the
merge takes the report only once it holds as many.

A put that a client makes just after its router came back can be dropped while the routes are
still being declared again, and a later put on another key still gets through (the base
station's progress report after its lost scans). Without the count the merge would take the
report and publish those scan times without the region, silently.
"""

from __future__ import annotations

from dataclasses import dataclass, field

KEEP = 60.0  # s of event time: scan times kept one by one (a scan sent again after a restart is counted once)


@dataclass
class RegionScanCounts:
    """The scans heard of each region: those of the last KEEP s by time, the older ones counted."""

    times: dict[str, set[float]] = field(default_factory=dict)  # region → times of its recent scans heard
    older: dict[str, int] = field(default_factory=dict)  # region → scans heard before those

    def heard(self, region: str, t: float) -> None:
        """A scan of ``region`` at ``t`` (s) came (live or fetched); a second copy counts once."""
        self.times.setdefault(region, set()).add(t)

    def missing(self, region: str, t: float, sent: int) -> int:
        """How many of the ``sent`` scans that ``region``'s base station reports up to ``t`` (s)
        were not heard. Zero when it counts fewer than heard: a base station restarted without a
        checkpoint counts from zero again, and then its count says nothing."""
        times = self.times.get(region, set())
        held = self.older.get(region, 0) + sum(1 for s in times if s <= t)
        return max(0, sent - held)

    def forget_before(self, t: float) -> None:
        """Keep the times of the last KEEP s before ``t`` (s) only; count the older ones."""
        for region, times in self.times.items():
            old = {s for s in times if s < t - KEEP}
            if old:
                times -= old
                self.older[region] = self.older.get(region, 0) + len(old)
