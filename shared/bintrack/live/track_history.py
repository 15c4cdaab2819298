"""The track sets a service published lately, the ``tracks`` queryable that serves them (the
base station's, the merge's), and the fetches from such queryables."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable

import zenoh

from bintrack.bus_payloads import TrackSet
from bintrack.keys import Keys
from bintrack.live.recording_files import FLUSH_SPAN
from bintrack.message_codec import MessageError, decode, encode

# the recent track sets kept for the ``tracks?after=T`` queryable: those of the last TRACKS_SPAN s
# of event time (twice the span a recorder's flush leaves open to a kill, which it fetches back),
# and at most TRACKS_HISTORY of them (memory stays bounded)
TRACKS_SPAN = 2 * FLUSH_SPAN
TRACKS_HISTORY = 16384


class TrackHistory:
    """The latest ``TrackSet`` published on ``key`` and those of the TRACKS_SPAN s before it."""

    def __init__(self, key: str):
        self.key = key
        self.latest: TrackSet | None = None
        self.recent: deque[TrackSet] = deque(maxlen=TRACKS_HISTORY)

    def add(self, tracks: TrackSet) -> None:
        self.latest = tracks
        self.recent.append(tracks)
        while self.recent[0].t < tracks.t - TRACKS_SPAN:
            self.recent.popleft()

    def restore(self, latest: TrackSet | None, recent: Iterable[TrackSet] = ()) -> None:
        """Take back what a checkpoint kept."""
        self.latest = latest
        self.recent.extend(recent)

    def answer(self, query: zenoh.Query) -> None:
        """Reply to ``query`` with the latest ``TrackSet`` (none before the first); with
        ``?after=T``, with each of the recent ones later than T (s), in order: what a recorder
        that lost some asks for. A T that is not a number gets an error reply."""
        after = query.parameters.get("after")
        if after is None:
            if self.latest is not None:
                query.reply(self.key, encode(self.latest))
            return
        try:
            after = float(after)
        except ValueError:
            query.reply_err(b"after must be a number of seconds")
            return
        for tracks in self.recent:
            if tracks.t > after:
                query.reply(self.key, encode(tracks))


def fetch_tracks_after(query: Callable[[str, float], list[bytes]], key: str, after: float,
                       report: Callable[[str, str], None]) -> list[tuple[TrackSet, bytes]]:
    """(track set, payload) of each one later than ``after`` (s) that the ``tracks`` queryable on
    ``key`` still holds, in order, each later than the one before; a bad reply is reported.
    ``query(selector, timeout)`` is a blocking get."""
    fetched = []
    for payload in query(f"{key}?after={after!r}", 2.0):
        try:
            tracks = decode(TrackSet, payload)
        except MessageError as exc:
            report(key, exc.reason)
            continue
        if tracks.t > after:
            fetched.append((tracks, payload))
            after = tracks.t
    return fetched


def fetch_region_tracks(query: Callable[[str, float], list[bytes]], keys: Keys, regions: Iterable[str],
                        after: float, report: Callable[[str, str], None]) -> list[tuple[str, TrackSet]]:
    """(region, scan) of every scan later than ``after`` (s) that the base stations of
    ``regions`` still hold (their ``region/<r>/tracks?after=T`` queryables), as they answered;
    a bad reply is reported. ``query(selector, timeout)`` is a blocking get."""
    fetched = []
    for region in regions:
        key = keys.region_tracks(region)
        for payload in query(f"{key}?after={after!r}", 2.0):
            try:
                fetched.append((region, decode(TrackSet, payload)))
            except MessageError as exc:
                report(key, exc.reason)
    return fetched
