"""The merge's count of each region's scans (DESIGN §11, order by counts): a region's progress
report says how many scans its base station has published up to the report's time, and the
merge takes the report only once it holds as many.

A put that a client makes just after its router came back can be dropped while the routes are
still being declared again, and a later put on another key still gets through (the base
station's progress report after its lost scans). Without the count the merge would take the
report and publish those scan times without the region, silently.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

KEEP = 60.0  # s of event time: scan times kept one by one (a scan sent again after a restart is counted once)
SHORT_FOR = 2.0  # s of wall time a region's reports may count scans not heard before those are named lost

log = logging.getLogger("bintrack")


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


class ReportCheck:
    """Service ``name``'s check of each region's progress reports against ``counts``: a report
    counting scans not heard has them fetched first (``fetch(region)``, blocking); still short,
    it is set aside and asked again at each later report or :meth:`retry`, for up to SHORT_FOR s
    of wall time, and then the scans are named lost in the log and the report is taken."""

    def __init__(self, name: str, counts: RegionScanCounts, fetch: Callable[[str], object],
                 now: Callable[[], float] = time.monotonic):
        self.name = name
        self.counts = counts
        self.fetch = fetch
        self.now = now
        self.reported: dict[str, tuple[float, int]] = {}  # region → (t, sent) of its last report
        self.short: dict[str, float] = {}  # region → wall time (s) since its reports count scans not heard

    def complete(self, region: str, t: float, sent: int, wait: bool = True) -> bool:
        """Whether the report of ``region`` up to ``t`` (s) counting ``sent`` scans may be taken
        (set aside otherwise; never set aside without ``wait``)."""
        self.reported[region] = (t, sent)
        if not self.counts.missing(region, t, sent):
            self.short.pop(region, None)
            return True
        self.fetch(region)
        missing = self.counts.missing(region, t, sent)
        if not missing:
            log.info("%s: region %s's scans up to t=%g s had not all arrived; fetched from its base station",
                     self.name, region, t)
            self.short.pop(region, None)
            return True
        if wait and self.now() - self.short.setdefault(region, self.now()) < SHORT_FOR:
            return False
        log.warning("%s: %d scans region %s's base station published up to t=%g s never arrived and it no longer "
                    "gives them; merged without them", self.name, missing, region, t)
        self.counts.older[region] = self.counts.older.get(region, 0) + missing
        self.short.pop(region, None)
        return True

    def retry(self, live: set[str]) -> list[tuple[str, float]]:
        """(region, t) of each report set aside, of the ``live`` regions, that may be taken now
        (no later report came to ask again)."""
        return [(region, self.reported[region][0]) for region in list(self.short)
                if region in live and self.complete(region, *self.reported[region])]

    def finish(self) -> None:
        """At the end of the stream: every region's last report checked, nothing set aside."""
        for region, (t, sent) in list(self.reported.items()):
            self.complete(region, t, sent, wait=False)
