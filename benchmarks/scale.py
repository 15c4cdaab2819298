"""How the region base stations scale: a field of 10 000 sensors and 100 people cut into 1, 4 and
16 regions (DESIGN §9, several machines).

    python benchmarks/scale.py [--grid 100] [--people 100] [--regions 1,4,16] [--window 10]

The field is simulated by ``bintrack simulate darpa-grid --grid 100 --people 100 --entry-gap 0.1
--dead 0`` (kept in ``--cache``). For each cut, every region's base-station tracker (mcmcda on
its sensors plus the border band, the objects ``basestation --region`` runs) is fed the
transitions of an event-time window in the middle of the run, when people are spread over the
field, one region after the other, and timed in CPU seconds (``time.process_time``: what a
machine of its own would spend, not the wall clock of this shared machine). Printed side by side
with the one-region baseline:

* event time per CPU second, per region (min/median/max) — a region runs in real time on a
  machine of its own when its figure is ≥ 1;
* in total on this one machine: the window over the sum of the regions' CPU time;
* messages per event second through each region's router (mean over the regions), counted from
  the window's transitions as the mesh routes them: the transitions its sensor agent publishes,
  those its base station needs (its sensors and the band: what it is delivered since design
  §11), those it was delivered before (every transition of the network, when each service held
  one subscription to its whole network, ``bintrack/<net>/**``, to keep each publisher's
  order), and the results it publishes (``region/<r>/{tracks,fusion/reports}`` per scan, plus a
  progress per clock tick).

and a plot (``--plot``).
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench_support import REPO
from bintrack.formats import open_dataset
from bintrack.bus_payloads import PositionReports, TrackSet
from bintrack.pipeline import TrackerDriver
from bintrack.regions import RegionMap, grid_areas, grid_shape
from bintrack.trackers import TrackerOptions, make_tracker
from bintrack.transition_detector import TransitionDetector


def simulate(folder: Path, grid: int, people: int, seed: int) -> Path:
    if not (folder / "events.csv").exists():
        print(f"simulating {grid * grid} sensors and {people} people into {folder} …", file=sys.stderr, flush=True)
        subprocess.run([sys.executable, "-m", "bintrack.cli", "simulate", "darpa-grid", "--grid", str(grid),
                        "--people", str(people), "--entry-gap", "0.1", "--dead", "0", "--seed", str(seed),
                        "--out", str(folder)], check=True)
    return folder


def window_transitions(dataset, start: float, end: float) -> list:
    """The transitions with start ≤ t < end (the detector runs from the beginning)."""
    detector = TransitionDetector(dataset.deployment)
    out = []
    for event in dataset.events():
        if event.t >= end:
            break
        transition = detector.update(event)
        if transition is not None and transition.t >= start:
            out.append(transition)
    return out


def run_region(part, transitions, taken: set[str], lateness: float = 2.0, tick: float = 0.5) -> dict:
    """One region's tracker over the window, advanced every clock tick like the live base
    station; CPU seconds and what it published."""
    tracker = make_tracker("mcmcda", part, TrackerOptions())
    driver = TrackerDriver(tracker)
    mine = [tr for tr in transitions if tr.sensor in taken]
    published = 0
    began = time.process_time()
    next_tick = math.floor(mine[0].t / tick) * tick + tick if mine else 0.0
    for tr in mine:
        while tr.t >= next_tick:
            published += sum(isinstance(o, (TrackSet, PositionReports)) for o in driver.advance(next_tick - lateness))
            next_tick += tick
        driver.push(tr)
    published += sum(isinstance(o, (TrackSet, PositionReports)) for o in driver.finish())
    return {"cpu": time.process_time() - began, "taken": len(mine), "published": published}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=100, help="nodes per side (default: %(default)s → 10 000)")
    parser.add_argument("--people", type=int, default=100)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--regions", default="1,4,16", help="region counts to compare (default: %(default)s)")
    parser.add_argument("--window", type=float, default=10.0, help="event-time window, s (default: %(default)s)")
    parser.add_argument("--start", type=float, help="window start, s (default: the middle of the run)")
    parser.add_argument("--cache", default=str(REPO / "benchmarks" / ".cache"), help="where the dataset is kept")
    parser.add_argument("--plot", default=str(REPO / "docs" / "scale.png"), help="PNG to write ('' for none)")
    args = parser.parse_args(argv)
    folder = simulate(Path(args.cache) / f"scale-{args.grid}-{args.people}-{args.seed}", args.grid, args.people,
                      args.seed)
    dataset = open_dataset(folder)
    deployment = dataset.deployment
    if args.start is None:
        args.start = math.floor(max(row.t for row in dataset.truth()) / 2)
    transitions = window_transitions(dataset, args.start, args.start + args.window)
    span = args.window
    print(f"{len(deployment.sensors)} sensors, {args.people} people; window t = {args.start:g}–{args.start + span:g} s: "
          f"{len(transitions)} transitions ({len(transitions) / span:.0f}/s)")
    rows = []
    for count in (int(n) for n in args.regions.split(",")):
        areas = grid_areas(deployment.region, *grid_shape(count))
        regions = RegionMap(deployment.model_copy(update={"regions": areas}))
        per = []
        for name in regions.names:
            part = regions.sub_deployment(name)
            taken = {s.id for s in part.sensors}
            own = set(regions.own_sensors(name))
            result = run_region(part, transitions, taken)
            result["own"] = sum(tr.sensor in own for tr in transitions)
            per.append(result)
            print(f"  {count:2d} regions, {name}: {len(taken)} sensors, {result['cpu']:.1f} CPU s, "
                  f"{span / result['cpu']:.2f} event-s per CPU-s", file=sys.stderr, flush=True)
        rates = [span / r["cpu"] for r in per]
        rows.append({
            "regions": count, "min": min(rates), "median": statistics.median(rates), "max": max(rates),
            "total": span / sum(r["cpu"] for r in per),
            "in": statistics.mean(r["own"] for r in per) / span,
            "needed": statistics.mean(r["taken"] for r in per) / span,
            "out": statistics.mean(r["published"] for r in per) / span + 1 / 0.5,
            "delivered": len(transitions) / span,
        })
    base = rows[0]
    print()
    print("| regions | event-s per CPU-s, per region: min / median / max | × baseline (min) | all regions on one "
          "core | per router, msgs per event-s: in / needed / delivered with ** (before §11) / results out |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        print(f"| {row['regions']} | {row['min']:.2f} / {row['median']:.2f} / {row['max']:.2f} | "
              f"{row['min'] / base['min']:.1f} | {row['total']:.2f} | "
              f"{row['in']:.0f} / {row['needed']:.0f} / {row['delivered']:.0f} / {row['out']:.0f} |")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        counts = [r["regions"] for r in rows]
        fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
        left.plot(counts, [r["median"] for r in rows], "o-", label="per region (median)")
        left.fill_between(counts, [r["min"] for r in rows], [r["max"] for r in rows], alpha=0.2, label="min–max")
        left.plot(counts, [r["total"] for r in rows], "s--", label="all regions on one core")
        left.axhline(1.0, color="grey", lw=0.8, ls=":", label="real time")
        left.set_xscale("log", base=2)
        left.set_yscale("log")
        left.set_xlabel("regions")
        left.set_ylabel("event s per CPU s")
        left.legend(fontsize=8)
        right.plot(counts, [r["in"] for r in rows], "o-", label="published in (own sensors)")
        right.plot(counts, [r["needed"] for r in rows], "s-", label="needed (sensors + band)")
        right.plot(counts, [r["delivered"] for r in rows], "x:", label="delivered with ** (whole network, before §11)")
        right.plot(counts, [r["out"] for r in rows], "^-", label="results out")
        right.set_xscale("log", base=2)
        right.set_yscale("log")
        right.set_xlabel("regions")
        right.set_ylabel("messages per event s, per region router")
        right.legend(fontsize=8)
        fig.suptitle(f"{len(deployment.sensors)} sensors, {args.people} people, window {span:g} s")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"\nplot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
