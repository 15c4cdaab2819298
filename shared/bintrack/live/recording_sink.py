"""What the recorder writes into its files, under its disk-full policy
(:mod:`bintrack.live.disk_full`): each admitted message (a new file at a clock tick once a
split is due), the track sets fetched after a loss, what a restarted recorder keeps of its
predecessor's file, the progress each tick written owes, and the finalising."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from bintrack.bus_payloads import TrackSet
from bintrack.live.disk_full import DiskFull
from bintrack.live.record_filter import RESULTS, Admitted, RecordFilter
from bintrack.live.recording_files import RecordingFiles

log = logging.getLogger("bintrack")


class RecordingSink:
    """Writes what ``record_filter`` admitted into the files (once :meth:`open`), each write run
    by ``disk``; ``report(key, reason)`` counts a message that cannot be recorded,
    ``progress(t)`` reports a clock tick written, ``new_part(part)`` saves the checkpoint."""

    def __init__(self, record_filter: RecordFilter, disk: DiskFull, report: Callable[[str, str], None],
                 progress: Callable[[float], None], new_part: Callable[[int], None]):
        self.filter = record_filter
        self.disk = disk
        self.report = report
        self.progress = progress
        self.new_part = new_part
        self.files: RecordingFiles | None = None
        self.last_tracks = float("-inf")  # event time of the newest track set recorded
        self.last_tick: float | None = None  # the newest clock tick recorded (its progress is owed while paused)

    @property
    def closed(self) -> bool:
        """Whether no file is open: none yet, or finalised."""
        return self.files is None or self.files.closed

    def open(self, files: RecordingFiles, resume: bool) -> bool:
        """Start writing ``files`` (raises OSError); a restarted recorder (``resume``) keeps what
        its predecessor recorded (what it recorded after its last flush is lost). Whether it did
        (then the track sets after ``last_tracks`` are to be fetched)."""
        self.files = files
        aside = files.open(resume=resume)  # keep what the previous instance recorded
        self.new_part(files.part)
        if aside is None:
            return False
        kept, last_t, self.last_tracks = files.copy_from(aside, self._copied)
        self.filter.last_t = max(self.filter.last_t, last_t)
        aside.unlink()
        log.info("recorder: restarted; kept the %d messages recorded before (up to t=%g s)", kept, self.filter.last_t)
        self.filter.restarted()
        return True

    def _copied(self, record) -> None:
        if record.kind in RESULTS:
            self.filter.kept(record.key, record.payload, record.t, record.kind)

    def write(self, admitted: Admitted, key: str, payload: bytes) -> bool:
        """Write ``admitted`` (``payload`` on ``key``); whether it is in the file."""
        kind, t = admitted.parsed.kind, admitted.t
        if kind == "clock" and not self.disk.paused:  # a new file starts with a clock tick
            # a split that fails ends the recording even under pause: the old file is half finalised
            if not self.disk.attempt(self.files.writer, lambda: self._split(t), stopping=True) or self.files.closed:
                return False
        self.filter.check_gap(kind, t, self.files.path)
        try:
            self.files.writer.write(key, t, payload, time.time_ns())
        except ValueError as exc:
            self.report(key, f"unrecordable: {exc}")
            return False
        self.filter.recorded(admitted, key, payload)
        if kind == "tracks":
            self.last_tracks = max(self.last_tracks, t)
        return True

    def _split(self, t: float) -> None:
        if self.files.split_before(t):
            self.new_part(self.files.part)

    def ticked(self, tick: Admitted) -> None:
        """The clock tick ``tick`` was written: flush when due and report progress, unless paused
        (replay then holds event time)."""
        self.last_tick = tick.message.t
        if not self.disk.paused and self.disk.attempt(self.files.writer, lambda: self.files.tick(tick.t)):
            self.progress(self.last_tick)

    def record_fetched(self, key: str, tracks: TrackSet, payload: bytes, n: int) -> bool:
        """Write the ``n``-th fetched copy of a track set if the file holds fewer; whether it did."""
        if self.files.closed or self.filter.tracks.held(key, tracks.t, payload) >= n:
            return False
        self.filter.kept(key, payload, tracks.t, "tracks")
        self.files.writer.write(key, tracks.t, payload, time.time_ns())
        self.last_tracks = max(self.last_tracks, tracks.t)
        return True

    def flush(self) -> bool:
        """Put what is written on disk; whether it went."""
        return self.disk.attempt(self.files.writer, self.files.writer.flush)

    async def retry_while_paused(self, stopping: asyncio.Event) -> None:
        """While paused (--on-disk-full pause): write what is held until it goes; then the
        progress owed."""
        await self.disk.retry_while_paused(self.files.writer, stopping, self._progress_owed)

    def _progress_owed(self) -> None:
        if self.last_tick is not None:
            self.progress(self.last_tick)

    def finalise(self, stopping: bool) -> bool:
        """Finalise the file (once ``stopping``, whatever the disk allows); whether it is done."""
        if self.closed:
            return True
        return self.disk.attempt(self.files.writer, self.files.finalise, stopping=stopping)
