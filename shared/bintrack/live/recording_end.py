"""The recorder's end of stream: once replay's ``control/eos`` has come and every live upstream
instance has reported done, the file is finalised and the recorder reports done (``--until
eos``), or it reports done and records on (``--until stopped``)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Iterable

from bintrack.keys import ParsedKey
from bintrack.live.end_of_stream import UpstreamDone
from bintrack.live.recording_sink import RecordingSink
from bintrack.live.track_ledger import TrackRefill

WAIT_LOG_INTERVAL = 5.0  # s of wall clock between "still waiting" lines

log = logging.getLogger("bintrack")


class RecordingEnd:
    """Waits for the end of stream and the ``upstream`` services' done reports, then finishes
    ``sink``'s recording (after ``refill`` fetched what it lacks) and calls ``report_done(t)``;
    with ``until_eos`` it then returns, else it records on. ``stopping`` ends the wait."""

    def __init__(self, upstream: Iterable[str], sink: RecordingSink, refill: TrackRefill,
                 report_done: Callable[[float], None], until_eos: bool, stopping: asyncio.Event):
        self.upstream = UpstreamDone(upstream)
        self.sink = sink
        self.refill = refill
        self.report_done = report_done
        self.until_eos = until_eos
        self.stopping = stopping
        self.eos: float | None = None
        self.changed = asyncio.Event()

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        self.upstream.on_presence(parsed, present)
        self.changed.set()

    def on_eos(self, t: float, awaited: Iterable[str] = ()) -> None:
        """Replay's end of stream at ``t`` (s), which names the ``awaited`` services."""
        self.upstream.expect(awaited)
        self.eos = t
        self.changed.set()

    def on_done(self, service: str, instance: str, t: float) -> None:
        self.upstream.on_done(service, instance, t)
        self.changed.set()

    async def run(self) -> None:
        """Until stopped or (``until_eos``) the end of stream is recorded. An upstream service
        gone at the end of stream is waited for up to END_GRACE s."""
        last_said = time.monotonic()
        while not self.stopping.is_set():
            left = None if self.eos is None else self.upstream.wait_for_gone("recorder", self.eos, time.monotonic())
            if self.eos is not None and self.upstream.complete:
                await self.refill.finish()
                eos, self.eos = self.eos, None
                if self.until_eos:
                    while not self.sink.finalise(self.stopping.is_set()) and self.sink.disk.paused:
                        await self.sink.retry_while_paused(self.stopping)
                    if not self.sink.disk.gave_up:
                        self.report_done(eos)
                    return
                if not self.sink.flush():
                    self.eos = eos  # reported done once it is on disk (paused), or never (gave up)
                    continue
                self.report_done(eos)
                self.upstream.done.clear()
                log.info("recorder: end of stream at t=%g s recorded; recording on", eos)
            self.changed.clear()
            if self.sink.disk.paused:
                await self.sink.retry_while_paused(self.stopping)
                continue
            try:
                await asyncio.wait_for(self.changed.wait(), min(left or WAIT_LOG_INTERVAL, WAIT_LOG_INTERVAL))
            except TimeoutError:
                if self.eos is not None and time.monotonic() - last_said >= WAIT_LOG_INTERVAL:
                    owing = ", ".join([f"{s}/{i}" for s, i in self.upstream.owing()] + self.upstream.gone())
                    log.info("recorder: end of stream seen; waiting for done from %s", owing)
                    last_said = time.monotonic()
