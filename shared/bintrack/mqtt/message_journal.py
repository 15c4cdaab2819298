"""The bridge's journal: every MQTT message it took since its last checkpoint, written before
the broker is acknowledged (paho acknowledges a QoS 1 message once the handler returns), so
that a bridge killed between two checkpoints loses none it acknowledged."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import time

import msgpack


class MessageJournal:
    """Append-only file of (seq, topic, payload, retained, received µs) records."""

    def __init__(self, path: str | Path, interval: float = 1.0):
        self.path, self.interval, self.saved_at = Path(path), interval, time.monotonic()
        self._file = open(self.path, "ab", buffering=0)

    def checkpoint(self, save: Callable[[], None]) -> None:
        """Every ``interval`` s of wall clock: ``save()`` a checkpoint, then empty the journal."""
        if time.monotonic() - self.saved_at >= self.interval:
            save()
            self.restart()
            self.saved_at = time.monotonic()

    def append(self, seq: int, topic: str, payload: bytes, retained: bool, received_us: int) -> None:
        self._file.write(msgpack.packb((seq, topic, payload, retained, received_us), use_bin_type=True))

    def restart(self) -> None:
        """Empty it (everything in it is in a checkpoint now)."""
        self._file.close()
        self._file = open(self.path, "wb", buffering=0)

    def close(self) -> None:
        self._file.close()


def read_journal(path: str | Path) -> list[tuple[int, str, bytes, bool, int]]:
    """The records of a journal, in order; a record cut short by a kill ends it."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return []
    unpacker = msgpack.Unpacker(raw=False)
    unpacker.feed(data)
    records = []
    try:
        for record in unpacker:
            records.append(tuple(record))
    except (ValueError, msgpack.UnpackException):
        pass
    return records


def take_journal(path: str | Path, after_seq: int, take: Callable[..., None]) -> int:
    """Hand each record of the journal at ``path`` numbered after ``after_seq`` (what a
    checkpoint already holds) to ``take(seq, topic, payload, retained, received_us)``; how many."""
    records = [r for r in read_journal(path) if r[0] > after_seq]
    for record in records:
        take(*record)
    return len(records)
