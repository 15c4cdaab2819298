"""``bintrack track DIR --tracker NAME [--out FILE]``: the offline runner. Trackers of line
sensors write objects.csv, the others tracks.csv (DESIGN §6)."""

from __future__ import annotations

import argparse
import sys

from .adaptive_basis import PHASE2_METHODS
from .argtypes import int_at_least, positive_float
from .errors import CommandError
from .mcmcda import MCMCDAConfig
from .formats import open_dataset, write_objects, write_tracks
from .pipeline import output_objects, output_rows, run_tracker
from .progress import Progress
from .trackers import OBJECT_TRACKERS, PEER_TRACKERS, TRACKER_NAMES, TrackerOptions, make_tracker


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", metavar="DIR", help="dataset folder (deployment.json, events.csv)")
    parser.add_argument("--tracker", required=True, choices=TRACKER_NAMES, help="tracker name")
    parser.add_argument("--out", help="tracks.csv (objects.csv for adaptive-basis) to write "
                        "(default: tracks.csv or objects.csv; '-' for stdout)")
    parser.add_argument("--speed", type=positive_float, help="target speed, units/s, for distance-weight and line-fit, and mcmcda's fastest target "
                        "(default: estimated from detection durations)")
    add_tracker_arguments(parser)
    parser.add_argument("--beams", metavar="FILE.csv",
                        help="adaptive-basis: also write the estimated beams a·x + b·y = 1 (sensor,a,b; units⁻¹)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show progress on stderr (default: when stderr is a terminal)")

def run(args: argparse.Namespace) -> int:
    beams = getattr(args, "beams", None)
    if beams is not None and args.tracker not in OBJECT_TRACKERS:
        raise CommandError(f"--beams: tracker {args.tracker} does not estimate beams (adaptive-basis does)")
    dataset = open_dataset(args.dataset)
    try:
        tracker = make_tracker(args.tracker, dataset.deployment, tracker_options(args))
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    objects = args.tracker in OBJECT_TRACKERS
    out = args.out or ("objects.csv" if objects else "tracks.csv")
    progress = Progress(f"track {args.tracker}", enabled=args.progress)
    outputs = run_tracker(dataset, tracker, on_event=progress.update)
    target = sys.stdout if out == "-" else out
    try:
        count = write_objects(target, output_objects(outputs)) if objects else write_tracks(target, output_rows(outputs))
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


def add_tracker_arguments(parser: argparse.ArgumentParser) -> None:
    """The trackers' options (but ``--speed``), alike for ``bintrack track``, ``up`` and the services."""
    parser.add_argument("--window", type=int_at_least(1), help="line-fit: estimates in the fitted history (default: 10); "
                        "velocity-plane, svm, ppr, motion-rw: periods per estimate (default: all so far; motion-rw: 1)")
    parser.add_argument("--seed", type=int, default=0, help="mcmcda, motion-rw: seed (default: %(default)s)")
    parser.add_argument("--n-mc", type=int_at_least(1), help=f"mcmcda: MH iterations per scan (default: {MCMCDAConfig.n_mc})")
    parser.add_argument("--scans", type=int_at_least(2), help=f"mcmcda: sliding window, scans (default: {MCMCDAConfig.window})")
    parser.add_argument("--estimates", choices=PEER_TRACKERS, metavar="TRACKER",
                        help="mcmcda: also take this peer tracker's estimates as position reports")
    parser.add_argument("--phase2", choices=PHASE2_METHODS,
                        help="adaptive-basis: lsq = eq. 5 to its least-squares optimum after every pass (default), "
                        "paper = 5 Newton iterations per pass (paper 003 §7.2)")


def tracker_arguments(options: TrackerOptions) -> tuple[str, ...]:
    """The command-line options that give a service ``options`` (but ``--estimates``, which
    decides the services themselves)."""
    out: list[str] = []
    for flag, value in (("--speed", options.speed), ("--window", options.window), ("--n-mc", options.n_mc),
                        ("--scans", options.scans), ("--phase2", options.phase2)):
        if value is not None:
            out += [flag, str(value)]
    if options.seed:
        out += ["--seed", str(options.seed)]
    return tuple(out)


def tracker_options(args: argparse.Namespace) -> TrackerOptions:
    """The ``TrackerOptions`` of parsed command-line options (absent ones keep their defaults)."""
    fields = {name: getattr(args, name) for name in ("speed", "window", "seed", "n_mc", "scans", "estimates", "phase2")
              if hasattr(args, name)}
    return TrackerOptions(**{k: v for k, v in fields.items() if v is not None})
