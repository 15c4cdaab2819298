"""Recordings of a bintrack network: MCAP files of (key, event time, msgpack payload) records.

Why MCAP: it is the recording convention of pub/sub systems (ROS 2, Foxglove): one channel
per topic (here: per key expression), a schema per message type (here the pydantic JSON
Schema of the message, ``encoding="jsonschema"``, payloads ``message_encoding="msgpack"``),
and an index, so a recording is read in log-time order or by topic without a full scan, with
the ``mcap`` CLI among others. Foxglove lists its channels but does not decode msgpack:
``bintrack export RECORDING --foxglove OUT.mcap`` writes a JSON copy it reads. The writer is chunked: a recording that was
never finalised (a crash) still holds a readable prefix, all of it except the chunk that was
being filled (at most ``CHUNK_SIZE`` bytes of messages).

Layout of a bintrack recording:

* metadata ``bintrack.recording``: ``{"format": "bintrack.recording/1", "net": <net>}``;
* attachment ``bintrack.deployment`` (``application/json``): the deployment, as
  ``deployment.json`` text (DESIGN §6);
* one message per received sample: channel topic = its key, ``log_time`` = its event time
  ``t`` in ns (``t_last`` for a ``LineObjectEstimate``), ``publish_time`` = wall-clock time of
  receipt in ns, ``data`` = the payload bytes as they were on the bus.

Nothing here talks to Zenoh: the recorder service feeds :class:`RecordingWriter`; replay and
``bintrack export`` read with :func:`open_recording`.
"""

from __future__ import annotations

import io
import json
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import msgpack
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Metadata
from mcap.records import Message as McapMessage
from mcap.writer import IndexType, Writer

from bintrack import __version__
from bintrack.formats import FormatError, deployment_text, open_input, parse_deployment
from bintrack.keys import Keys, parse_key
from bintrack.live.spooled_file import SpooledFile
from bintrack.bus_payloads import (
    Clock, EndOfStream, LineObjectEstimate, LocalEstimate, PositionReports, RawSample, SensorState, TrackSet,
    Transition, TruthSample, VelocityEstimate,
)
from bintrack.deployment_model import Deployment
from bintrack.message_base import Message
from bintrack.message_codec import MessageError, decode
from bintrack.live.recording_check import MCAP_MAGIC, Damage, checked_scan, count_mismatch, skipped_by_statistics

RECORDING_FORMAT = "bintrack.recording/1"
RECORDING_METADATA = "bintrack.recording"
DEPLOYMENT_ATTACHMENT = "bintrack.deployment"
MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
CHUNK_SIZE = 64 * 1024

# The message type of each key kind (keys.parse_key); ``alive`` keys carry no message.
KIND_TYPES: dict[str, type[Message]] = {
    "raw": RawSample,
    "transition": Transition,
    "state": SensorState,
    "estimate": LocalEstimate,
    "fusion_reports": PositionReports,
    "tracks": TrackSet,
    "laser_objects": LineObjectEstimate,
    "motion_velocity": VelocityEstimate,
    "truth": TruthSample,
    "deployment": Deployment,
    "clock": Clock,
    "eos": EndOfStream,
    "progress": Clock,
    "done": EndOfStream,
    "region_reports": PositionReports,
    "region_tracks": TrackSet,
    "region_progress": Clock,
}

# Key kinds replay never republishes from a recording (it makes its own end of stream); None
# stands for a key that is not a bintrack key at all.
CONTROL_KINDS = frozenset({"eos", "progress", "done", "alive", "region_progress", None})

_MAX_LOG_TIME = 2**64 - 1
_TIME_FIELDS = ("t", "t_first", "t_last")


def message_type(key: str) -> type[Message]:
    """The message type carried on concrete bintrack key ``key``; ValueError if there is none."""
    kind = parse_key(key).kind
    if kind not in KIND_TYPES:
        raise ValueError(f"key {key!r} carries no message")
    return KIND_TYPES[kind]


def event_time(message: Message) -> float | None:
    """Event time of ``message`` in s: its ``t``, or ``t_last`` for a line object; None if it has none."""
    if isinstance(message, LineObjectEstimate):
        return message.t_last
    return getattr(message, "t", None)


