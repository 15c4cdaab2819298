"""``bintrack view [RECORDING.mcap] [--net NAME] [--map-port 8080] [--map-bind 127.0.0.1] [bus options]``.

Without a recording: the view service (``python -m bintrack.services.view``), the live map of
a network on the bus (``--net``, else the one network alive there, as ``bintrack watch``
finds it). With one: the same page serving the recording, with a time slider, play/pause and
speed; no bus needed.
"""

from __future__ import annotations

import argparse

from bintrack.argtypes import add_alias, port_number, positive_float
from bintrack.live.service import configure_logging
from bintrack.live.session_options import add_bus_arguments
from bintrack.view.map_server import DEFAULT_BIND, DEFAULT_PORT
from bintrack.view.map_state import DEFAULT_TAIL


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", nargs="?", metavar="RECORDING.mcap",
                        help="a recording to play in the page (default: the live network on the bus)")
    parser.add_argument("--map-port", dest="port", type=port_number, default=DEFAULT_PORT, metavar="PORT",
                        help="HTTP port of the map (default: %(default)s, or a free one if that is taken)")
    add_alias(parser, "--port", "--map-port", "port", type=port_number)
    parser.add_argument("--map-bind", dest="bind", default=DEFAULT_BIND, metavar="ADDRESS",
                        help="address the map is served on (default: %(default)s, this machine only)")
    add_alias(parser, "--bind", "--map-bind", "bind")
    parser.add_argument("--map-token", dest="token", metavar="TOKEN", help="a secret the map asks for, needed to serve it beyond 127.0.0.1: open the printed URL, which carries it "
                        "(default: $BINTRACK_MAP_TOKEN)")
    add_alias(parser, "--view-token", "--map-token", "token")
    parser.add_argument("--tail", type=positive_float, default=DEFAULT_TAIL, metavar="S",
                        help="event time drawn behind each track and truth target, s (default: %(default)s)")
    parser.add_argument("--salvage", action="store_true",
                        help="with a recording: play one with bad chunks anyway: the sound ones, saying in one line what was lost "
                        "(without it a corrupt recording is refused, exit 2)")
    parser.add_argument("--id", help="instance id on the bus (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser, net_default=None)
    parser.set_defaults(socket_fd=None, no_token=False)
    parser.epilog = "Without --net and a recording: the one network alive on the bus (they are listed if several)."


def run(args: argparse.Namespace) -> int:
    configure_logging(args.verbose)
    if args.recording is not None:
        from bintrack.view.recording_source import serve_recording

        return serve_recording(args)
    from bintrack.cli.network_choice import network_of
    from bintrack.services.view import View

    args.net = network_of(args, "view")
    return View(args).run()
