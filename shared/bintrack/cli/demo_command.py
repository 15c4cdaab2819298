"""``bintrack demo``: the README's main job.

Starts the embedded stack (``bintrack up``: a router in this process, every service as a
subprocess), replays the shipped DARPA-style 3-person dataset faster than real time while
recording everything, then exports the tracks from the recording, prints the final track
table and the metrics against truth, and writes a PNG of sensors, detections, tracks and truth.
"""

from __future__ import annotations

import argparse
import socket
from pathlib import Path

from bintrack.argtypes import add_alias, non_negative_float, output_folder
from bintrack.cli import up_command as up
from bintrack.cli.up_command import RouterPortTaken, add_map_arguments
from bintrack.errors import CommandError
from bintrack.evaluation.eval_report import evaluate
from bintrack.cli.export_command import track_rows
from bintrack.formats import TrackRow, fmt, open_dataset, write_tracks
from bintrack.evaluation.plotting import plot_evaluation
from bintrack.live.recording import open_recording
from bintrack.trackers import TRACKER_NAMES

SHIPPED_DATASET = Path(__file__).resolve().parents[3] / "datasets" / "darpa-grid-3"
# Several people at once: fusion and online MCMCDA at the base station (paper 004).
DEMO_TRACKER = "mcmcda"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", nargs="?", type=Path, metavar="DIR",
                        help="dataset folder (default: the shipped darpa-grid-3)")
    add_alias(parser, "--dataset", "DIR (positional)", "dataset_option", type=Path)
    parser.add_argument("--tracker", choices=TRACKER_NAMES, default=DEMO_TRACKER, help="tracker (default: %(default)s)")
    parser.add_argument("--speed", type=non_negative_float, default=0.0,
                        help="replay speed; 0 = as fast as the services keep up (default: %(default)s)")
    add_map_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("out/demo"), metavar="DIR",
                        help="folder for recording.mcap, tracks.csv and demo.png (default: %(default)s)")


def final_table(rows: list[TrackRow]) -> list[str]:
    """Every track's last row, by track id, as aligned text."""
    last: dict[int, TrackRow] = {}
    for r in rows:
        if r.track not in last or r.t >= last[r.track].t:
            last[r.track] = r
    lines = [f"{'t [s]':>10} {'track':>5} {'x':>9} {'y':>9} {'vx':>8} {'vy':>8}"]
    for track in sorted(last):
        r = last[track]
        lines.append(f"{fmt(r.t, 3):>10} {r.track:>5} {fmt(r.x, 2):>9} {fmt(r.y, 2):>9} "
                     f"{fmt(r.vx, 2) or '-':>8} {fmt(r.vy, 2) or '-':>8}")
    return lines


def _free_endpoint() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


def run(args: argparse.Namespace) -> int:
    folder = args.source or getattr(args, "dataset_option", None) or SHIPPED_DATASET
    if not (folder / "deployment.json").exists():
        raise CommandError(f"no dataset at {folder} (run `make datasets`, or give a dataset folder)")
    dataset = open_dataset(folder)
    output_folder(args.out)
    recording = args.out / "recording.mcap"
    print(f"bintrack demo: {dataset.deployment.name}, {len(dataset.deployment.sensors)} sensors, "
          f"tracker {args.tracker}, live stack at speed {args.speed:g} (0 = as fast as it keeps up)")
    # up's own parser, so that every option of up has its default here too
    parser = argparse.ArgumentParser(prog="bintrack up")
    up.add_arguments(parser)
    options = [str(folder), "--tracker", args.tracker, "--speed", repr(args.speed), "--record", str(recording),
               "--exit-at-end", "--map-port", str(args.view_port), "--map-bind", args.view_bind,
               *(("--map-token", args.view_token) if args.view_token else ()), *(() if args.view else ("--no-map",))]
    # the router's port is checked free and then bound: should another program take it in
    # between, try another one
    for attempt in range(3):
        try:
            status = up.run(parser.parse_args([*options, "--listen", _free_endpoint()]))
            break
        except RouterPortTaken:
            if attempt == 2:
                raise
    if status != 0:
        return status
    rows = track_rows(open_recording(recording), "tracks")
    tracks_path = args.out / "tracks.csv"
    write_tracks(tracks_path, rows)
    print(f"\nfinal track table ({len(rows)} rows in {tracks_path}; each track's last row):")
    print("\n".join(final_table(rows)))
    evaluation = evaluate(dataset, tracks_path)
    print("\nmetrics against truth.csv:")
    print("\n".join(evaluation.lines()))
    png = plot_evaluation(args.out / "demo.png", dataset, evaluation)
    print(f"\nrecording: {recording}\nplot: {png}")
    return 0
