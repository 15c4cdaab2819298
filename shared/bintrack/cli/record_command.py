"""``bintrack record --out FILE.mcap``: the recorder in the foreground, until Ctrl-C
(``--until eos`` to stop at the first end of stream instead)."""

from __future__ import annotations

import argparse

from bintrack.live.service import configure_logging
from bintrack.services import recorder


def add_arguments(parser: argparse.ArgumentParser) -> None:
    recorder.add_arguments(parser, until_default="stopped")


def run(args: argparse.Namespace) -> int:
    configure_logging(args.verbose)
    return recorder.Recorder(args).run()
