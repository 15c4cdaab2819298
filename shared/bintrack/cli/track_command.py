"""``bintrack track DIR --tracker NAME [--out FILE]``: the offline runner. Trackers of line
sensors write objects.csv, the others tracks.csv (DESIGN §6)."""

from __future__ import annotations

import argparse
import sys

from bintrack.argtypes import output_file
from bintrack.argtypes import positive_float
from bintrack.errors import CommandError
from bintrack.formats import open_dataset, write_objects, write_tracks
from bintrack.pipeline import output_objects, output_rows, run_regions, run_tracker
from bintrack.regions import RegionMap
from bintrack.time_span import TimeSpan
from bintrack.trackers.multi.region_merge import RegionMerge
from bintrack.cli.progress import Progress
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.trackers import OBJECT_TRACKERS, TRACKER_NAMES, check_options, make_tracker, sensor_mismatch
from bintrack.trackers.tracker_arguments import add_tracker_arguments, tracker_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", metavar="DIR", help="dataset folder (deployment.json, events.csv)")
    parser.add_argument("--tracker", required=True, choices=TRACKER_NAMES, help="tracker name")
    parser.add_argument("--out", help="tracks.csv (objects.csv for adaptive-basis) to write "
                        "(default: tracks.csv or objects.csv; '-' for stdout)")
    parser.add_argument("--speed", type=positive_float, metavar="V",
                        help="target speed, units/s: for distance-weight and line-fit (default: estimated from "
                        f"detection durations); mcmcda's fastest target (default: {MCMCDAConfig.max_speed:g} m/s in "
                        "the deployment's units); motion-rw's first guess")
    add_tracker_arguments(parser)
    parser.add_argument("--beams", metavar="FILE.csv",
                        help="adaptive-basis: also write the estimated beams a·x + b·y = 1 (sensor,a,b; units⁻¹)")
    parser.add_argument("--online", action="store_true",
                        help="adaptive-basis: write each object as first estimated, when its pass ended (default: its "
                        "latest revision, re-solved with the beams as sharpened by every later pass)")
    parser.add_argument("--regions", action="store_true",
                        help="mcmcda: run a tracker per region of deployment.json (its sensors and a border band two "
                        "sensing ranges wide) and merge them, as the region base stations and the merge service do")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show progress on stderr (default: when stderr is a terminal)")

def run(args: argparse.Namespace) -> int:
    beams = getattr(args, "beams", None)
    if beams is not None and args.tracker not in OBJECT_TRACKERS:
        raise CommandError(f"--beams: tracker {args.tracker} does not estimate beams (adaptive-basis does)")
    online = getattr(args, "online", False)
    if online and args.tracker not in OBJECT_TRACKERS:
        raise CommandError(f"--online: tracker {args.tracker} does not revise its estimates (adaptive-basis does)")
    dataset = open_dataset(args.dataset)
    span = TimeSpan.of(event.t for event in dataset.events()).warning(str(dataset.events_path))
    if span is not None:
        print(f"bintrack track: warning: {span}", file=sys.stderr)
    if args.out not in (None, "-"):
        output_file(args.out)
    if getattr(args, "regions", False):
        return run_regions_command(args, dataset)
    try:
        tracker = make_tracker(args.tracker, dataset.deployment, tracker_options(args))
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    mismatch = sensor_mismatch(args.tracker, dataset.deployment)
    if mismatch is not None:
        print(f"bintrack track: warning: {mismatch}", file=sys.stderr)
    objects = args.tracker in OBJECT_TRACKERS
    out = args.out or ("objects.csv" if objects else "tracks.csv")
    progress = Progress(f"track {args.tracker}", enabled=args.progress)
    outputs = run_tracker(dataset, tracker, on_event=progress.update)
    target = sys.stdout if out == "-" else out
    try:
        count = write_objects(target, output_objects(outputs, online=online)) if objects else write_tracks(target, output_rows(outputs))
    finally:
        progress.close()
    print(f"{count} {'objects' if objects else 'estimates'} by {args.tracker} written to {out}", file=sys.stderr)
    if hasattr(tracker, "info"):
        print_info(tracker.info())
    if beams is not None:
        rows = tracker.beams()
        write_beams(beams, rows)
        print(f"{len(rows)} beams written to {beams}", file=sys.stderr)
    return 0


def region_trackers(deployment, options, band: float | None = None) -> tuple[dict, dict[str, set[str]], RegionMap]:
    """Per region of ``deployment``: its mcmcda tracker and the sensors it takes."""
    regions = RegionMap(deployment)
    trackers, taken = {}, {}
    for name in regions.names:
        part = regions.sub_deployment(name, band)
        trackers[name] = make_tracker("mcmcda", part, options)
        taken[name] = {s.id for s in part.sensors}
    return trackers, taken, regions


def run_regions_command(args: argparse.Namespace, dataset) -> int:
    if args.tracker != "mcmcda":
        raise CommandError(f"--regions runs mcmcda per region; --tracker {args.tracker} cannot")
    options = tracker_options(args)
    try:
        check_options("mcmcda", options, regional=True)
        trackers, taken, regions = region_trackers(dataset.deployment, options)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    out = args.out or "tracks.csv"
    outputs = run_regions(dataset, trackers, taken, RegionMerge(regions))
    count = write_tracks(sys.stdout if out == "-" else out, output_rows(outputs))
    print(f"{count} estimates by mcmcda in {len(regions.names)} regions written to {out}", file=sys.stderr)
    return 0


def print_info(info: dict) -> None:
    """The adaptive basis tracker's frame and warnings, on stderr."""
    if info.get("frame_source") is not None:
        residual = info["frame_residual"]
        fit = f"; residual {residual:.3g} {info['units']} RMS on {info['frame_points']}" if residual is not None else ""
        print(f"phase 2: {info['phase2']}; real-world frame from {info['frame_source']}{fit}", file=sys.stderr)
    for warning in info.get("warnings", ()):
        print(f"warning: {warning}", file=sys.stderr)


def write_beams(path: str, beams: dict[str, tuple[float, float]]) -> None:
    """Write sensor,a,b rows (the beam a·x + b·y = 1, units⁻¹) to ``path`` ('-': stdout)."""
    import csv

    try:
        handle = sys.stdout if path == "-" else open(path, "w", newline="")
    except OSError as exc:
        raise CommandError(f"cannot write --beams {path}: {exc.strerror or exc}") from None
    try:
        writer = csv.writer(handle)
        writer.writerow(["sensor", "a", "b"])
        for sensor, (a, b) in beams.items():
            writer.writerow([sensor, repr(a), repr(b)])
    finally:
        if handle is not sys.stdout:
            handle.close()
