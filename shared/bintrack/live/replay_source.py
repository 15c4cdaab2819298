"""What replay plays: a dataset folder or a recording, as keys and payloads, and the raw
samples of its last ticks (for a restarted sensor agent's ``recent`` query and for sending
them again after replay itself restarted)."""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path

import zenoh

from bintrack.formats import TruthRow, open_dataset
from bintrack.keys import Keys
from bintrack.live.recording import Record, open_recording, replay_items, shift_payload
from bintrack.live.replay_schedule import Publish
from bintrack.bus_payloads import Clock, TruthSample
from bintrack.message_codec import encode, encode_raw_sample
from bintrack.time_span import TimeSpan

Put = Callable[[str, bytes, bytes | None], None]


RECENT_SPAN = 30.0  # s of event time whose raw samples replay keeps at least, for ``recent``


class ReplaySource:
    """The source at ``path`` (a ``.mcap`` recording, else a dataset folder); raises
    FormatError for a bad one (a corrupt recording too, unless ``salvage``): its deployment at
    once, every row in :meth:`check`, which replay runs before it publishes anything."""

    def __init__(self, path: str, filters: Iterable[str], memory_ticks: int, salvage: bool = False):
        path = Path(path)
        if path.suffix == ".mcap":
            self.recording, self.dataset, self.truth = open_recording(path, salvage), None, []
            self.deployment, self.net = self.recording.deployment, self.recording.net
            self.total = None
        else:
            self.recording, self.dataset = None, open_dataset(path)
            self.deployment = self.dataset.deployment
            self.net = self.deployment.name
            self.total = None  # rows, once checked
            # truth.csv, if the dataset has one, is published on `truth` (sorted by t; read and checked now)
            self.truth = sorted(self.dataset.truth(), key=lambda row: row.t) if self.dataset.has_truth else []
        self.filters = [zenoh.KeyExpr(k) for k in filters]
        self._matches: dict[str, bool] = {}
        self.keys: Keys | None = None  # the keys it is played on (set by :meth:`play_on`)
        self.source_prefix = Keys(self.recording.net).prefix if self.recording is not None else None
        self.raw_keys: dict[str, str] = {}  # sensor id → its raw key
        # (tick before it, key, payload) of the raw samples of the last few ticks and RECENT_SPAN s, for ``recent``
        self.recent: deque[tuple[float, str, bytes]] = deque()
        self.recent_ticks: deque[float] = deque(maxlen=memory_ticks)
        self.last_tick: float | None = None
        self._recorded_step: float | None = None  # a recording's largest gap between ticks, s, once checked
        self.span: TimeSpan | None = None  # a dataset's event times, once checked
        self.raw_published = 0  # raw samples published (or walked past by a restart), in each clock tick
        # with regions: raw key → its sensor's region, and the raw samples published per region (a tick's sent_to)
        self.region_of: dict[str, str] = {}
        self.raw_published_to: dict[str, int] | None = None

    def check(self) -> None:
        """Read every row of a dataset's events, or every tick of a recording (FormatError for a
        bad one); blocking (a few tenths of a second per hundred thousand rows)."""
        if self._recorded_step is not None or self.span is not None:
            return
        if self.dataset is not None:
            self.span = TimeSpan.of(e.t for e in self.dataset.events())
            self.total = self.span.count
        else:
            ticks = [t for t, item in replay_items(self.recording) if item is None]
            self._recorded_step = max((b - a for a, b in zip(ticks, ticks[1:])), default=0.0)

    def play_on(self, keys: Keys) -> None:
        self.keys = keys
        if self.deployment.regions:
            from bintrack.regions import RegionMap  # shapely: loaded only for a deployment with regions

            try:
                regions = RegionMap(self.deployment)
            except ValueError:  # a bad region: the region's services say so, and none can narrow
                return
            self.region_of = {keys.raw(sid): name for name in regions.names for sid in regions.own_sensors(name)}
            self.raw_published_to = dict.fromkeys(regions.names, 0)

    def counts(self) -> dict[str, int] | None:
        """The raw samples published so far per region (a copy), None without regions."""
        return None if self.raw_published_to is None else dict(self.raw_published_to)

    def largest_step(self, period: float, max_gap: float) -> float:
        """The largest gap between two ticks (s): ``period``, or a recording's own if larger, or
        a dataset's longest silence if replay jumps over it (longer than ``max_gap``, s)."""
        self.check()
        if self.recording is None:  # ticks on the grid, or a jump over a silence longer than max_gap
            return max(period, self.span.silence if self.span.silence > max_gap else 0.0)
        return max(period, self._recorded_step)

    def _keep(self, key: str) -> bool:
        if not self.filters:
            return True
        if key not in self._matches:
            self._matches[key] = any(f.intersects(zenoh.KeyExpr(key)) for f in self.filters)
        return self._matches[key]

    def items(self) -> Iterable[tuple[float, object]]:
        """One pass of the source: (event time s, item), in event-time order (None: a recorded tick)."""
        if self.dataset is not None:
            events = ((e.t, e) for e in self.dataset.events() if not self.filters or self._keep(self.keys.raw(e.sensor)))
            if self.truth and self._keep(self.keys.truth()):
                # truth.csv rows beside the events in event time; an event before a truth row at the same t
                return heapq.merge(events, ((row.t, row) for row in self.truth), key=lambda item: item[0])
            return events
        return replay_items(self.recording, self._keep)

    def publish(self, action: Publish, put: Put | None, attachment: bytes | None = None) -> None:
        """Put the sample of ``action`` (a raw sample with ``attachment``) and keep a raw sample
        for ``recent``; with ``put`` None only keep it (a restarted replay rebuilding what it had
        published)."""
        item = action.item
        if isinstance(item, Record):
            raw = item.kind == "raw"
            if put is not None or raw:
                key = self.keys.prefix + item.key[len(self.source_prefix):]
                payload = shift_payload(item.payload, action.shift)
                if put is not None:
                    put(key, payload, attachment if raw else None)
                if raw:
                    self._remember(key, payload)
        elif isinstance(item, TruthRow):
            if put is not None:
                put(self.keys.truth(), encode(TruthSample(t=action.t, target=item.target, x=item.x, y=item.y)), None)
        else:
            key = self.raw_keys.get(item.sensor) or self.raw_keys.setdefault(item.sensor, self.keys.raw(item.sensor))
            payload = encode_raw_sample(action.t, item.sensor, item.value)
            if put is not None:
                put(key, payload, attachment)
            self._remember(key, payload)

    def _remember(self, key: str, payload: bytes) -> None:
        """Keep a raw sample put after the last tick, for ``recent`` and for sending it again."""
        self.raw_published += 1
        if self.raw_published_to is not None:
            region = self.region_of.get(key)
            if region is not None:
                self.raw_published_to[region] += 1
        self.recent.append((-math.inf if self.last_tick is None else self.last_tick, key, payload))

    def ticked(self, t: float) -> None:
        """After the tick at ``t`` (s): forget samples older than any live consumer can still need
        (it has acknowledged a tick at most max_ahead ticks back) and than :data:`RECENT_SPAN`
        (what a consumer that was out of reach, its link cut, may still ask for)."""
        self.last_tick = t
        self.recent_ticks.append(t)
        oldest = min(self.recent_ticks[0], t - RECENT_SPAN)
        while self.recent and self.recent[0][0] < oldest:
            self.recent.popleft()

    def last_ticks(self) -> list[tuple[str, bytes]]:
        """(key, payload) of the raw samples put since the oldest of the last few ticks (what a
        consumer may not have acknowledged yet), in order: what a restarted replay sends again
        (not the whole RECENT_SPAN kept for ``recent``)."""
        oldest = self.recent_ticks[0] if self.recent_ticks else -math.inf
        return [(key, payload) for tick, key, payload in self.recent if tick >= oldest]

    def recent_answer(self, after: float) -> list[bytes]:
        """``control/recent?after=T``: each raw sample published after the tick at ``after`` (s),
        in order, then a ``Clock`` (the last tick published, 0 before the first, and every raw
        sample published so far in ``sent``) that ends the answer, so the asker knows it is
        complete, and can tell from the ``sent`` of the tick at ``after`` how many samples since
        are no longer held (with regions, ``sent_to`` per region: what a region's sensor agent
        holds once it has taken the answer)."""
        answer = [payload for tick, _, payload in self.recent if tick >= after]
        answer.append(encode(Clock(t=0.0 if self.last_tick is None else self.last_tick, sent=self.raw_published,
                                   sent_to=self.counts())))
        return answer
