"""``bintrack export RECORDING --what tracks|estimates|objects|velocity --out FILE``: the results
in a recording, in the files of DESIGN §6; ``bintrack export RECORDING --foxglove OUT.mcap``: a
copy Foxglove can open (:mod:`bintrack.live.foxglove_export`).

* ``tracks``: every ``TrackSet`` → one tracks.csv row per track;
* ``estimates``: every ``LocalEstimate`` → a tracks.csv row of track 0;
* ``velocity``: every ``VelocityEstimate`` → a tracks.csv row of track 0 (x, y empty when the
  method gives no position);
* ``objects``: ``LineObjectEstimate`` → objects.csv, the last estimate of each object (a later
  estimate of the same pass refines an earlier one).

Rows are sorted by (t, track, x, y) — objects by object number — so an export does not depend
on the order messages arrived in.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from bintrack.argtypes import output_file
from bintrack.errors import CommandError
from bintrack.formats import ObjectRow, TrackRow, write_objects, write_tracks
from bintrack.pipeline import output_objects, output_rows
from bintrack.live.recording import Recording, open_recording

WHAT = {"tracks": "tracks", "estimates": "estimate", "velocity": "motion_velocity", "objects": "laser_objects"}


def _order(row: TrackRow) -> tuple[float, int, float, float]:
    return (row.t, row.track, -math.inf if row.x is None else row.x, -math.inf if row.y is None else row.y)


def track_rows(recording: Recording, what: str) -> list[TrackRow]:
    """tracks.csv rows of the ``tracks``, ``estimates`` or ``velocity`` messages of ``recording``,
    sorted by (t, track, x, y); FormatError for a payload that does not decode."""
    messages = (message for _, message in recording.messages({WHAT[what]}))
    return sorted(output_rows(messages), key=_order)


def object_rows(recording: Recording) -> list[ObjectRow]:
    """objects.csv rows of ``recording``: the last ``LineObjectEstimate`` of each object, by object."""
    return output_objects(message for _, message in recording.messages({WHAT["objects"]}))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="RECORDING", help="a recording (FILE.mcap) made by bintrack record")
    parser.add_argument("--what", choices=tuple(WHAT), help="which results to export")
    parser.add_argument("--out", metavar="FILE",
                        help="tracks.csv (objects.csv for --what objects) to write; '-' for standard output")
    parser.add_argument("--foxglove", metavar="OUT.mcap",
                        help="instead: write every message JSON-encoded, plus a foxglove.SceneUpdate channel /scene, "
                        "for Foxglove")
    parser.add_argument("--salvage", action="store_true",
                        help="read a recording with bad chunks anyway: the sound ones, saying in one line what was lost "
                        "(without it a corrupt recording is refused, exit 2)")


def run(args: argparse.Namespace) -> int:
    if args.foxglove is not None:
        if args.what is not None or args.out is not None:
            raise CommandError("--foxglove writes the whole recording: give it without --what and --out")
        if not args.foxglove.endswith(".mcap"):
            raise CommandError(f"--foxglove {args.foxglove}: the output's name must end in .mcap")
    elif args.what is None or args.out is None:
        raise CommandError("give --what and --out (or --foxglove OUT.mcap)")
    recording = open_recording(args.recording, salvage=args.salvage)
    note = recording.note()
    if note is not None:
        print(f"bintrack export: warning: {note}; exporting what was read", file=sys.stderr)
    elif not recording.complete:
        print(f"bintrack export: warning: {args.recording} was not finalised (it has no index); all its "
              f"{recording.message_count} records read", file=sys.stderr)
    if args.foxglove is not None or args.out != "-":
        output_file(args.foxglove if args.foxglove is not None else args.out)
    if args.foxglove is not None:
        from bintrack.live.foxglove_export import export_foxglove

        if Path(args.foxglove).resolve() == Path(args.recording).resolve():
            raise CommandError("--foxglove must not overwrite the recording itself")
        counts = export_foxglove(recording, args.foxglove)
        print(f"{sum(counts.values())} JSON messages written to {args.foxglove} "
              f"({', '.join(f'{kind} {n}' for kind, n in sorted(counts.items()))})", file=sys.stderr)
        return 0
    target = sys.stdout if args.out == "-" else args.out
    if args.what == "objects":
        count = write_objects(target, object_rows(recording))
    else:
        count = write_tracks(target, track_rows(recording, args.what))
    print(f"{count} {args.what} rows written to {args.out}", file=sys.stderr)
    return 0
