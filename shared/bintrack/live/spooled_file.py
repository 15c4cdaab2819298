"""The file a recording is written to: what the MCAP writer hands it is kept in memory until
:meth:`SpooledFile.flush` writes it, whole or not at all.

A flush that fails (a full or failing disk) truncates the file back to the end of the last
flush that succeeded and keeps the spool: the file on disk is always a whole prefix of what
was flushed, and nothing handed over is lost while the process lives, so a later flush (once
space is back) or a finalisation can still write it. A reserve file beside it holds a little
space that :meth:`free_reserve` gives back for the finalisation.
"""

from __future__ import annotations

import os
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer

RESERVE_MAX = 1024 * 1024  # bytes held for finalising: the summary of a long recording and a chunk …
RESERVE_SHARE = 8  # … but at most this fraction of the space free when the file is opened
MCAP_MAGIC = b"\x89MCAP0\r\n"


def free_bytes(folder: Path) -> int:
    """The bytes an unprivileged writer may still write on ``folder``'s file system (OSError if
    it cannot be asked)."""
    stat = os.statvfs(folder)
    return stat.f_bavail * stat.f_frsize


class SpooledFile:
    """A file at ``path`` (created, truncated) written through a memory spool, with a reserve
    of ``reserve`` bytes (0: none; None: :data:`RESERVE_MAX`, at most 1/RESERVE_SHARE of the
    free space) in a hidden file beside it. Raises OSError if either cannot be made."""

    def __init__(self, path: Path | str, reserve: int | None = 0):
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        self._pending = bytearray()
        self.good = 0  # bytes at the start of the file that flushes wrote whole
        self.reserve_path: Path | None = None
        if reserve != 0:
            if reserve is None:
                reserve = max(4096, min(RESERVE_MAX, free_bytes(self.path.parent) // RESERVE_SHARE))
            self.reserve_path = self.path.with_name(f".{self.path.name}.reserve")
            fd = os.open(self.reserve_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.posix_fallocate(fd, 0, reserve)
            except OSError:
                os.close(fd)
                self.free_reserve()
                os.close(self._fd)
                raise
            os.close(fd)

    # the stream the MCAP writer needs
    def write(self, data: bytes) -> int:
        self._pending += data
        return len(data)

    def tell(self) -> int:
        return self.good + len(self._pending)

    def flush(self) -> None:
        """Write the spool at the end of the file; on OSError the file is cut back to
        :attr:`good` and the spool kept (the error is raised)."""
        done = 0
        with memoryview(self._pending) as view:
            try:
                while done < len(view):
                    done += os.pwrite(self._fd, view[done:], self.good + done)
            except OSError:
                os.ftruncate(self._fd, self.good)
                raise
        self.good += done
        self._pending.clear()

    @property
    def pending(self) -> int:
        """Bytes handed over but not on disk yet."""
        return len(self._pending)

    def free_reserve(self) -> bool:
        """Remove the reserve file, giving its space back; whether there was one."""
        if self.reserve_path is None:
            return False
        self.reserve_path.unlink(missing_ok=True)
        self.reserve_path = None
        return True

    def end_without_summary(self, keep_spool: bool) -> bool:
        """End the file with a data end and a footer with no summary, a finalised MCAP file
        that readers read from the start: after the spool if ``keep_spool`` (it holds whole
        records) and the disk takes it, else after what flushes wrote whole. Whether the spool
        was kept; raises OSError if even the ending cannot be written."""
        builder = RecordBuilder()
        DataEnd(data_section_crc=0).write(builder)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
        ending = builder.end() + MCAP_MAGIC
        if keep_spool:
            self._pending += ending
            try:
                self.flush()
                return True
            except OSError:
                pass
        self._pending[:] = ending
        self.flush()
        return False

    def close(self) -> None:
        """Close the file (what was not flushed is dropped) and remove the reserve."""
        self.free_reserve()
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
