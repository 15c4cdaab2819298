"""The track sets a recording holds, so that each is recorded once, and the track sets it may
lack after a restart or a router outage, fetched once their publisher has caught up (DESIGN §6).

A restarted base station (or merge) sends again the track sets since its checkpoint, and one
that restarted with the recorder has not published, when the recorder comes back, the sets it
will send again: the recorder fetches the sets it lacks (``tracks?after=T``) only once the
publisher's progress says it has released past the first tick the recorder heard again (or it
reported done), and records each set once by (key, event time, payload).
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
from collections import deque
from collections.abc import Callable

from bintrack.bus_payloads import Clock, TrackSet
from bintrack.keys import parse_key
from bintrack.live.track_history import fetch_tracks_after
from bintrack.message_codec import MessageError, decode

TRACK_KINDS = frozenset({"tracks", "region_tracks"})
TRACK_SOURCES = ("basestation", "merge")  # the services whose ``tracks`` queryable a recorder asks
LEDGER_SPAN = 4096  # track sets remembered per key (a duplicate comes within a checkpoint's span)

log = logging.getLogger("bintrack")


def _digest(payload: bytes) -> bytes:
    return hashlib.blake2b(payload, digest_size=8).digest()


class TrackLedger:
    """How many times each of the newest LEDGER_SPAN track sets of each key is in the file, by
    (event time, payload). Equal sets can be legitimate (a relay of two equal estimates), so a
    set is a duplicate only after a publisher came back (:meth:`returned`): then the n-th
    arrival of a set is one if the file holds it n times already (the publisher sends again
    what it sent since its checkpoint)."""

    def __init__(self):
        self.order: dict[str, deque[tuple[float, bytes]]] = {}
        self.counts: dict[str, dict[tuple[float, bytes], int]] = {}
        self.since_return: dict[str, dict[tuple[float, bytes], int]] | None = None

    def returned(self) -> None:
        """A publisher came back (or this recorder restarted): what arrives may be sent again."""
        self.since_return = {}

    def duplicate(self, key: str, t: float, payload: bytes) -> bool:
        """Whether this arrival of a set is one the file holds already (see the class)."""
        if self.since_return is None:
            return False
        entry = (t, _digest(payload))
        seen = self.since_return.setdefault(key, {})
        seen[entry] = seen.get(entry, 0) + 1
        return seen[entry] <= self.counts.get(key, {}).get(entry, 0)

    def held(self, key: str, t: float, payload: bytes) -> int:
        """How many times the file holds this set."""
        return self.counts.get(key, {}).get((t, _digest(payload)), 0)

    def add(self, key: str, t: float, payload: bytes) -> None:
        entry = (t, _digest(payload))
        counts = self.counts.setdefault(key, {})
        order = self.order.setdefault(key, deque())
        if len(order) >= LEDGER_SPAN:
            old = order.popleft()
            counts[old] -= 1
            if not counts[old]:
                del counts[old]
                if self.since_return is not None:
                    self.since_return.get(key, {}).pop(old, None)
        order.append(entry)
        counts[entry] = counts.get(entry, 0) + 1


class TrackGap:
    """The track sets published after ``after`` (s) that the recording may lack, until the
    publisher has released past ``until``, the first clock tick recorded since (s)."""

    def __init__(self):
        self.after: float | None = None
        self.until: float | None = None

    @property
    def open(self) -> bool:
        return self.after is not None

    def start(self, after: float) -> None:
        """The recording may lack the track sets after ``after`` (s); a gap already open stays
        open from its own start."""
        if self.after is None:
            self.after, self.until = after, None

    def tick(self, t: float) -> None:
        if self.after is not None and self.until is None:
            self.until = t

    def caught_up(self, service: str, report: Clock) -> bool:
        """Whether ``service``'s progress ``report`` says it has published every track set
        before ``until``: then the gap can be fetched whole."""
        return (self.until is not None and service in TRACK_SOURCES and report.released is not None
                and report.released >= self.until)

    def close(self) -> None:
        self.after = self.until = None


class TrackRefill:
    """The recorder's part that fetches the track sets a restart or a router outage kept from
    it: :meth:`start` opens a gap after the newest set recorded, :meth:`tick` and
    :meth:`progress` follow the run, and the fetch (``query(selector, timeout)``, off the loop)
    runs once the publisher caught up or, at the latest, in :meth:`finish`. ``record(key,
    tracks, payload, n)`` writes the ``n``-th fetched copy of a set if the file holds fewer
    (whether it did); ``present()`` says
    whether a publisher's token is there to answer."""

    def __init__(self, key: str, query: Callable[[str, float], list[bytes]],
                 record: Callable[[str, TrackSet, bytes, int], bool], report: Callable[[str, str], None],
                 present: Callable[[], bool]):
        self.key = key
        self.present = present
        self.query = query
        self.record = record
        self.report = report
        self.gap = TrackGap()
        self._task: asyncio.Task | None = None

    def start(self, after: float) -> None:
        self.gap.start(after)
        log.info("recorder: the track sets published after t=%g s are fetched once their publisher has caught up",
                 after)

    def tick(self, t: float) -> None:
        self.gap.tick(t)

    def progress(self, key: str, payload: bytes) -> None:
        """A sample on ``key``: a publisher's progress report may say it has caught up."""
        if self.gap.until is None or "/control/progress/" not in key:
            return
        try:
            parsed, report = parse_key(key), decode(Clock, payload)
        except (ValueError, MessageError):
            return
        if self.gap.caught_up(parsed.service, report):
            self._fill_soon(f"the {parsed.service} had released to t={report.released:g} s")

    async def finish(self) -> None:
        """At the end of the stream, every publisher done: what they hold is whole."""
        if self.gap.open:
            self._fill_soon("at the end of the stream, from publishers that are done")
        if self._task is not None:
            await self._task
            self._task = None

    def _fill_soon(self, why: str) -> None:
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._fill(why))

    async def _fill(self, why: str) -> None:
        after = self.gap.after
        self.gap.close()
        if not self.present():
            log.warning("recorder: the track sets published after t=%g s may be missing from the file: no base "
                        "station or merge is there to fetch them from", after)
            return
        fetched = await asyncio.to_thread(fetch_tracks_after, self.query, self.key, after, self.report)
        recorded = sum(self.record(self.key, tracks, payload, n) for tracks, payload, n in _numbered(fetched))
        log.info("recorder: %d track sets published after t=%g s fetched (%s); %d more were recorded already",
                 recorded, after, why, len(fetched) - recorded)


def _numbered(fetched: list[tuple[TrackSet, bytes]]) -> list[tuple[TrackSet, bytes, int]]:
    """Each fetched (set, payload) with how many equal ones came up to it (1 for the first)."""
    counts: dict[tuple[float, bytes], int] = {}
    out = []
    for tracks, payload in fetched:
        entry = (tracks.t, _digest(payload))
        counts[entry] = counts.get(entry, 0) + 1
        out.append((tracks, payload, counts[entry]))
    return out
