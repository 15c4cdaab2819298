"""``bintrack track DIR --tracker NAME [--out FILE]``: the offline runner."""

from __future__ import annotations

import argparse
import sys

from .argtypes import int_at_least, positive_float
from .errors import CommandError
from .formats import open_dataset, write_tracks
from .pipeline import output_rows, run_tracker
from .progress import Progress
from .trackers import TRACKER_NAMES, make_tracker


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", metavar="DIR", help="dataset folder (deployment.json, events.csv)")
    parser.add_argument("--tracker", required=True, choices=TRACKER_NAMES, help="tracker name")
    parser.add_argument("--out", default="tracks.csv", help="tracks.csv to write (default: %(default)s; '-' for stdout)")
    parser.add_argument("--speed", type=positive_float, help="target speed, units/s, for distance-weight and line-fit "
                        "(default: estimated from detection durations)")
    parser.add_argument("--window", type=int_at_least(2), default=10, help="line-fit: estimates in the fitted history (default: %(default)s)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show progress on stderr (default: when stderr is a terminal)")

def run(args: argparse.Namespace) -> int:
    dataset = open_dataset(args.dataset)
    try:
        tracker = make_tracker(args.tracker, dataset.deployment, speed=args.speed, window=args.window)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    progress = Progress(f"track {args.tracker}", enabled=args.progress)
    rows = output_rows(run_tracker(dataset, tracker, on_event=progress.update))
    target = sys.stdout if args.out == "-" else args.out
    try:
        count = write_tracks(target, rows)
    finally:
        progress.close()
    print(f"{count} estimates by {args.tracker} written to {args.out}", file=sys.stderr)
    return 0
