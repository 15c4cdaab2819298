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
import logging
from pathlib import Path

import zenoh

from bintrack.argtypes import positive_float, size_bytes
from bintrack.errors import CommandError
from bintrack.live.checkpoint import RecorderCheckpoint
from bintrack.live.disk_full import MODES, DiskFull
from bintrack.live.record_filter import RecordFilter
from bintrack.live.recording_end import RecordingEnd
from bintrack.live.recording_files import RecordingFiles
from bintrack.live.recording_sink import RecordingSink
from bintrack.live.service import Service, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.track_ledger import TRACK_SOURCES, TrackRefill
from bintrack.live.foxglove_export import write_foxglove_copy

log = logging.getLogger("bintrack")

UPSTREAM = ("sensor_agent", "peer_agent", "basestation", "merge")


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
        self.filter = RecordFilter(self.bad.report)
        self.sink = RecordingSink(self.filter, DiskFull(args.on_disk_full, self._give_up), self.bad.report,
                                  self.report_progress, lambda part: self.checkpoints.save(RecorderCheckpoint(part)))
        # track sets the file may lack after a restart or a router outage
        self.refill = TrackRefill(self.keys.tracks(), self.query, self.sink.record_fetched, self.bad.report,
                                  lambda: any(self.presence.holders(s) for s in TRACK_SOURCES))
        self.end = RecordingEnd(UPSTREAM, self.sink, self.refill, self.report_done, args.until == "eos", self.stopping)

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        checkpoint = self.checkpoints.load(RecorderCheckpoint)
        files = RecordingFiles(self.args.out, deployment, self.args.net,
                               checkpoint.part if checkpoint is not None else 0,
                               self.args.split_size, self.args.split_duration,
                               on_finalised=write_foxglove_copy if self.args.foxglove else None)
        try:
            restarted = self.sink.open(files, resume=checkpoint is not None)
        except OSError as exc:
            log.error("recorder: cannot write %s: %s", files.path, exc.strerror or exc)
            self.exit_status = 2
            self.stop()
            return
        if restarted:
            self.refill.start(self.sink.last_tracks)
        self.follow_presence(self.end.on_presence)
        self.follow_presence(self.filter.on_presence)
        self.subscribe(self.keys.all(), self._on_sample)
        log.info("recorder: recording %s into %s", self.keys.all(), files.path)

    async def on_router_back(self) -> None:
        if not self.sink.closed:
            self.refill.start(self.sink.last_tracks)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self.sink.closed:
            return
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        self.refill.progress(key, payload)
        admitted = self.filter.admit(key, payload, None if sample.attachment is None else sample.attachment.to_bytes())
        if admitted is None or not self.sink.write(admitted, key, payload):
            return
        kind = admitted.parsed.kind
        if kind == "clock":
            self.refill.tick(admitted.t)
            self.sink.ticked(admitted)
        elif kind == "eos":
            self.end.on_eos(admitted.message.t, admitted.message.awaited or ())
        elif kind == "done":
            self.end.on_done(admitted.parsed.service, admitted.parsed.instance, admitted.message.t)

    def _give_up(self, status: int) -> None:
        self.exit_status = status
        self.stop()

    def stop(self) -> None:
        super().stop()
        self.end.changed.set()

    async def main(self) -> None:
        await self.end.run()

    async def teardown(self) -> None:
        if self.sink.files is None and self.exit_status == 0:
            log.info("recorder: stopped before the deployment was known; nothing recorded")
        self.sink.finalise(self.stopping.is_set())

    def run(self) -> int:
        try:
            return super().run()
        finally:
            self.sink.finalise(self.stopping.is_set())  # whatever went wrong, never leave the file unfinalised


def main(argv: list[str] | None = None) -> int:
    try:
        return service_main(Recorder, build_parser, argv)
    except CommandError as exc:
        log.error("recorder: %s", exc)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
