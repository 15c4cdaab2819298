"""Recorder: records everything of one network into an MCAP file that replay can play.

    python -m bintrack.services.recorder --out FILE.mcap [--until eos|stopped] [--split-size BYTES]
        [--split-duration S] [bus options]

The file is MCAP (:mod:`bintrack.live.recording` says why and how); the chunked writer leaves a
readable prefix if the recorder dies; a stop by SIGINT/SIGTERM finalises the file. Foxglove does
not decode msgpack: with ``--foxglove`` each finished file gets a copy beside it that Foxglove
opens (``FILE.foxglove.mcap``, as ``bintrack export --foxglove`` writes it).

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
import time
from pathlib import Path

import zenoh

from bintrack.argtypes import positive_float, size_bytes
from bintrack.errors import CommandError
from bintrack.keys import ParsedKey
from bintrack.live.checkpoint import RecorderCheckpoint
from bintrack.live.disk_full import MODES, DiskFull
from bintrack.live.end_of_stream import UpstreamDone
from bintrack.live.record_filter import RESULTS, RecordFilter
from bintrack.live.recording_files import RecordingFiles
from bintrack.live.service import Service, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.track_ledger import TRACK_SOURCES, TrackRefill
from bintrack.live.foxglove_export import write_foxglove_copy

log = logging.getLogger("bintrack")

UPSTREAM = ("sensor_agent", "peer_agent", "basestation", "merge")
WAIT_LOG_INTERVAL = 5.0  # s of wall clock between "still waiting" lines


def add_arguments(parser: argparse.ArgumentParser, until_default: str = "eos", net_default: str | None = "default") -> None:
    parser.add_argument("--out", required=True, metavar="FILE.mcap", help="the recording to write (overwritten)")
    parser.add_argument("--until", choices=("eos", "stopped"), default=until_default,
                        help="finalise and exit at the first end of stream once the services upstream are done "
                        "(eos), or record until SIGINT/SIGTERM (stopped) (default: %(default)s)")
    parser.add_argument("--split-size", type=size_bytes, metavar="BYTES",
                        help="start a new file once this one holds this many bytes, e.g. 100M "
                        "(FILE.mcap, then FILE_1.mcap, FILE_2.mcap, …; default: one file)")
    parser.add_argument("--split-duration", type=positive_float, metavar="S",
                        help="start a new file once this one spans this much event time, s (as --split-size)")
    parser.add_argument("--foxglove", action="store_true",
                        help="as each file is finalised, also write FILE.foxglove.mcap beside it: every message as "
                        "JSON and the scene as foxglove.SceneUpdate, the schemas `up --foxglove` serves, which "
                        "Foxglove opens directly")
    parser.add_argument("--on-disk-full", choices=MODES, default="stop",
                        help="when the file cannot be written (a full or failing disk): finalise it with what was "
                        "written and exit with status 3 (stop), or hold event time until it can be written again "
                        "(pause) (default: %(default)s)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser, net_default=net_default)


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
        self.files: RecordingFiles | None = None
        self.filter = RecordFilter(self.bad.report)
        self.upstream = UpstreamDone(UPSTREAM)
        self.eos: float | None = None
        self.last_tracks = float("-inf")  # event time of the newest track set recorded
        self.disk = DiskFull(args.on_disk_full, self._give_up)
        self.last_tick: float | None = None  # the newest clock tick recorded (its progress is owed while paused)
        # track sets the file may lack after a restart or a router outage
        self.refill = TrackRefill(self.keys.tracks(), self.query, self._record_fetched, self.bad.report,
                                  lambda: any(self.presence.holders(s) for s in TRACK_SOURCES))
        self._changed = asyncio.Event()

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        checkpoint = self.checkpoints.load(RecorderCheckpoint)
        self.files = files = RecordingFiles(self.args.out, deployment, self.args.net,
                                            checkpoint.part if checkpoint is not None else 0,
                                            self.args.split_size, self.args.split_duration,
                                            on_finalised=write_foxglove_copy if self.args.foxglove else None)
        try:
            aside = files.open(resume=checkpoint is not None)  # keep what the previous instance recorded
        except OSError as exc:
            log.error("recorder: cannot write %s: %s", files.path, exc.strerror or exc)
            self.exit_status = 2
            self.stop()
            return
        self.checkpoints.save(RecorderCheckpoint(files.part))
        if aside is not None:
            kept, last_t, self.last_tracks = files.copy_from(aside, self._copied)
            self.filter.last_t = max(self.filter.last_t, last_t)
            aside.unlink()
            log.info("recorder: restarted; kept the %d messages recorded before (up to t=%g s)", kept,
                     self.filter.last_t)
            self.refill.start(self.last_tracks)
            self.filter.restarted()
        self.follow_presence(self._on_presence)
        self.subscribe(self.keys.all(), self._on_sample)
        log.info("recorder: recording %s into %s", self.keys.all(), files.path)

    def _copied(self, record) -> None:
        if record.kind in RESULTS:
            self.filter.kept(record.key, record.payload, record.t, record.kind)

    def _record_fetched(self, key: str, tracks, payload: bytes, n: int) -> bool:
        if self.files.closed or self.filter.tracks.held(key, tracks.t, payload) >= n:
            return False
        self.filter.kept(key, payload, tracks.t, "tracks")
        self.files.writer.write(key, tracks.t, payload, time.time_ns())
        self.last_tracks = max(self.last_tracks, tracks.t)
        return True

    async def on_router_back(self) -> None:
        if not (self.files is None or self.files.closed):
            self.refill.start(self.last_tracks)

    def _on_presence(self, parsed: ParsedKey, present: bool) -> None:
        self.upstream.on_presence(parsed, present)
        self.filter.on_presence(parsed, present)
        self._changed.set()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self.files is None or self.files.closed:
            return
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        self.refill.progress(key, payload)
        admitted = self.filter.admit(key, payload, None if sample.attachment is None else sample.attachment.to_bytes())
        if admitted is None:
            return
        kind, t = admitted.parsed.kind, admitted.t
        if kind == "clock" and not self.disk.paused:  # a new file starts with a clock tick
            # a split that fails ends the recording even under pause: the old file is half finalised
            if not self.disk.attempt(self.files.writer, lambda: self._split(t), stopping=True) or self.files.closed:
                return
        self.filter.check_gap(kind, t, self.files.path)
        try:
            self.files.writer.write(key, t, payload, time.time_ns())
        except ValueError as exc:
            self.bad.report(key, f"unrecordable: {exc}")
            return
        self.filter.recorded(admitted, key, payload)
        if kind == "tracks":
            self.last_tracks = max(self.last_tracks, t)
        elif kind == "clock":
            self.refill.tick(t)
            self.last_tick = admitted.message.t
            if not self.disk.paused and self.disk.attempt(self.files.writer, lambda: self.files.tick(t)):
                self.report_progress(self.last_tick)  # none while paused: replay holds event time
        elif kind == "eos":
            self.eos = admitted.message.t
            self._changed.set()
        elif kind == "done":
            self.upstream.on_done(admitted.parsed.service, admitted.parsed.instance, admitted.message.t)
            self._changed.set()

    def _split(self, t: float) -> None:
        if self.files.split_before(t):
            self.checkpoints.save(RecorderCheckpoint(self.files.part))

    def _give_up(self, status: int) -> None:
        self.exit_status = status
        self.stop()

    async def _retry_while_paused(self) -> None:
        """While paused (--on-disk-full pause): write what is held until it goes; then the
        progress owed."""
        await self.disk.retry_while_paused(self.files.writer, self.stopping, self._progress_owed)

    def _progress_owed(self) -> None:
        if self.last_tick is not None:
            self.report_progress(self.last_tick)

    def stop(self) -> None:
        super().stop()
        self._changed.set()

    async def main(self) -> None:
        last_said = time.monotonic()
        while not self.stopping.is_set():
            if self.eos is not None and self.upstream.complete:
                await self.refill.finish()
                eos, self.eos = self.eos, None
                if self.args.until == "eos":
                    while not self._finalise() and self.disk.paused:
                        await self._retry_while_paused()
                    if not self.disk.gave_up:
                        self.report_done(eos)
                    return
                if not self.disk.attempt(self.files.writer, self.files.writer.flush):
                    self.eos = eos  # reported done once it is on disk (paused), or never (gave up)
                    continue
                self.report_done(eos)
                self.upstream.done.clear()
                log.info("recorder: end of stream at t=%g s recorded; recording on", eos)
            self._changed.clear()
            if self.disk.paused:
                await self._retry_while_paused()
                continue
            try:
                await asyncio.wait_for(self._changed.wait(), WAIT_LOG_INTERVAL)
            except TimeoutError:
                if self.eos is not None and time.monotonic() - last_said >= WAIT_LOG_INTERVAL:
                    owing = ", ".join(f"{s}/{i}" for s, i in self.upstream.owing())
                    log.info("recorder: end of stream seen; waiting for done from %s", owing)
                    last_said = time.monotonic()

    def _finalise(self) -> bool:
        """Finalise the file (once stopping, whatever the disk allows); whether it is done."""
        if self.files is None or self.files.closed:
            return True
        return self.disk.attempt(self.files.writer, self.files.finalise, stopping=self.stopping.is_set())

    async def teardown(self) -> None:
        if self.files is None and self.exit_status == 0:
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
