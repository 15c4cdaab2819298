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

from bintrack.cli import up_command as up
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
DEMO_VIEW_PORT = 8080


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", type=Path, default=SHIPPED_DATASET,
                        help="dataset folder (default: the shipped darpa-grid-3)")
    parser.add_argument("--tracker", choices=TRACKER_NAMES, default=DEMO_TRACKER, help="tracker (default: %(default)s)")
    parser.add_argument("--speed", type=float, default=0.0,
                        help="replay speed; 0 = as fast as the services keep up (default: %(default)s)")
    parser.add_argument("--no-view", dest="view", action="store_false", help="do not start the map")
    parser.add_argument("--view-port", type=int, metavar="PORT",
                        help=f"HTTP port of the map while the stack runs (default: {DEMO_VIEW_PORT}, or a free one "
                        "if that is taken)")
    parser.add_argument("--out", type=Path, default=Path("out/demo"),
                        help="folder for recording.mcap, tracks.csv and demo.png (default: %(default)s)")


def final_table(rows: list[TrackRow], last: int = 10) -> list[str]:
    """The last ``last`` rows of the track table as aligned text."""
    lines = [f"{'t [s]':>10} {'track':>5} {'x':>9} {'y':>9} {'vx':>8} {'vy':>8}"]
    for r in rows[-last:]:
        lines.append(f"{fmt(r.t, 3):>10} {r.track:>5} {fmt(r.x, 2):>9} {fmt(r.y, 2):>9} "
                     f"{fmt(r.vx, 2) or '-':>8} {fmt(r.vy, 2) or '-':>8}")
    return lines


def _free_port(preferred: int = 0) -> int:
    """``preferred`` if it is free on 127.0.0.1, else a free port."""
    for port in (preferred, 0):
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return sock.getsockname()[1]
    raise CommandError("no free port on 127.0.0.1")


def _free_endpoint() -> str:
    return f"tcp/127.0.0.1:{_free_port()}"


def run(args: argparse.Namespace) -> int:
    if not (args.dataset / "deployment.json").exists():
        raise CommandError(f"no dataset at {args.dataset} (run `make datasets`, or pass --dataset DIR)")
    dataset = open_dataset(args.dataset)
    args.out.mkdir(parents=True, exist_ok=True)
    recording = args.out / "recording.mcap"
    print(f"bintrack demo: {dataset.deployment.name}, {len(dataset.deployment.sensors)} sensors, "
          f"tracker {args.tracker}, live stack at speed {args.speed:g} (0 = as fast as it keeps up)")
    # up's own parser, so that every option of up has its default here too
    parser = argparse.ArgumentParser(prog="bintrack up")
    up.add_arguments(parser)
    stack = parser.parse_args([str(args.dataset), "--tracker", args.tracker, "--speed", repr(args.speed),
                               "--record", str(recording), "--exit-at-end", "--listen", _free_endpoint(),
                               "--view-port", str(args.view_port or _free_port(DEMO_VIEW_PORT)),
                               *(() if args.view else ("--no-view",))])
    status = up.run(stack)
    if status != 0:
        return status
    rows = track_rows(open_recording(recording), "tracks")
    tracks_path = args.out / "tracks.csv"
    write_tracks(tracks_path, rows)
    print(f"\nfinal track table ({len(rows)} rows in {tracks_path}; last {min(10, len(rows))} shown):")
    print("\n".join(final_table(rows)))
    evaluation = evaluate(dataset, tracks_path)
    print("\nmetrics against truth.csv:")
    print("\n".join(evaluation.lines()))
    png = plot_evaluation(args.out / "demo.png", dataset, evaluation)
    print(f"\nrecording: {recording}\nplot: {png}")
    return 0
