"""Recorder: records everything of one network into an MCAP file that replay can play.

    python -m bintrack.services.recorder --out FILE.mcap [--until eos|stopped]
        [-m MODE] [-e ENDPOINT]… [-l ENDPOINT]… [-c FILE] [--cfg KEY:VALUE]… [--net NAME]

Why MCAP: it is how pub/sub systems record their buses (ROS 2 bags, Foxglove): one channel per
topic — here per key expression — with a schema per message type (the pydantic JSON Schema,
payloads kept as the msgpack bytes that were on the bus), indexed by time, readable by
Foxglove and the ``mcap`` CLI. The chunked writer leaves a readable prefix if the recorder
dies; a stop by SIGINT/SIGTERM finalises the file. Layout: :mod:`bintrack.recording`.

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

from bintrack.bus import Service, UpstreamDone, add_bus_arguments, service_main
from bintrack.errors import CommandError
from bintrack.keys import parse_key
from bintrack.recording import KIND_TYPES, RecordingWriter, event_time

log = logging.getLogger("bintrack")

UPSTREAM = ("sensor_agent", "peer_agent", "basestation")
WAIT_LOG_INTERVAL = 5.0  # s of wall clock between "still waiting" lines


def add_arguments(parser: argparse.ArgumentParser, until_default: str = "eos") -> None:
    parser.add_argument("--out", required=True, metavar="FILE.mcap", help="the recording to write (overwritten)")
    parser.add_argument("--until", choices=("eos", "stopped"), default=until_default,
                        help="finalise and exit at the first end of stream once the services upstream are done "
                        "(eos), or record until SIGINT/SIGTERM (stopped) (default: %(default)s)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser)


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
        self._changed = asyncio.Event()

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        try:
            self.writer = RecordingWriter(self.args.out, deployment, self.args.net)
        except OSError as exc:
            log.error("recorder: cannot write %s: %s", self.args.out, exc.strerror or exc)
            self.exit_status = 2
            self.stop()
            return
        self._declared.append(self.session.liveliness().declare_subscriber(
            self.keys.alive(), self.inbox.callback(self._on_alive), history=True))
        self.subscribe(self.keys.all(), self._on_sample)
        log.info("recorder: recording %s into %s", self.keys.all(), self.args.out)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        self.upstream.on_liveliness(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
        self._changed.set()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self.writer is None or self.writer.closed:
            return
        key = str(sample.key_expr)
        try:
            parsed = parse_key(key)
            cls = KIND_TYPES[parsed.kind]
        except (ValueError, KeyError):
            self.bad.report(key, "unknown key: not a key of a bintrack message")
            return
        if parsed.kind == "progress":
            return
        message = self.decode(cls, sample)
        if message is None:
            return
        t = event_time(message)
        t = self.last_t if t is None else t
        try:
            self.writer.write(key, t, sample.payload.to_bytes(), time.time_ns())
        except ValueError as exc:
            self.bad.report(key, f"unrecordable: {exc}")
            return
        self.last_t = max(self.last_t, t)
        if parsed.kind == "clock":
            self.writer.flush()
            self.report_progress(message.t)
        elif parsed.kind == "eos":
            self.eos = message.t
            self._changed.set()
        elif parsed.kind == "done":
            self.upstream.on_done(parsed.service, parsed.instance, message.t)
            self._changed.set()

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
            log.info("recorder: %d messages recorded in %s", self.writer.count, self.args.out)

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