def log_time_ns(t: float) -> int:
    """Event time ``t`` (s) as an MCAP log time (ns); ValueError if it does not fit (t < 0)."""
    ns = round(t * 1e9) if math.isfinite(t) else -1
    if not 0 <= ns <= _MAX_LOG_TIME:
        raise ValueError(f"event time {t!r} s cannot be an MCAP log time (needs 0 <= t < 1.8e10 s)")
    return ns


def shift_payload(payload: bytes, dt: float) -> bytes:
    """``payload`` (a msgpack map) with ``dt`` seconds added to its event times (t, t_first,
    t_last); the bytes unchanged when ``dt`` is 0 or the payload has no such field."""
    if dt == 0:
        return payload
    try:
        obj = msgpack.unpackb(payload, raw=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ValueError(f"cannot shift the times of a payload that is not msgpack: {exc}") from None
    if not isinstance(obj, dict):
        return payload
    changed = False
    for name in _TIME_FIELDS:
        value = obj.get(name)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            obj[name] = value + dt
            changed = True
    return msgpack.packb(obj, use_bin_type=True) if changed else payload


# --------------------------------------------------------------------------- writing


class RecordingWriter:
    """Writes a recording (chunked MCAP) to ``path``: the deployment first, then records.

    ``write`` takes payloads already validated by the caller. ``flush`` pushes finished chunks
    to the operating system; ``close`` finalises the file (summary, index, footer) and is
    idempotent. Raises OSError if ``path`` cannot be created. The file is written through a
    :class:`~bintrack.live.spooled_file.SpooledFile` (with a ``reserve`` of disk space beside
    it, bytes; None for the default): a ``flush`` or ``close`` that fails on a full or failing
    disk raises OSError and may be tried again, or the file ended with :meth:`abandon`.
    """

    def __init__(self, path: Path | str, deployment: Deployment, net: str, chunk_size: int = CHUNK_SIZE,
                 reserve: int | None = 0):
        self.path = Path(path)
        Keys(net)  # a valid network name
        self._handle = SpooledFile(self.path, reserve)
        # No per-channel message indexes: the writer keeps each chunk's index in memory until the
        # file is finalised, ~19 kB per chunk with them (a recorder flushing every 5 s grew without
        # bound), 0.4 kB without. Readers seek by chunk index and read the chunk, as they may.
        # The data section's CRC as well as each chunk's: a zeroed range that also zeroes a
        # chunk's CRC (0 means "none") would otherwise drop the chunk unseen.
        self._writer = Writer(self._handle, chunk_size=chunk_size, enable_data_crcs=True,
                              index_types=IndexType.CHUNK | IndexType.ATTACHMENT | IndexType.METADATA)
        self._writer.start(profile="", library=f"bintrack {__version__}")
        self._writer.add_metadata(RECORDING_METADATA, {"format": RECORDING_FORMAT, "net": net})
        now = time.time_ns()
        self._writer.add_attachment(create_time=now, log_time=0, name=DEPLOYMENT_ATTACHMENT,
                                    media_type="application/json", data=deployment_text(deployment).encode())
        self._schemas: dict[type[Message], int] = {}
        self._channels: dict[str, int] = {}
        self.count = 0
        self.last_t = -math.inf  # event time of the newest message written, s
        self.durable = (0, -math.inf)  # (messages, newest event time) the last successful flush put on disk
        self.closed = False
        self._finished = False

    def write(self, key: str, t: float, payload: bytes, received_ns: int | None = None) -> None:
        """Record ``payload`` received on ``key`` with event time ``t`` (s) at wall-clock
        ``received_ns`` (ns since the epoch; default now). ValueError for a key that carries no
        message or a time that cannot be a log time."""
        if self.closed:
            raise ValueError(f"recording {self.path} is already finalised")
        log_time = log_time_ns(t)
        channel = self._channels.get(key)
        if channel is None:
            channel = self._channel(key)
        self._writer.add_message(channel_id=channel, log_time=log_time, data=bytes(payload),
                                 publish_time=time.time_ns() if received_ns is None else received_ns,
                                 sequence=self.count % 2**32)
        self.count += 1
        self.last_t = max(self.last_t, t)

    def _channel(self, key: str) -> int:
        cls = message_type(key)
        schema = self._schemas.get(cls)
        if schema is None:
            text = json.dumps(cls.model_json_schema(by_alias=True), sort_keys=True)
            schema = self._writer.register_schema(name=f"bintrack.{cls.__name__}", encoding=SCHEMA_ENCODING,
                                                  data=text.encode())
            self._schemas[cls] = schema
        channel = self._writer.register_channel(topic=key, message_encoding=MESSAGE_ENCODING, schema_id=schema)
        self._channels[key] = channel
        return channel

    def flush(self) -> None:
        """Finish the open chunk and hand everything to the operating system: what was written
        so far survives the writer's process being killed."""
        if not self.closed:
            self._writer.flush()
            self.durable = (self.count, self.last_t)

    def close(self) -> None:
        """Finalise the file: the open chunk, the summary and the footer. On OSError (a full
        disk) it stays open, and may be tried again or :meth:`abandon`-ed."""
        if self.closed:
            return
        if not self._finished:
            self.flush()  # the messages first: if only they fit, abandon() keeps them
            self._finished = True
            self._writer.finish()
        self._handle.flush()
        self.durable = (self.count, self.last_t)
        self.closed = True
        self._handle.close()

    def free_reserve(self) -> bool:
        """Give back the disk space reserved for finalising; whether there was any."""
        return self._handle.free_reserve()

    def abandon(self) -> None:
        """End the file after what was flushed whole (:attr:`durable`), with no summary (a
        finalised file that readers read from the start), dropping the rest; OSError if even
        that cannot be written (the file then holds a readable prefix)."""
        if self.closed:
            return
        self.closed = True
        try:
            if self._handle.end_without_summary(keep_spool=not self._finished):
                self.durable = (self.count, self.last_t)
        finally:
            self._handle.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class Record:
    """One recorded sample: its ``key``, event time ``t`` (s, the log time), the payload bytes
    as they were on the bus and the wall-clock time of receipt ``received_ns`` (ns)."""

    key: str
    t: float
    payload: bytes
    received_ns: int

    @property
    def kind(self) -> str:
        """The key's kind (keys.parse_key), e.g. ``raw``, ``clock``, ``tracks``."""
        return parse_key(self.key).kind


@dataclass(frozen=True)
class Recording:
    """An opened recording: its deployment, network name, and records in log-time order.

    ``complete`` is False for a file that was never finalised: then only its readable prefix
    is played (and it is read into memory to sort it).
    """

    path: Path
    deployment: Deployment
    net: str
    complete: bool
    message_count: int | None
    damage: Damage | None = None

    def records(self, keep: Callable[[str], bool] | None = None) -> Iterator[Record]:
        """Every record whose key passes ``keep`` (default: all), in log-time order, ties in
        the order they were recorded: one checked pass over the data section
        (:mod:`.recording_check`), so the summary, which no checksum covers, is never
        trusted. Only the sound chunks are read (the file was opened knowing their damage)."""
        with open_input(self.path, "an .mcap recording", binary=True) as handle:
            scan = checked_scan(handle, keep_messages=True)
        pairs = [(c, m) for c, m in scan.messages if keep is None or keep(c.topic)]
        pairs.sort(key=lambda pair: pair[1].log_time)  # stable: ties stay in file order
        for channel, message in pairs:
            yield _record(channel, message)

    def note(self) -> str | None:
        """One line on what of the file could not be read (a damaged or torn file), else None."""
        if self.damage is None:
            return None
        return f"{self.path}: {self.damage.describe(self.message_count or 0)}"

    def messages(self, kinds: set[str] | frozenset[str]) -> Iterator[tuple[Record, Message]]:
        """Decoded messages of the given key kinds, in log-time order; FormatError for a payload
        that does not decode as its key's type."""
        for record in self.records(lambda key: _kind_or_none(key) in kinds):
            try:
                yield record, decode(KIND_TYPES[record.kind], record.payload)
            except MessageError as exc:
                raise FormatError(self.path, None, record.key, f"bad payload at t={record.t:.9g}: {exc.reason}") from None


def replay_items(recording: Recording, keep: Callable[[str], bool] | None = None) -> Iterator[tuple[float, Record | None]]:
    """One pass of a recording as replay plays it: (event time s, record) in log-time order
    for every record whose key passes ``keep``, and (t, None) for each recorded clock tick
    (always, whatever ``keep`` says: the ticks carry flow control). Control keys (``eos``,
    ``progress``, ``done``, ``alive``) are left out. FormatError for a tick that does not decode."""
    for record in recording.records(lambda key: _kind_or_none(key) not in CONTROL_KINDS):
        if record.kind == "clock":
            try:
                yield decode(Clock, record.payload).t, None
            except MessageError as exc:
                raise FormatError(recording.path, None, record.key, f"bad clock tick: {exc.reason}") from None
        elif keep is None or keep(record.key):
            yield record.t, record


def _kind_or_none(key: str) -> str | None:
    try:
        return parse_key(key).kind
    except ValueError:
        return None


def _record(channel: Channel, message: McapMessage) -> Record:
    return Record(channel.topic, message.log_time / 1e9, bytes(message.data), message.publish_time)


def open_recording(path: Path | str, salvage: bool = False) -> Recording:
    """Open a bintrack recording and read its deployment and network name, checking every
    chunk (:func:`~bintrack.live.recording_check.checked_scan`).

    Raises FormatError (one line naming the file) for a missing, non-MCAP or corrupt file, or
    an MCAP file that is not a bintrack recording. A file with a bad chunk or a broken record
    is corrupt unless ``salvage``: then its sound chunks are read, and :meth:`Recording.note`
    says what was lost; so it does for a file that merely stops (never finalised, or cut short).
    """
    path = Path(path)
    with open_input(path, "an .mcap recording", binary=True) as handle:
        magic = handle.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            raise FormatError(path, None, "file", "empty file, expected an MCAP recording" if not magic
                              else "not an MCAP recording (bad magic bytes)")
        scan = checked_scan(handle, keep_messages=False)
        summary = _summary(handle)
        damage = scan.damage
        total = summary.statistics.message_count if summary is not None and summary.statistics is not None else None
        if damage is not None:
            damage = skipped_by_statistics(damage, scan.count, total)
        else:
            damage = count_mismatch(scan.count, total)
        if damage is not None and not damage.torn and (not salvage or not scan.attachments):
            hint = "; --salvage reads the sound chunks" if scan.attachments else ""
            raise FormatError(path, None, "mcap", f"corrupt recording: {damage.describe(scan.count)}{hint}")
        if damage is not None and damage.torn and not scan.attachments:
            raise FormatError(path, None, "mcap", f"corrupt or truncated recording: {damage.describe(scan.count)}")
        complete = scan.finalised and summary is not None  # with the index a seek needs (the map's slider)
    return Recording(path, _deployment(path, scan.attachments), _net(path, scan.metadata), complete, scan.count, damage)


def _summary(handle: IO[bytes]):
    """The file's summary (mcap ``Summary``), None if it has none or it does not read."""
    try:
        handle.seek(0, io.SEEK_SET)
        return SeekingReader(handle).get_summary()
    except Exception:  # assorted types from a damaged or missing summary
        return None


def _deployment(path: Path, attachments: list[Attachment]) -> Deployment:
    for attachment in attachments:
        if attachment.name == DEPLOYMENT_ATTACHMENT:
            try:
                text = bytes(attachment.data).decode("utf-8")
            except UnicodeDecodeError as exc:
                raise FormatError(path, None, DEPLOYMENT_ATTACHMENT, f"not UTF-8 text: {exc}") from None
            return parse_deployment(text, f"{path}:{DEPLOYMENT_ATTACHMENT}")
    raise FormatError(path, None, DEPLOYMENT_ATTACHMENT, "missing attachment: not a bintrack recording")


def _net(path: Path, metadata: list[Metadata]) -> str:
    for record in metadata:
        if record.name == RECORDING_METADATA:
            fmt_tag = record.metadata.get("format")
            if fmt_tag != RECORDING_FORMAT:
                raise FormatError(path, None, RECORDING_METADATA,
                                  f"unsupported format {fmt_tag!r} (expected {RECORDING_FORMAT!r})")
            net = record.metadata.get("net", "")
            try:
                Keys(net)
            except ValueError as exc:
                raise FormatError(path, None, f"{RECORDING_METADATA}.net", str(exc)) from None
            return net
    raise FormatError(path, None, RECORDING_METADATA, "missing metadata: not a bintrack recording")
