"""The offline runner: a dataset's events, in event-time order, through the same objects the
services run (transition detector → tracker), giving the rows of tracks.csv."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator

from bintrack.formats import Dataset, ObjectRow, TrackRow
from bintrack.bus_payloads import LineObjectEstimate, LocalEstimate, TrackSet, Transition, VelocityEstimate
from bintrack.message_base import Message
from bintrack.ordering import ReorderBuffer
from bintrack.trackers import Tracker
from bintrack.transition_detector import TransitionDetector

SINGLE_TARGET_TRACK = 0


class TrackerDriver:
    """Feeds a tracker its transitions in event-time order, ties broken by sensor id.

    The same object runs offline and in the live services: transitions are pushed as they
    arrive, and ``advance(watermark)`` releases those before the watermark (s) to the tracker,
    sorted, then lets it emit what is complete. ``finish`` releases everything at the end.
    """

    def __init__(self, tracker: Tracker):
        self.tracker = tracker
        self.buffer: ReorderBuffer[Transition] = ReorderBuffer()

    def push(self, transition: Transition) -> bool:
        """Hold ``transition``; False if it is later than what was already released (late)."""
        return self.buffer.push(transition)

    def advance(self, watermark: float) -> list[Message]:
        out: list[Message] = []
        for transition in self.buffer.release(watermark):
            out.extend(self.tracker.update(transition))
        out.extend(self.tracker.flush(math.nextafter(watermark, -math.inf)))
        return out

    def finish(self) -> list[Message]:
        out: list[Message] = []
        for transition in self.buffer.release_all():
            out.extend(self.tracker.update(transition))
        out.extend(self.tracker.flush(math.inf))
        return out


def run_tracker(dataset: Dataset, tracker: Tracker, on_event: Callable[[int], None] | None = None,
                sensors: set[str] | None = None) -> Iterator[Message]:
    """Feed every event of ``dataset`` to ``tracker`` and yield its outputs, then flush it.

    ``on_event(count)`` is called after each event (for progress display). ``sensors``: only
    these sensors' transitions reach the tracker, as if the others were unplugged (None: all);
    every event still advances event time.
    """
    detector = TransitionDetector(dataset.deployment)
    driver = TrackerDriver(tracker)
    for count, event in enumerate(dataset.events(), start=1):
        transition = detector.update(event)
        if transition is not None:
            yield from driver.advance(transition.t)
            if sensors is None or transition.sensor in sensors:
                driver.push(transition)
        if on_event is not None:
            on_event(count)
    yield from driver.finish()


def run_regions(dataset: Dataset, trackers: dict[str, Tracker], taken: dict[str, set[str]], merge) -> Iterator[Message]:
    """The regions' base stations and the merge, offline: each transition goes to the tracker of
    every region that takes its sensor (``taken``: region → sensor ids); after each event time
    every region's tracker is advanced to it, its ``TrackSet``s given to ``merge`` (a
    :class:`~bintrack.trackers.multi.region_merge.RegionMerge`) with its progress, and the
    merged ``TrackSet``s are yielded — what the live base stations with ``--region`` and the
    merge service publish on ``tracks``."""
    detector = TransitionDetector(dataset.deployment)
    drivers = {region: TrackerDriver(tracker) for region, tracker in trackers.items()}
    for region in drivers:
        merge.back(region)

    def advance(outputs_of: Callable[[TrackerDriver], list[Message]], done: float) -> Iterator[Message]:
        for region, driver in drivers.items():
            for out in outputs_of(driver):
                if isinstance(out, TrackSet):
                    merge.add(region, out)
            yield from merge.progress(region, done)

    for event in dataset.events():
        transition = detector.update(event)
        if transition is None:
            continue
        yield from advance(lambda d: d.advance(transition.t), math.nextafter(transition.t, -math.inf))
        for region, driver in drivers.items():
            if transition.sensor in taken[region]:
                driver.push(transition)
    yield from advance(TrackerDriver.finish, math.inf)
    yield from merge.finish()


def output_rows(outputs: Iterable[Message]) -> Iterator[TrackRow]:
    """tracks.csv rows of tracker outputs: every track of a ``TrackSet``; a single-target
    estimate (``LocalEstimate``, ``VelocityEstimate``) is track 0, a velocity-only one with
    empty x, y. Other outputs (position reports, line objects) have no rows here."""
    for out in outputs:
        if isinstance(out, TrackSet):
            for track in out.tracks:
                yield TrackRow(out.t, track.track, track.x, track.y, track.vx, track.vy)
        elif isinstance(out, (LocalEstimate, VelocityEstimate)):
            yield TrackRow(out.t, SINGLE_TARGET_TRACK, out.x, out.y, out.vx, out.vy)


def output_objects(outputs: Iterable[Message], *, online: bool = False) -> list[ObjectRow]:
    """objects.csv rows of tracker outputs, by object number: the latest revision of each object
    (the highest ``revision``; of equals, the last — a later estimate of a pass refines an
    earlier one); ``online``: each object's first estimate (no ``revision``), what was known when
    the pass ended."""
    latest: dict[int, LineObjectEstimate] = {}
    for out in outputs:
        if not isinstance(out, LineObjectEstimate) or (online and out.revision is not None):
            continue
        have = latest.get(out.object)
        if have is None or (out.revision or 0) >= (have.revision or 0):
            latest[out.object] = out
    return [ObjectRow(*(getattr(m, f) for f in ObjectRow._fields)) for _, m in sorted(latest.items())]
