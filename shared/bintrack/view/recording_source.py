"""A recording played into the map page: ``bintrack view RECORDING.mcap``, no bus needed.

Each page gets its own player (time slider, play/pause, speed): a :class:`MapState` filled
from the recording through the MCAP index. A seek to ``t`` reads, with the mcap library's
indexed ``iter_messages(start_time=…)``, only the messages of the drawn keys from
``t − LOOKBACK`` to ``t`` (tails, the latest scan, each sensor's status), so it costs the same
anywhere in a long recording; playing then reads on from there, ``speed`` seconds of event
time per second of wall clock. A sensor still detecting since before ``t − LOOKBACK`` shows
idle until its next transition.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from mcap.reader import SeekingReader

from bintrack.errors import CommandError
from bintrack.keys import parse_key
from bintrack.message_codec import MessageError, decode
from bintrack.live.recording import KIND_TYPES, open_recording
from bintrack.view.map_messages import DRAWN_KINDS, Item, message_item
from bintrack.view.map_access import check_bind, token_from
from bintrack.view.map_server import DEFAULT_PAGE_QUEUE, PageFeed, listening_socket, make_app, served_line, start_site
from bintrack.view.map_state import DEFAULT_TAIL, MapState

log = logging.getLogger("bintrack")

LOOKBACK = 60.0        # s of event time read before a seek's time
FRAME = 0.05           # s of wall clock between steps of a playing page
STATUS_EVERY = 0.2     # s of wall clock between status items to a playing page
MAX_SPEED = 256.0


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


class RecordingSource:
    """A finalised bintrack recording, opened once; each page gets a :class:`RecordingPage`.

    FormatError (one line) for a file that is not a bintrack recording; CommandError for one
    that was never finalised (it has no index to seek in)."""

    def __init__(self, path: Path | str, tail: float = DEFAULT_TAIL, capacity: int = DEFAULT_PAGE_QUEUE,
                 salvage: bool = False):
        self.recording = open_recording(path, salvage)
        if self.recording.note() is not None:
            log.warning("view: %s; its bad chunks are skipped", self.recording.note())
        if not self.recording.complete:
            raise CommandError(f"{path}: the recording was never finalised, so it has no index to seek in; "
                               "`mcap recover` makes a finalised copy")
        self.path = Path(path)
        self.tail = tail
        self.capacity = capacity
        with open(self.path, "rb") as handle:
            summary = SeekingReader(handle).get_summary()
        self.topics = sorted(channel.topic for channel in summary.channels.values() if _drawn(channel.topic))
        stats = summary.statistics
        if stats is None or not stats.message_count:
            raise CommandError(f"{path}: the recording holds no messages")
        self.range = (stats.message_start_time / 1e9, stats.message_end_time / 1e9)
        self.bad = 0
        self._logged_bad = False

    def snapshot(self) -> Item:
        """The picture at the recording's start (``/state.json``)."""
        state = MapState(self.recording.deployment, self.tail)
        return {**state.snapshot(), "status": self._status(self.range[0], False, 1.0)}

    def _status(self, position: float, playing: bool, speed: float) -> Item:
        return {"k": "status", "mode": "recording", "file": self.path.name, "range": list(self.range),
                "position": position, "playing": playing, "speed": speed, "message": "",
                "net": self.recording.net}

    async def open_page(self) -> RecordingPage:
        page = RecordingPage(self)
        await page.seek(self.range[0])
        page.start()
        return page

    def items(self, reader: SeekingReader, start: float, end: float | None = None) -> Iterator[tuple[float, Item]]:
        """(log time s, item) of the drawn messages from ``start`` (s, inclusive) to ``end``
        (s, inclusive; None: the end), in log-time order; a bad payload is skipped and counted."""
        end_ns = None if end is None else _ns(end) + 1
        messages = reader.iter_messages(topics=self.topics, start_time=_ns(start), end_time=end_ns, log_time_order=True)
        while True:
            try:
                _, channel, message = next(messages)
            except StopIteration:
                return
            except Exception as exc:  # a bad chunk (--salvage): assorted types from the reader
                self._bad_chunk(exc)
                return
            kind = parse_key(channel.topic).kind
            try:
                decoded = decode(KIND_TYPES[kind], message.data)
            except MessageError as exc:
                self.bad += 1
                if not self._logged_bad:
                    self._logged_bad = True
                    log.warning("view: %s: skipped a bad payload on %s: %s (further ones are only counted)",
                                self.path, channel.topic, exc.reason)
                continue
            item = message_item(decoded)
            if item is not None:
                yield message.log_time / 1e9, item


    def _bad_chunk(self, exc: Exception) -> None:
        """A chunk that does not read ends the page's stream there, said once."""
        self.bad += 1
        if not self._logged_bad:
            self._logged_bad = True
            log.warning("view: %s: a chunk does not read (%s); the picture stops before it", self.path,
                        type(exc).__name__)


