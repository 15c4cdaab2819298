"""``bintrack demo``: the README's main job.

Tracks the shipped DARPA-style 3-person dataset, prints the final track table and the metrics,
and writes a PNG of sensors, detections, tracks and truth. Until the live system lands it runs
the offline pipeline (the same tracker objects the services will run).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .errors import CommandError
from .evaluation import evaluate
from .formats import TrackRow, fmt, open_dataset, write_tracks
from .pipeline import output_rows, run_tracker
from .plotting import plot_evaluation
from .progress import Progress
from .trackers import TRACKER_NAMES, make_tracker

SHIPPED_DATASET = Path(__file__).resolve().parents[2] / "datasets" / "darpa-grid-3"
# The best tracker available for this dataset; paper 001 §5.3.2 finds equal weight the best baseline.
DEMO_TRACKER = "equal-weight"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", type=Path, default=SHIPPED_DATASET,
                        help="dataset folder (default: the shipped darpa-grid-3)")
    parser.add_argument("--tracker", choices=TRACKER_NAMES, default=DEMO_TRACKER, help="tracker (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("out/demo"),
                        help="folder for tracks.csv and demo.png (default: %(default)s)")


def final_table(rows: list[TrackRow], last: int = 10) -> list[str]:
    """The last ``last`` rows of the track table as aligned text."""
    lines = [f"{'t [s]':>10} {'track':>5} {'x':>9} {'y':>9} {'vx':>8} {'vy':>8}"]
    for r in rows[-last:]:
        lines.append(f"{fmt(r.t, 3):>10} {r.track:>5} {fmt(r.x, 2):>9} {fmt(r.y, 2):>9} "
                     f"{fmt(r.vx, 2) or '-':>8} {fmt(r.vy, 2) or '-':>8}")
    return lines


def run(args: argparse.Namespace) -> int:
    if not (args.dataset / "deployment.json").exists():
        raise CommandError(f"no dataset at {args.dataset} (run `make datasets`, or pass --dataset DIR)")
    dataset = open_dataset(args.dataset)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"bintrack demo: {dataset.deployment.name}, {len(dataset.deployment.sensors)} sensors, "
          f"tracker {args.tracker} (offline pipeline)")
    tracker = make_tracker(args.tracker, dataset.deployment)
    progress = Progress("events", enabled=None)
    rows = list(output_rows(run_tracker(dataset, tracker, on_event=progress.update)))
    progress.close()
    tracks_path = args.out / "tracks.csv"
    write_tracks(tracks_path, rows)
    print(f"\nfinal track table ({len(rows)} rows in {tracks_path}; last {min(10, len(rows))} shown):")
    print("\n".join(final_table(rows)))
    evaluation = evaluate(dataset, tracks_path)
    print("\nmetrics against truth.csv:")
    print("\n".join(evaluation.lines()))
    png = plot_evaluation(args.out / "demo.png", dataset, evaluation)
    print(f"\nplot: {png}")
    return 0
