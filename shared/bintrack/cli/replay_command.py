"""``bintrack replay DIR|RECORDING [--speed X] [--loop] …``: the replay service in the foreground."""

from __future__ import annotations

import argparse

from bintrack.live.service import configure_logging
from bintrack.services.replay import Replay, add_arguments

__all__ = ["add_arguments", "run"]


def run(args: argparse.Namespace) -> int:
    configure_logging(args.verbose)
    return Replay(args).run()
