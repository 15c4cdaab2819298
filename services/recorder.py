"""Recorder: records everything of one network into an MCAP file that replay can play.

    python -m bintrack.services.recorder --out FILE.mcap [--until eos|stopped]
        [--split-size BYTES] [--split-duration S]
        [-m MODE] [-e ENDPOINT]… [-l ENDPOINT]… [-c FILE] [--cfg KEY:VALUE]… [--net NAME]

Why MCAP: it is how pub/sub systems record their buses (ROS 2 bags, Foxglove): one channel per
topic — here per key expression — with a schema per message type (the pydantic JSON Schema,
payloads kept as the msgpack bytes that were on the bus), indexed by time, readable by
the ``mcap`` CLI (for Foxglove, which does not decode msgpack: ``bintrack export --foxglove``). The chunked writer leaves a readable prefix if the recorder
dies; a stop by SIGINT/SIGTERM finalises the file. Layout: :mod:`bintrack.live.recording`.

It waits for the ``deployment`` queryable and stores the deployment, subscribes to
``bintrack/<net>/**`` and records every valid message but ``control/progress/**``, with its
event time as log time (ns). A payload that does not decode is counted, logged once per
sender and not recorded. After each ``clock`` tick it reports progress. At end of stream it
waits until every live sensor_agent, peer_agent and basestation has reported done, then (with
``--until eos``, the default) finalises the file, reports done and exits 0; with ``--until
stopped`` it reports done and keeps recording until stopped.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import os
import time
from collections import deque
from pathlib import Path

import zenoh

from bintrack.argtypes import positive_float
from bintrack.live.bus import Service, UpstreamDone, add_bus_arguments, service_main
from bintrack.errors import CommandError
from bintrack.keys import parse_key
from bintrack.formats import FormatError
from bintrack.messages import MessageError, TrackSet, decode, decode_view, is_resent
from bintrack.live.recording import KIND_TYPES, RecordingWriter, event_time, open_recording

log = logging.getLogger("bintrack")

UPSTREAM = ("sensor_agent", "peer_agent", "basestation", "merge")
# outputs a restarted service may send again, recorded once (transitions are not here: they
# carry their seq, and remembering them per sensor would cost memory that grows for long)
RESULTS = frozenset({"estimate", "fusion_reports", "tracks", "laser_objects", "motion_velocity", "region_reports",
                     "region_tracks"})
FLUSH_INTERVAL, FLUSH_SPAN = 5.0, 32.0  # s of wall clock or of event time between two flushes of the file
CHUNK_SIZE = 1024 * 1024  # bytes: few chunks, so that the chunk index kept in memory stays small
DEDUPE_AFTER_RETURN = 1024  # result messages checked for duplicates after a service came back
RECENT_PER_KEY = 64  # payloads remembered per key of RESULTS, to record a message sent again only once
PARSED_KEYS = 65536  # distinct keys whose parse is remembered (a bound against key floods)
WAIT_LOG_INTERVAL = 5.0  # s of wall clock between "still waiting" lines


def add_arguments(parser: argparse.ArgumentParser, until_default: str = "eos") -> None:
    parser.add_argument("--out", required=True, metavar="FILE.mcap", help="the recording to write (overwritten)")
    parser.add_argument("--until", choices=("eos", "stopped"), default=until_default,
                        help="finalise and exit at the first end of stream once the services upstream are done "
                        "(eos), or record until SIGINT/SIGTERM (stopped) (default: %(default)s)")
    parser.add_argument("--split-size", type=size_bytes, metavar="BYTES",
                        help="start a new file once this one holds this many bytes, e.g. 100M "
                        "(FILE.mcap, then FILE_1.mcap, FILE_2.mcap, …; default: one file)")
    parser.add_argument("--split-duration", type=positive_float, metavar="S",
                        help="start a new file once this one spans this much event time, s (as --split-size)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser)


def size_bytes(text: str) -> int:
    """``123``, ``64K``, ``100M`` or ``2G`` (powers of 1024) as a positive number of bytes (argparse type)."""
    units = {"K": 1024, "M": 1024**2, "G": 1024**3}
    try:
        value = int(float(text[:-1]) * units[text[-1].upper()]) if text[-1:].upper() in units else int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f"not a positive size in bytes: {text!r} (e.g. 100M)")
    return value


def part_path(out: str, part: int) -> str:
    """The file of split ``part``: ``out`` itself for part 0, else ``<stem>_<part>.mcap``."""
    return out if part == 0 else str(Path(out).with_name(f"{Path(out).stem}_{part}.mcap"))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.recorder",
                                     description="Record bintrack/<net>/** into an MCAP file.")
    add_arguments(parser)
    return parser


class Recorder(Service):
    """The recorder service; raises CommandError on construction for an unusable ``--out``."""

    name = "recorder"

    def __init__(self, args: argparse.Namespace):
        out = Path(args.out)
        if out.suffix != ".mcap":
            raise CommandError(f"--out {args.out}: a recording's name must end in .mcap (replay tells them by it)")
        if not out.parent.is_dir():
            raise CommandError(f"--out {args.out}: folder {out.parent} does not exist")
        super().__init__(args)
        self.writer: RecordingWriter | None = None
        self.upstream = UpstreamDone(UPSTREAM)
        self.eos: float | None = None
        self.last_t = 0.0
        self.last_tracks = float("-inf")  # event time of the newest track set recorded
        self.recent: dict[str, deque[bytes]] = {}
        self.parsed: dict[str, tuple] = {}  # key → (its ParsedKey, its message type)
        self.raw_last: dict[str, float] = {}  # raw key → event time of the newest sample recorded (keys of parsed)
        self.resent_dropped = 0  # raw samples a restarted replay sent again that were already recorded
        self.gone: set[str] = set()  # alive/ keys of services that went away
        self.dedupe_left = 0  # result messages still checked for duplicates after a return
        self.gap_from: float | None = None  # after a restart: event time up to which the file was kept
        self.flushed_at, self.flushed_t = time.monotonic(), None
        self.part_start: float | None = None  # event time of the first tick of the current file
        self._changed = asyncio.Event()

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        self.deployment = deployment
        checkpoint = self.load_checkpoint()
        self.part = checkpoint.get("part", 0) if isinstance(checkpoint, dict) else 0
        self.path = part_path(self.args.out, self.part)
        restarted = checkpoint is not None and Path(self.path).exists()
        if restarted:  # keep what the previous instance recorded: it is copied into the new file
            aside = Path(self.path + ".interrupted")
            os.replace(self.path, aside)
        try:
            self.writer = RecordingWriter(self.path, deployment, self.args.net, chunk_size=CHUNK_SIZE)
        except OSError as exc:
            log.error("recorder: cannot write %s: %s", self.path, exc.strerror or exc)
            self.exit_status = 2
            self.stop()
            return
        self.writer.flush()  # the header and the deployment are on disk whatever happens next
        self.save_checkpoint({"part": self.part})
        if restarted:
            kept = self._copy(aside)
            aside.unlink()
            fetched = await asyncio.to_thread(self._fetch_tracks)
            log.info("recorder: restarted; kept the %d messages recorded before (up to t=%g s), fetched %d "
                     "track sets published since from the base station", kept, self.last_t, fetched)
            self.gap_from = self.last_t
        self._declared.append(self.session.liveliness().declare_subscriber(
            self.keys.alive(), self.inbox.callback(self._on_alive), history=True))
        self.subscribe(self.keys.all(), self._on_sample)
        log.info("recorder: recording %s into %s", self.keys.all(), self.path)

    def _copy(self, path: Path) -> int:
        """Copy the readable records of an interrupted recording into this one; how many."""
        count = 0
        try:
            for record in open_recording(path).records():
                self.writer.write(record.key, record.t, record.payload, record.received_ns)
                if record.kind == "tracks":
                    self.last_tracks = max(self.last_tracks, record.t)
                self.last_t = max(self.last_t, record.t)
                count += 1
        except FormatError as exc:
            log.warning("recorder: %s; kept %d messages of it", exc, count)
        return count

    def _fetch_tracks(self) -> int:
        """Record the track sets the base station published after the last one recorded (its
        ``tracks?after=T`` queryable): those a restart or a router outage kept from us."""
        count = 0
        for payload in self.query(f"{self.keys.tracks()}?after={self.last_tracks!r}", timeout=2.0):
            try:
                tracks = decode(TrackSet, payload)
            except MessageError as exc:
                self.bad.report(self.keys.tracks(), exc.reason)
                continue
            if tracks.t > self.last_tracks:
                self.recent.setdefault(self.keys.tracks(), deque(maxlen=RECENT_PER_KEY)).append(payload)
                self.writer.write(self.keys.tracks(), tracks.t, payload, time.time_ns())
                self.last_tracks = tracks.t
                count += 1
        return count

    async def on_router_back(self) -> None:
        if self.writer is not None and not self.writer.closed:
            fetched = await asyncio.to_thread(self._fetch_tracks)
            log.info("recorder: %d track sets published during the outage fetched from the base station", fetched)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        key, present = str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT
        self.upstream.on_liveliness(key, present)
        if present and key in self.gone:  # back after a restart or a router outage
            self.dedupe_left = DEDUPE_AFTER_RETURN
        (self.gone.discard if present else self.gone.add)(key)
        self._changed.set()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self.writer is None or self.writer.closed:
            return
        key = str(sample.key_expr)
        known = self.parsed.get(key)
        if known is None:
            try:
                parsed = parse_key(key)
                known = (parsed, KIND_TYPES[parsed.kind])
            except (ValueError, KeyError):
                self.bad.report(key, "unknown key: not a key of a bintrack message")
                return
            if len(self.parsed) >= PARSED_KEYS:
                self.parsed.clear()
                self.raw_last.clear()
            self.parsed[key] = known
        parsed, cls = known
        if parsed.kind in ("progress", "region_progress"):
            return
        payload = sample.payload.to_bytes()
        try:
            message = decode_view(cls, payload)
        except MessageError as exc:
            self.bad.report(key, exc.reason)
            return
        recent = self.recent.setdefault(key, deque(maxlen=RECENT_PER_KEY)) if parsed.kind in RESULTS else None
        if recent is not None and self.dedupe_left > 0:
            # an upstream service came back (restart, router): what it sends again is recorded
            # once. Only then: equal messages can be legitimate (a relay of equal estimates).
            self.dedupe_left -= 1
            if payload in recent:
                self.bad.report(key, "duplicate: the same message again, after a restart")
                return
        t = event_time(message)
        t = self.last_t if t is None else t
        if parsed.kind == "raw":
            if sample.attachment is not None and t <= self.raw_last.get(key, -math.inf) \
                    and is_resent(sample.attachment.to_bytes()):
                self.resent_dropped += 1  # a restarted replay sent it again; it is here already
                return
            self.raw_last[key] = t
        elif parsed.kind == "clock":
            if self.resent_dropped:
                log.info("recorder: %d raw samples a restarted replay sent again were already recorded; "
                         "recorded once", self.resent_dropped)
                self.resent_dropped = 0
            self._maybe_split(t)  # a new file starts with a clock tick
        if self.gap_from is not None and parsed.kind in ("clock", "eos"):
            # the first tick after a restart, or the end of stream if no tick follows (a kill
            # after the last tick): up to there, what the lost chunk held is not coming back
            log.warning("recorder: recording again from t=%g s; the raw samples, transitions and estimates "
                        "published between t=%g s and then are missing from %s (track sets fetched)",
                        t, self.gap_from, self.path)
            self.gap_from = None
        try:
            self.writer.write(key, t, payload, time.time_ns())
        except ValueError as exc:
            self.bad.report(key, f"unrecordable: {exc}")
            return
        if recent is not None:
            recent.append(payload)
        self.last_t = max(self.last_t, t)
        if parsed.kind == "tracks":
            self.last_tracks = max(self.last_tracks, t)
        elif parsed.kind == "clock":
            # each flush closes an MCAP chunk (its index, an entry per channel, stays in memory
            # until the file is finalised), so not at every tick: every FLUSH_INTERVAL s of
            # wall clock or FLUSH_SPAN s of event time. What a kill loses since is fetched back
            # for the track sets (tracks?after=T); the other messages of that span are missing.
            now = time.monotonic()
            if self.flushed_t is None:
                self.flushed_t = t
            if now - self.flushed_at >= FLUSH_INTERVAL or t - self.flushed_t >= FLUSH_SPAN:
                self.writer.flush()
                self.flushed_at, self.flushed_t = now, t
            self.report_progress(message.t)
        elif parsed.kind == "eos":
            self.eos = message.t
            self._changed.set()
        elif parsed.kind == "done":
            self.upstream.on_done(parsed.service, parsed.instance, message.t)
            self._changed.set()

    def _maybe_split(self, t: float) -> None:
        """Before the clock tick at ``t`` (so that each file starts with one): finalise the file and
        go on in the next once it reached --split-size bytes or would span --split-duration s of
        event time."""
        if self.part_start is None:
            self.part_start = t
        size, span = self.args.split_size, self.args.split_duration
        if not ((size and Path(self.path).stat().st_size >= size) or (span and t - self.part_start >= span)):
            return
        self._finalise()
        self.part += 1
        self.path = part_path(self.args.out, self.part)
        self.writer = RecordingWriter(self.path, self.deployment, self.args.net, chunk_size=CHUNK_SIZE)
        self.writer.flush()
        self.part_start = t
        self.save_checkpoint({"part": self.part})
        log.info("recorder: recording on into %s", self.path)

    def stop(self) -> None:
        super().stop()
        self._changed.set()

    def _owing(self) -> str:
        return ", ".join(f"{s}/{i}" for s, i in sorted(self.upstream.alive) if (s, i) not in self.upstream.done)

    async def main(self) -> None:
        last_said = time.monotonic()
        while not self.stopping.is_set():
            if self.eos is not None and self.upstream.complete:
                eos, self.eos = self.eos, None
                if self.args.until == "eos":
                    self._finalise()
                    self.report_done(eos)
                    return
                self.writer.flush()
                self.report_done(eos)
                self.upstream.done.clear()
                log.info("recorder: end of stream at t=%g s recorded; recording on", eos)
            self._changed.clear()
            try:
                await asyncio.wait_for(self._changed.wait(), WAIT_LOG_INTERVAL)
            except TimeoutError:
                if self.eos is not None and time.monotonic() - last_said >= WAIT_LOG_INTERVAL:
                    log.info("recorder: end of stream seen; waiting for done from %s", self._owing())
                    last_said = time.monotonic()

    def _finalise(self) -> None:
        if self.writer is not None and not self.writer.closed:
            self.writer.close()
            log.info("recorder: %d messages recorded in %s", self.writer.count, self.writer.path)

    async def teardown(self) -> None:
        if self.writer is None and self.exit_status == 0:
            log.info("recorder: stopped before the deployment was known; nothing recorded")
        self._finalise()

    def run(self) -> int:
        try:
            return super().run()
        finally:
            self._finalise()  # whatever went wrong, never leave the file unfinalised


def main(argv: list[str] | None = None) -> int:
    try:
        return service_main(Recorder, build_parser, argv)
    except CommandError as exc:
        log.error("recorder: %s", exc)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
