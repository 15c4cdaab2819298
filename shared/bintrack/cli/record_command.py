"""``bintrack record --out FILE.mcap``: the recorder in the foreground, until Ctrl-C
(``--until eos`` to stop at the first end of stream instead). Without ``--net``, the one
network alive on the bus, as ``bintrack watch`` finds it."""

from __future__ import annotations

import argparse

from bintrack.argtypes import output_file
from bintrack.cli.network_choice import network_of
from bintrack.errors import CommandError
from bintrack.live.service import configure_logging
from bintrack.services import recorder


def add_arguments(parser: argparse.ArgumentParser) -> None:
    recorder.add_arguments(parser, until_default="stopped", net_default=None)
    parser.epilog = "Without --net, the one network alive on the bus (they are listed if several)."


def run(args: argparse.Namespace) -> int:
    if not args.out.endswith(".mcap"):
        raise CommandError(f"--out {args.out}: a recording's name must end in .mcap")
    output_file(args.out)
    configure_logging(args.verbose)
    args.net = network_of(args, "record")
    return recorder.Recorder(args).run()
