"""View: the live map of a network in the browser (DESIGN §9).

    python -m bintrack.services.view [--port 8080] [--bind 127.0.0.1] [--tail S]
        [-m MODE] [-e ENDPOINT]… [-l ENDPOINT]… [-c FILE] [--cfg KEY:VALUE]… [--net NAME]

Serves the page on http://BIND:PORT/ at once, then takes the deployment from the
``deployment`` queryable and the latest tracks from the ``tracks`` queryable (again whenever
a page connects before any scan has arrived), and follows the whole network through the one
bounded inbox every service has: transitions light sensors, and fused reports, estimates,
tracks, laser objects, velocities and truth are pushed to every open page. It acknowledges
each clock tick once it has taken it in (pages never hold it up: a slow page is dropped to the
latest state), so replay's flow control counts it like any other service. A status line on
the page says when the router or the stack is gone.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import sys
import time
from collections import Counter

import zenoh

from bintrack.argtypes import port_number, positive_float
from bintrack.live.service import Service, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.errors import CommandError
from bintrack.keys import parse_key
from bintrack.bus_payloads import TrackSet
from bintrack.message_codec import MessageError, decode
from bintrack.live.recording import KIND_TYPES
from bintrack.view.map_access import check_bind, token_from
from bintrack.view.map_messages import DRAWN_KINDS, message_item
from bintrack.view.map_server import (DEFAULT_BIND, DEFAULT_PORT, MapHub, listening_socket, make_app, page_url,
                                      served_line, start_site)
from bintrack.view.map_state import DEFAULT_TAIL, MapState

log = logging.getLogger("bintrack")

STATUS_PERIOD = 1.0   # s of wall clock between status lines to the pages
RATE_KINDS = ("raw", "transition", "estimate", "fusion_reports", "tracks")


def add_web_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=port_number, default=DEFAULT_PORT,
                        help="HTTP port of the page (default: %(default)s; a free one if that is taken, and 0 "
                        "always picks a free one)")
    parser.add_argument("--bind", default=DEFAULT_BIND, metavar="ADDRESS",
                        help="address to serve on (default: %(default)s, this machine only)")
    parser.add_argument("--token", metavar="TOKEN", help="a secret the map asks for, needed to serve it beyond 127.0.0.1: open the printed URL, which carries it "
                        "(default: $BINTRACK_MAP_TOKEN)")
    parser.add_argument("--no-token", action="store_true",
                        help="start beyond 127.0.0.1 even without a token: for `bintrack up`, which checked that "
                        "itself, and a container whose port is published on the host's loopback alone (the compose "
                        "files); a token given is still asked for")
    parser.add_argument("--socket-fd", type=int, metavar="FD", help=argparse.SUPPRESS)  # a listening socket from `up`
    parser.add_argument("--tail", type=positive_float, default=DEFAULT_TAIL, metavar="S",
                        help="event time drawn behind each track and truth target, s (default: %(default)s)")


class View(Service):
    name = "view"

    async def setup(self) -> None:
        self.hub = MapHub(MapState(tail=self.args.tail))
        self.hub.on_page = self.complete_picture
        self.counts: Counter = Counter()
        token = token_from(self.args.token)
        if not self.args.no_token:
            check_bind(self.args.bind, token)
        try:
            if self.args.socket_fd is not None:   # bound by `bintrack up`, which keeps the port across restarts
                sock = socket.socket(fileno=self.args.socket_fd)
            else:
                sock = listening_socket(self.args.bind, self.args.port)
            self.runner = await start_site(make_app(self.hub, token), sock)
        except OSError as exc:
            raise CommandError(str(exc)) from None
        self.url = page_url(self.args.bind, sock.getsockname()[1], token)
        # one write: unbuffered, print() sends the line and its newline apart, and another
        # process sharing the stream can land between them
        sys.stderr.write(served_line("view", self.args.bind, self.args.port, sock, token) + "\n")
        sys.stderr.flush()
        self.subscribe(self.keys.all(), self.on_sample)
        self.services: set[tuple[str, str]] = set()
        self.follow_presence(self.on_presence)

    def on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            kind = parse_key(key).kind
        except ValueError:
            return
        self.counts[kind] += 1
        if kind not in DRAWN_KINDS:
            return
        message = self.decode(KIND_TYPES[kind], sample)
        if message is None:
            return
        item = message_item(message)
        if item is not None and not self.hub.publish(item):
            self.bad.report(key, f"{item['k']} of a sensor or node not in the deployment")
        if kind == "clock":
            self.report_progress(message.t)
        elif kind == "eos":  # every time: replay repeats it until each awaited service reports done
            self.report_done(message.t)

    def on_presence(self, parsed, present: bool) -> None:
        if parsed.kind == "alive":
            (self.services.add if present else self.services.discard)((parsed.service, parsed.instance))

    async def complete_picture(self) -> None:
        """Before a page's first snapshot: the latest tracks from the queryable if none came yet."""
        if self.hub.state.latest_tracks is None and self.hub.state.deployment is not None:
            await self.fetch_latest_tracks()

    async def fetch_latest_tracks(self) -> None:
        best = None
        for payload in await asyncio.to_thread(self.query, self.keys.tracks(), 1.0):
            try:
                candidate = decode(TrackSet, payload)
            except MessageError as exc:
                self.bad.report(self.keys.tracks(), exc.reason)
                continue
            if best is None or candidate.t > best.t:
                best = candidate
        if best is not None and self.hub.state.latest_tracks is None:
            self.hub.publish(message_item(best))

    async def main(self) -> None:
        status = asyncio.create_task(self.report_status())
        try:
            deployment = await self.wait_for_deployment()
            if deployment is not None:
                self.hub.set_status(message="")
                self.hub.broadcast(self.hub.state.set_deployment(deployment))
                await self.fetch_latest_tracks()
            await self.stopping.wait()
        finally:
            status.cancel()

    def _routers(self) -> int:
        return len(self.session.info.routers_zid())

    async def report_status(self) -> None:
        before, t_before = Counter(), time.monotonic()
        while not self.stopping.is_set():
            await asyncio.sleep(STATUS_PERIOD)
            mode = self.args.mode or "client"
            router = True if mode != "client" else await asyncio.to_thread(self._routers) > 0
            now = time.monotonic()
            rates = {kind: round((self.counts[kind] - before[kind]) / (now - t_before), 1) for kind in RATE_KINDS}
            before, t_before = Counter(self.counts), now
            others = sorted({service for service, _ in self.services if service != self.name})
            if not router:
                message = "bus gone: no Zenoh router reachable; retrying"
            elif self.hub.state.deployment is None:
                message = f"waiting for the deployment on {self.keys.deployment()}"
            elif not others:
                message = "stack gone: no bintrack service is alive on this network"
            else:
                message = ""
            self.hub.set_status(router=router, services=others, rates=rates, message=message, net=self.args.net,
                                dropped=self.inbox.dropped + sum(f.dropped for f in self.hub.feeds))

    async def teardown(self) -> None:
        await self.runner.cleanup()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.view", description=__doc__.splitlines()[0])
    add_web_arguments(parser)
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(View, build_parser))
