"""The track sets a recording holds, so that each is recorded once, and the track sets it may
lack after a restart or a router outage, fetched once their publisher has caught up (DESIGN §6).

A restarted base station (or merge) sends again the track sets since its checkpoint, and one
that restarted with the recorder has not published, when the recorder comes back, the sets it
will send again: the recorder fetches the sets it lacks (``tracks?after=T``) only once the
publisher's progress says it has released past the first tick the recorder heard again (or it
reported done), and records each set once by (key, event time, payload).
"""

from __future__ import annotations

import hashlib
from collections import deque

from bintrack.bus_payloads import Clock

TRACK_KINDS = frozenset({"tracks", "region_tracks"})
TRACK_SOURCES = ("basestation", "merge")  # the services whose ``tracks`` queryable a recorder asks
LEDGER_SPAN = 4096  # track sets remembered per key (a duplicate comes within a checkpoint's span)


def _digest(payload: bytes) -> bytes:
    return hashlib.blake2b(payload, digest_size=8).digest()


class TrackLedger:
    """The newest LEDGER_SPAN track sets recorded on each key, by (event time, payload)."""

    def __init__(self):
        self.order: dict[str, deque[tuple[float, bytes]]] = {}
        self.members: dict[str, set[tuple[float, bytes]]] = {}

    def seen(self, key: str, t: float, payload: bytes) -> bool:
        return (t, _digest(payload)) in self.members.get(key, ())

    def add(self, key: str, t: float, payload: bytes) -> None:
        entry = (t, _digest(payload))
        members = self.members.setdefault(key, set())
        if entry in members:
            return
        order = self.order.setdefault(key, deque())
        if len(order) >= LEDGER_SPAN:
            members.discard(order.popleft())
        order.append(entry)
        members.add(entry)


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
