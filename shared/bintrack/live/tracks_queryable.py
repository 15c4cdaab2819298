"""The answer of a ``tracks`` queryable (the base station's, the merge's)."""

from __future__ import annotations

from collections.abc import Iterable

import zenoh

from bintrack.messages import TrackSet, encode


def answer_tracks_query(query: zenoh.Query, key: str, latest: TrackSet | None, recent: Iterable[TrackSet]) -> None:
    """Reply to ``query`` on ``key`` with the latest ``TrackSet`` (none before the first); with
    ``?after=T``, with each of the ``recent`` ones later than T (s), in order: what a recorder
    that lost some asks for. A T that is not a number gets an error reply."""
    after = query.parameters.get("after")
    if after is None:
        if latest is not None:
            query.reply(key, encode(latest))
        return
    try:
        after = float(after)
    except ValueError:
        query.reply_err(b"after must be a number of seconds")
        return
    for tracks in recent:
        if tracks.t > after:
            query.reply(key, encode(tracks))
