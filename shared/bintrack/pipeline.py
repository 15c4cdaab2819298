"""The offline runner: a dataset's events, in event-time order, through the same objects the
services run (transition detector → tracker), giving the rows of tracks.csv."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

from .formats import Dataset, TrackRow
from .messages import LocalEstimate, TrackSet
from .trackers import Tracker
from .transitions import TransitionDetector

SINGLE_TARGET_TRACK = 0


def run_tracker(dataset: Dataset, tracker: Tracker, on_event: Callable[[int], None] | None = None) -> Iterator[LocalEstimate | TrackSet]:
    """Feed every event of ``dataset`` to ``tracker`` and yield its outputs, then flush it.

    ``on_event(count)`` is called after each event (for progress display).
    """
    detector = TransitionDetector(dataset.deployment)
    last_t = None
    for count, event in enumerate(dataset.events(), start=1):
        last_t = event.t
        transition = detector.update(event)
        if transition is not None:
            yield from tracker.update(transition)
        if on_event is not None:
            on_event(count)
    if last_t is not None:
        yield from tracker.flush(last_t)


def output_rows(outputs: Iterable[LocalEstimate | TrackSet]) -> Iterator[TrackRow]:
    """tracks.csv rows of tracker outputs: a single-target estimate is track 0."""
    for out in outputs:
        if isinstance(out, TrackSet):
            for track in out.tracks:
                yield TrackRow(out.t, track.track, track.x, track.y, track.vx, track.vy)
        else:
            yield TrackRow(out.t, SINGLE_TARGET_TRACK, out.x, out.y, out.vx, out.vy)
