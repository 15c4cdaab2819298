"""``bintrack view [RECORDING.mcap] [--net NAME] [--port 8080] [--bind 127.0.0.1] [bus options]``.

Without a recording: the view service (``python -m bintrack.services.view``), the live map of
network ``--net`` on the bus. With one: the same page serving the recording, with a time
slider, play/pause and speed; no bus needed.
"""

from __future__ import annotations

import argparse

from bintrack.live.service import configure_logging
from bintrack.live.session_options import add_bus_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from bintrack.services.view import add_web_arguments

    parser.add_argument("recording", nargs="?", metavar="RECORDING.mcap",
                        help="a recording to play in the page (default: the live network on the bus)")
    add_web_arguments(parser)
    parser.add_argument("--id", help="instance id on the bus (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser)


def run(args: argparse.Namespace) -> int:
    configure_logging(args.verbose)
    if args.recording is not None:
        from bintrack.view.recording_source import serve_recording

        return serve_recording(args)
    from bintrack.services.view import View

    return View(args).run()
