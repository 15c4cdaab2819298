"""The merge's account of the regions whose base stations went away (DESIGN §9): how long the
merge waits for one before it gives the region up, and the scans a region sends too late,
after the merged scans of their time went out (a region cut off while event time went on)."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

from bintrack.live.watermark import DEPARTED_HOLD, SILENT_AFTER

log = logging.getLogger("bintrack")


class RegionDepartures:
    """The regions service ``name`` stopped hearing from, and their late scans, named in its log."""

    def __init__(self, name: str, now: Callable[[], float] = time.monotonic):
        self.name = name
        self.now = now
        self.departed: dict[str, float | None] = {}  # region gone → the first tick (s) after it went
        self.late: dict[str, list[float]] = {}  # region → times of its scans that came after their time was merged
        self.lagging: dict[str, float] = {}  # region → wall time (s) its progress fell behind the clock
        self.quiet: set[str] = set()  # regions taken for gone while their token is still declared

    def went(self, region: str, shown: int) -> None:
        """The base station of ``region``, whose ``shown`` tracks are in the latest output, is gone."""
        log.warning("%s: region %s's base station is gone; its %d tracks are marked stale unless it is back within "
                    "%g s of event time", self.name, region, shown, DEPARTED_HOLD)
        self.departed[region] = None

    def back(self, region: str, stale: bool) -> bool:
        """The base station of ``region`` is back; whether it was gone (or given up: ``stale``),
        so that what it published meanwhile is to be fetched."""
        was_away = stale or region in self.departed
        self.departed.pop(region, None)
        return was_away

    def silent(self, progress: dict[str, float], t: float, lead: float) -> list[str]:
        """The regions, of those whose token is declared and their progress (s) in ``progress``,
        whose progress has stayed more than DEPARTED_HOLD s plus ``lead`` behind the tick ``t`` (s)
        for SILENT_AFTER s of wall time: each is taken for gone (logged) until it reports again
        (:meth:`reports`). A router can keep the token of a base station behind a cut link
        (see :mod:`bintrack.live.watermark`); the merge would wait for it for ever."""
        out = []
        for region, reported in progress.items():
            if region in self.departed or region in self.quiet or not math.isfinite(reported) \
                    or t - reported <= DEPARTED_HOLD + lead:
                self.lagging.pop(region, None)
                continue
            if self.now() - self.lagging.setdefault(region, self.now()) >= SILENT_AFTER:
                del self.lagging[region]
                self.quiet.add(region)
                log.warning("%s: region %s's base station has not reported since t=%g s, %g s of wall time, though "
                            "its token is still declared (its router out of reach?)", self.name, region, reported,
                            SILENT_AFTER)
                out.append(region)
        return out

    def reports(self, region: str) -> bool:
        """A progress report of ``region`` came: whether it had been taken for gone by :meth:`silent`
        (then it is back, and what it published meanwhile is to be fetched)."""
        if region not in self.quiet:
            return False
        self.quiet.discard(region)
        self.departed.pop(region, None)
        return True

    def tick(self, t: float, lead: float) -> list[str]:
        """The regions to give up at the tick ``t`` (s): gone for DEPARTED_HOLD s of event time
        past the first tick after they went, plus ``lead``, what the replays may have in flight."""
        given_up = []
        for region, since in list(self.departed.items()):
            if since is None:
                self.departed[region] = t
            elif t >= since + DEPARTED_HOLD + lead:
                del self.departed[region]
                given_up.append(region)
        return given_up

    def scan(self, region: str, t: float, merged_up_to: float) -> None:
        """A scan of ``region`` at ``t`` (s) came, the merge having published up to ``merged_up_to``."""
        if t <= merged_up_to:
            self.late.setdefault(region, []).append(t)
        else:
            self.say_late(region)

    def say_late(self, region: str) -> None:
        """Name the scans of ``region`` that came after the merged scans of their time went out
        (a region cut off while event time went on, catching up): left out, not merged silently."""
        times = self.late.pop(region, None)
        if times:
            log.warning("%s: %d scans of region %s (t=%g–%g s) came after the merged scans of their time had been "
                        "published; left out (those merged scans show its last tracks, stale once it was given up)",
                        self.name, len(times), region, min(times), max(times))

    def finish(self) -> None:
        """At the end of the stream: name every region's late scans still unnamed."""
        for region in list(self.late):
            self.say_late(region)
