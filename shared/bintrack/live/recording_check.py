"""Reading a recording with every check MCAP offers: one linear pass over the data section that
verifies each chunk's CRC (and the data section's, at its end) and goes on past a bad chunk,
counting what it held, so that damage is reported, never silently exported.

A chunk that fails its CRC, does not decompress or does not parse is skipped whole; the
message indexes that follow it in the file say how many messages it held. Damage to the
records between chunks (a broken length) ends the pass there. A file that simply stops (no
footer, cut inside a record) is *torn*: a recorder that never finalised it, or a copy cut short.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field, replace
from typing import IO

from mcap.exceptions import EndOfFile
from mcap.records import Attachment, Channel, Chunk, DataEnd, Message, MessageIndex, Metadata
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK = 256 * 2**20  # bytes: a chunk claiming more once decompressed is damaged (ours hold 64 KiB)


@dataclass(frozen=True)
class Damage:
    """The first damage found: its byte ``offset`` (None when no one place is known), the chunk (numbered from 1 in file order,
    None outside chunks), why, how many chunks failed, how many messages were lost (None when
    the rest of the file is unreadable) and whether the file is merely torn (cut short)."""

    offset: int | None
    chunk: int | None
    reason: str
    bad_chunks: int
    skipped: int | None
    torn: bool

    def describe(self, read: int) -> str:
        """One line: where, why, and what was lost (``read``: messages read)."""
        if self.torn:
            return (f"the file ends inside a record at byte {self.offset} (never finalised, or cut short): "
                    f"{read} records read before it, whatever followed is lost")
        if self.offset is None:
            where = "the data section"
        elif self.chunk is not None:
            where = f"chunk {self.chunk} at byte {self.offset}"
        else:
            where = f"byte {self.offset}"
        if self.skipped is None:
            lost = "the rest of the file is unreadable"
        else:
            lost = f"{self.skipped} records skipped"
            if self.bad_chunks > 1:
                lost += f" in {self.bad_chunks} bad chunks"
        return f"{where} fails its check ({self.reason}); {lost}, {read} read"


@dataclass
class CheckedScan:
    """What the pass found: messages (with their channels, in file order; only when asked
    for), how many there were, attachments, metadata, whether the footer was reached, and the
    first damage (None for a sound file)."""

    messages: list[tuple[Channel, Message]] = field(default_factory=list)
    count: int = 0
    attachments: list[Attachment] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    finalised: bool = False
    damage: Damage | None = None


def _reason(exc: BaseException) -> str:
    if isinstance(exc, CRCValidationError):
        return "CRC mismatch"
    text = str(exc).splitlines()[0][:120] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _ends_with_magic(handle: IO[bytes]) -> bool:
    size = handle.seek(0, os.SEEK_END)
    if size < 2 * len(MCAP_MAGIC):
        return False
    handle.seek(size - len(MCAP_MAGIC))
    return handle.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def checked_scan(handle: IO[bytes], keep_messages: bool) -> CheckedScan:
    """One pass over the recording open in ``handle`` (see the module docstring)."""
    torn_file = not _ends_with_magic(handle)
    size = handle.seek(0, os.SEEK_END)
    handle.seek(0)
    scan = CheckedScan()
    channels: dict[int, Channel] = {}
    chunks = bad = 0
    lost = 0  # messages of bad chunks (their message indexes) and of channels they defined
    counting = False  # between a bad chunk and the next chunk: its message indexes
    first: tuple[int, int | None, str] | None = None
    start = len(MCAP_MAGIC)
    records = StreamReader(handle, validate_crcs=True, emit_chunks=True, record_size_limit=size).records
    try:
        for record in records:
            if isinstance(record, Chunk):
                chunks += 1
                counting = False
                try:
                    if record.uncompressed_size > MAX_CHUNK:
                        raise ValueError(f"claims {record.uncompressed_size} bytes")
                    inner = breakup_chunk(record, validate_crc=True)
                except Exception as exc:  # CRC, decompression, parsing: assorted types
                    bad += 1
                    counting = True
                    first = first or (start, chunks, _reason(exc))
                    inner = []
                    held = _messages_in(record)
                    lost += held
                for item in inner:
                    if isinstance(item, Channel):
                        channels[item.id] = item
                    elif isinstance(item, Message):
                        lost += _take(scan, channels, item, keep_messages)
            elif isinstance(record, MessageIndex):
                if counting:
                    lost += len(record.records)
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                lost += _take(scan, channels, record, keep_messages)
            elif isinstance(record, Attachment):
                scan.attachments.append(record)
            elif isinstance(record, Metadata):
                scan.metadata.append(record)
            elif isinstance(record, DataEnd):
                break  # the summary that follows is not needed: everything is in the data section
            start = handle.tell()
        scan.finalised = True
    except Exception as exc:  # a broken record between chunks, the data section's CRC, a torn end
        if isinstance(exc, CRCValidationError) and isinstance(exc.record, DataEnd):
            scan.finalised = True
            first = first or (None, None, "its CRC does not match: a record changed without failing a check of its own")
        else:
            torn = torn_file and isinstance(exc, (EndOfFile, struct.error)) and first is None
            first = first or (start, None, _reason(exc))
            scan.damage = Damage(first[0], first[1], first[2], bad, None, torn)
            return scan
    if first is None and lost:
        first = (0, None, "messages on channels the file never defines")
    if first is not None:
        scan.damage = Damage(first[0], first[1], first[2], bad, lost, False)
    return scan


def _messages_in(chunk: Chunk) -> int:
    """How many messages a bad chunk seems to hold, read without its CRC (0 if it does not
    read; the file's statistics, when they read, correct the count: :func:`skipped_by_statistics`)."""
    try:
        return sum(isinstance(r, Message) for r in breakup_chunk(chunk, validate_crc=False))
    except Exception:  # assorted types
        return 0


def skipped_by_statistics(damage: Damage, read: int, total: int | None) -> Damage:
    """``damage`` with the messages lost counted from the file's statistics (``total``, None
    when the summary does not read), when they are plausible (at least ``read``)."""
    if total is None or total < read or damage.torn:
        return damage
    return replace(damage, skipped=total - read)


def count_mismatch(read: int, total: int | None) -> Damage | None:
    """Damage when the file's statistics (``total`` messages, None when the summary does not
    read) disagree with the ``read`` messages that every check passed: a chunk lost without a
    failing check, as when a zeroed range also zeroes its CRC (0 means none). None if they agree."""
    if total is None or total == read:
        return None
    reason = f"its statistics count {total} messages, its chunks hold {read}"
    return Damage(None, None, reason, 0, max(total - read, 0), False)


def _take(scan: CheckedScan, channels: dict[int, Channel], message: Message, keep: bool) -> int:
    """Count (and keep) ``message``; 1 if it is lost (its channel was defined in a bad chunk)."""
    channel = channels.get(message.channel_id)
    if channel is None:
        return 1
    scan.count += 1
    if keep:
        scan.messages.append((channel, message))
    return 0
