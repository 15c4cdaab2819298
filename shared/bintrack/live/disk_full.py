"""What the recorder does when its file cannot be written (a full or failing disk): a fault
like any other, said once in one line.

``--on-disk-full stop`` (the default): the file is finalised with everything written before
(with the space of its reserve; failing that, ended after the last flush that reached the
disk, without its index, naming how many messages were lost) and the recorder exits with
:data:`EXIT_WRITE_FAILED`, which ``up`` takes to end the stack. ``--on-disk-full pause``: the
recorder holds what it is handed in memory and stops reporting progress, so replay holds event
time, and tries again every :data:`RETRY` s until space is back; stopped meanwhile, it ends the
file as ``stop`` does.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from bintrack.live.recording import RecordingWriter
from bintrack.live.spooled_file import free_bytes

EXIT_WRITE_FAILED = 3  # the recorder's exit status when it could not write its file
RETRY = 1.0  # s between two tries while paused
MODES = ("stop", "pause")

log = logging.getLogger("bintrack")


def _reason(exc: OSError) -> str:
    return f"{exc.strerror} (errno {exc.errno})" if exc.strerror else str(exc) or type(exc).__name__


class DiskFull:
    """Runs the recorder's writes (:meth:`attempt`) and answers a failure as ``mode`` says;
    ``give_up(status)`` stops the recorder with that exit status."""

    def __init__(self, mode: str, give_up: Callable[[int], None]):
        self.mode = mode
        self._give_up = give_up
        self.paused_since: float | None = None  # monotonic time the writes failed, while paused
        self.gave_up = False

    @property
    def paused(self) -> bool:
        return self.paused_since is not None

    def attempt(self, writer: RecordingWriter, action: Callable[[], None], stopping: bool = False) -> bool:
        """Run ``action`` (a write to ``writer``'s file); whether it succeeded."""
        if self.gave_up:
            return False
        try:
            action()
        except OSError as exc:
            if self.mode == "pause" and not stopping:
                if not self.paused:
                    self.paused_since = time.monotonic()
                    log.warning("recorder: cannot write %s: %s; holding event time until it can be written again "
                                "(--on-disk-full pause; tried every %g s)", writer.path, _reason(exc), RETRY)
            else:
                self.end(writer, exc)
            return False
        if self.paused:
            log.info("recorder: %s written again after %.1f s; recording on", writer.path,
                     time.monotonic() - self.paused_since)
            self.paused_since = None
        return True

    async def retry_while_paused(self, writer: RecordingWriter, stopping: asyncio.Event,
                                 written: Callable[[], None]) -> None:
        """While paused: flush ``writer`` every RETRY s (calling ``written()`` once it went)
        until it goes or ``stopping`` is set."""
        while self.paused and not stopping.is_set():
            try:
                await asyncio.wait_for(stopping.wait(), RETRY)
            except TimeoutError:
                if self.attempt(writer, writer.flush):
                    written()

    def end(self, writer: RecordingWriter, exc: OSError) -> None:
        """Finalise ``writer``'s file as well as the disk allows, say so in one line, give up."""
        self.gave_up = True
        writer.free_reserve()
        try:
            writer.close()
            kept = f"finalised with all {writer.count} messages recorded"
        except OSError:
            count, t = writer.durable
            held = f"the {count} messages written up to t={t:g} s" if count else "no message"
            lost = f"the {writer.count - count} recorded after are lost" if writer.count > count else "none lost"
            try:
                writer.abandon()
                kept = f"finalised without its index, with {held}; {lost}"
            except OSError as ending:
                try:
                    free = free_bytes(writer.path.parent)
                except OSError:
                    free = "?"
                kept = (f"not finalised (its ending could not be written either: {_reason(ending)}, "
                        f"{free} bytes free): it holds a readable prefix, {held}; {lost}")
        log.error("recorder: cannot write %s: %s; stopped: the file is %s", writer.path, _reason(exc), kept)
        self._give_up(EXIT_WRITE_FAILED)