def _drawn(topic: str) -> bool:
    try:
        return parse_key(topic).kind in DRAWN_KINDS
    except ValueError:
        return False


class RecordingPage:
    """One page's player: position (event time, s), playing, speed; commands ``play``,
    ``pause``, ``seek`` (``t``, s), ``speed`` (``x``), ``snapshot``."""

    def __init__(self, source: RecordingSource):
        self.source = source
        self.state = MapState(source.recording.deployment, source.tail)
        self.feed = PageFeed(self.snapshot, source.capacity)
        self.position = source.range[0]
        self.playing = False
        self.speed = 1.0
        self._handle = open(source.path, "rb")
        self._reader = SeekingReader(self._handle, validate_crcs=True)
        self._stream: Iterator[tuple[float, Item]] | None = None
        self._next: tuple[float, Item] | None = None
        self._lock = asyncio.Lock()
        self._task: asyncio.Task | None = None

    def status(self) -> Item:
        return self.source._status(self.position, self.playing, self.speed)

    def snapshot(self) -> Item:
        return {**self.state.snapshot(), "status": self.status()}

    def start(self) -> None:
        self._task = asyncio.create_task(self._play())

    async def seek(self, t: float) -> None:
        """Show the picture at event time ``t`` (s, clamped to the recording)."""
        t0, t1 = self.source.range
        t = min(max(t, t0), t1)
        start = max(t0, t - max(LOOKBACK, self.source.tail))

        def read() -> list[Item]:
            return [item for _, item in self.source.items(self._reader, start, t)]

        async with self._lock:
            items = await asyncio.to_thread(read)
            self.state.clear()
            for item in items:
                self.state.apply(item)
            self.position = t
            self._stream = self.source.items(self._reader, t + 1e-9)
            self._next = None
            self.feed.request_snapshot()

    async def command(self, message: dict) -> None:
        cmd = message.get("cmd")
        if cmd == "play":
            if self.position >= self.source.range[1]:
                await self.seek(self.source.range[0])
            self.playing = True
        elif cmd == "pause":
            self.playing = False
        elif cmd == "seek" and _number(message.get("t")):
            await self.seek(float(message["t"]))
            return
        elif cmd == "speed" and _number(message.get("x")) and 0 < message["x"] <= MAX_SPEED:
            self.speed = float(message["x"])
        elif cmd == "snapshot":
            self.feed.request_snapshot()
            return
        else:
            log.warning("view: a page sent an unknown command %r; ignored", message)
            return
        self.feed.push(self.status())

    async def _play(self) -> None:
        last = last_status = time.monotonic()
        while not self.feed.closed:
            await asyncio.sleep(FRAME)
            now = time.monotonic()
            elapsed, last = now - last, now
            if not self.playing:
                continue
            async with self._lock:
                target = min(self.source.range[1], self.position + elapsed * self.speed)
                self._advance(target)
                self.position = target
                if target >= self.source.range[1]:
                    self.playing = False
            if not self.playing or now - last_status >= STATUS_EVERY:
                self.feed.push(self.status())
                last_status = now

    def _advance(self, target: float) -> None:
        """Apply and send every item up to event time ``target`` (s)."""
        while True:
            if self._next is None:
                self._next = next(self._stream, None)
                if self._next is None:
                    return
            t, item = self._next
            if t > target:
                return
            self._next = None
            if self.state.apply(item):
                self.feed.push(item)

    def close(self) -> None:
        self.feed.close()
        if self._task is not None:
            self._task.cancel()
        self._handle.close()


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def serve_recording(args: argparse.Namespace) -> int:
    """``bintrack view RECORDING.mcap``: serve the page on the recording until Ctrl-C/SIGTERM."""
    token = token_from(args.token)
    check_bind(args.bind, token)
    source = RecordingSource(args.recording, tail=args.tail, salvage=args.salvage)

    async def main() -> int:
        try:
            sock = listening_socket(args.bind, args.port)
            runner = await start_site(make_app(source, token), sock)
        except OSError as exc:
            raise CommandError(str(exc)) from None
        t0, t1 = source.range
        sys.stderr.write(f"{served_line('view', args.bind, args.port, sock, token)} ({source.path.name}: "
                         f"{t1 - t0:.1f} s of event time, {len(source.recording.deployment.sensors)} sensors)\n")
        sys.stderr.flush()
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            await stop.wait()
        finally:
            await runner.cleanup()
        if source.bad:
            log.warning("view: %d bad payloads skipped in %s", source.bad, source.path)
        return 0

    return asyncio.run(main())
