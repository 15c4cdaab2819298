"""The recorder's files: one MCAP file, or a series split by size or event-time span, each
flushed now and then so that a kill loses little, and finalised at the end."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from bintrack.formats import FormatError
from bintrack.live.recording import RecordingWriter, open_recording
from bintrack.deployment_model import Deployment

FLUSH_INTERVAL, FLUSH_SPAN = 5.0, 32.0  # s of wall clock or of event time between two flushes of the file
CHUNK_SIZE = 1024 * 1024  # bytes: few chunks, so that the chunk index kept in memory stays small

log = logging.getLogger("bintrack")


def part_path(out: str, part: int) -> str:
    """The file of split ``part``: ``out`` itself for part 0, else ``<stem>_<part>.mcap``."""
    return out if part == 0 else str(Path(out).with_name(f"{Path(out).stem}_{part}.mcap"))


class RecordingFiles:
    """The files of recording ``out`` of ``deployment`` on network ``net``, from split ``part``
    on; a new file once one holds ``split_size`` bytes or spans ``split_duration`` s."""

    def __init__(self, out: str, deployment: Deployment, net: str, part: int = 0,
                 split_size: int | None = None, split_duration: float | None = None,
                 on_finalised: Callable[[str], None] | None = None):
        self.out = out
        self.deployment = deployment
        self.net = net
        self.part = part
        self.path = part_path(out, part)
        self.split_size = split_size
        self.split_duration = split_duration
        self.writer: RecordingWriter | None = None
        self.part_start: float | None = None  # event time of the first tick of the current file
        self.flushed_at, self.flushed_t = time.monotonic(), None
        self.on_finalised = on_finalised  # called with each file's path once it is finalised

    def open(self, resume: bool = False) -> Path | None:
        """Start the current part's file (raises OSError); the header and the deployment are on
        disk whatever happens next. With ``resume`` (a restarted recorder), a file already there
        is first set aside: its path is returned, for :meth:`copy_from` and then removal."""
        aside = None
        if resume and os.path.exists(self.path):
            aside = Path(self.path + ".interrupted")
            os.replace(self.path, aside)
        self.writer = RecordingWriter(self.path, self.deployment, self.net, chunk_size=CHUNK_SIZE, reserve=None)
        self.writer.flush()
        return aside

    def copy_from(self, path: Path, copied: Callable | None = None) -> tuple[int, float, float]:
        """Copy the readable records of an interrupted recording into the current file (telling
        ``copied`` of each): (how many, the event time of the newest, that of the newest track
        set; s)."""
        count, last_t, last_tracks = 0, 0.0, float("-inf")
        try:
            recording = open_recording(path, salvage=True)
            if recording.note() is not None:
                log.warning("recorder: %s", recording.note())
            for record in recording.records():
                self.writer.write(record.key, record.t, record.payload, record.received_ns)
                if copied is not None:
                    copied(record)
                if record.kind == "tracks":
                    last_tracks = max(last_tracks, record.t)
                last_t = max(last_t, record.t)
                count += 1
        except FormatError as exc:
            log.warning("recorder: %s; kept %d messages of it", exc, count)
        return count, last_t, last_tracks

    @property
    def closed(self) -> bool:
        return self.writer is None or self.writer.closed

    def split_before(self, t: float) -> bool:
        """Before the clock tick at ``t`` (s), so that each file starts with one: finalise the file
        and go on in the next once it is full; whether it did."""
        if self.part_start is None:
            self.part_start = t
        size, span = self.split_size, self.split_duration
        if not ((size and Path(self.path).stat().st_size >= size) or (span and t - self.part_start >= span)):
            return False
        self.finalise()
        self.part += 1
        self.path = part_path(self.out, self.part)
        self.open()
        self.part_start = t
        log.info("recorder: recording on into %s", self.path)
        return True

    def tick(self, t: float) -> None:
        """After the clock tick at ``t`` (s): flush every FLUSH_INTERVAL s of wall clock or
        FLUSH_SPAN s of event time. Each flush closes an MCAP chunk (its index, an entry per
        channel, stays in memory until the file is finalised), so not at every tick. What a kill
        loses since is fetched back for the track sets (tracks?after=T); the other messages of
        that span are missing."""
        now = time.monotonic()
        if self.flushed_t is None:
            self.flushed_t = t
        if now - self.flushed_at >= FLUSH_INTERVAL or t - self.flushed_t >= FLUSH_SPAN:
            self.writer.flush()
            self.flushed_at, self.flushed_t = now, t

    def finalise(self) -> None:
        if self.writer is not None and not self.writer.closed:
            self.writer.close()
            log.info("recorder: %d messages recorded in %s", self.writer.count, self.writer.path)
            if self.on_finalised is not None:
                self.on_finalised(str(self.writer.path))
