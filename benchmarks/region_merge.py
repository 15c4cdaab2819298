"""The regions' merged tracks beside one base station over the whole field (DESIGN §9), over seeds.

    python benchmarks/region_merge.py [--seeds 20-29] [--regions 2x2]

For each seed, ``bintrack simulate darpa-grid --regions 2x2`` (3 people crossing region borders;
kept in ``--cache``), then offline with the objects the services run: mcmcda over the whole
field, mcmcda per region merged (``bintrack track --regions``), and the noise floors of the
comparison: the whole field again with another mcmcda seed; with every sensor's position moved
by up to 1 cm; with its sensors listed in another order; less the one sensor that never
detected anything, farthest from those that did; and less the four sensors nearest its corners
(what a small change of its input alone does to the whole field's own answer). Per seed
and as mean ± standard deviation: scans with the same count of tracks, share of paired tracks
within 0.5 m, the largest gap, identity switches (a whole-field track, kept under one identity,
paired with another merged identity than at its previous scan: an identity lost at a border;
pairs kept from scan to scan as CLEAR MOT keeps them, and beside them with the pairs decided
afresh at every scan),
identities split (a whole-field track paired with more than one merged identity over the run,
which also counts the whole-field tracker's own changes of identity) and joined. The merge's defaults
(gate 5 m, hand-over 5 s, reach 8 m) and the band (three sensing ranges; ``--band`` to try
others) were chosen on seeds 10–13; report on others.
"""

from __future__ import annotations

import argparse
import random
import statistics
import subprocess
import sys
from pathlib import Path

from bench_support import REPO
from bintrack.evaluation.track_agreement import agreement
from bintrack.formats import open_dataset
from bintrack.pipeline import output_rows, run_regions, run_tracker
from bintrack.regions import RegionMap
from bintrack.trackers import TrackerOptions, make_tracker
from bintrack.trackers.multi.region_merge import RegionMerge


def seeds(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def without_corners(deployment):
    """The deployment less the sensor nearest each corner of the sensors' bounding box: the
    same field with four sensors unplugged, far from most of the walking."""
    xs, ys = [s.x for s in deployment.sensors], [s.y for s in deployment.sensors]
    corners = [(x, y) for x in (min(xs), max(xs)) for y in (min(ys), max(ys))]
    drop = {min(deployment.sensors, key=lambda s: (s.x - x) ** 2 + (s.y - y) ** 2).id for x, y in corners}
    return deployment.model_copy(update={"sensors": [s for s in deployment.sensors if s.id not in drop]})


def moved(deployment, by: float, seed: int):
    """The deployment with each sensor moved by up to ``by`` units along each axis (uniform,
    seeded): far less than any survey of the sensors' positions can promise."""
    rng = random.Random(seed)
    return deployment.model_copy(update={"sensors": [
        s.model_copy(update={"x": s.x + rng.uniform(-by, by), "y": s.y + rng.uniform(-by, by)})
        for s in deployment.sensors]})


def reordered(deployment, seed: int):
    """The deployment with its sensors listed in another (seeded) order: the same field."""
    sensors = list(deployment.sensors)
    random.Random(seed).shuffle(sensors)
    return deployment.model_copy(update={"sensors": sensors})


def without_silent(deployment, dataset):
    """The deployment less one sensor that never detected anything in the dataset: of those,
    the farthest from every sensor that did (None if every sensor detected)."""
    heard = {event.sensor for event in dataset.events()}
    loud = [s for s in deployment.sensors if s.id in heard]
    silent = [s for s in deployment.sensors if s.id not in heard]
    if not silent or not loud:
        return None
    far = max(silent, key=lambda s: min((s.x - t.x) ** 2 + (s.y - t.y) ** 2 for t in loud))
    return deployment.model_copy(update={"sensors": [s for s in deployment.sensors if s.id != far.id]})


def compare(folder: Path, band: float | None = None, seed: int = 0) -> dict[str, dict]:
    dataset = open_dataset(folder)
    deployment = dataset.deployment
    whole = list(output_rows(run_tracker(dataset, make_tracker("mcmcda", deployment, TrackerOptions()))))
    again = list(output_rows(run_tracker(dataset, make_tracker("mcmcda", deployment, TrackerOptions(seed=1)))))
    regions = RegionMap(deployment)
    trackers, taken = {}, {}
    for name in regions.names:
        part = regions.sub_deployment(name, band)
        trackers[name] = make_tracker("mcmcda", part, TrackerOptions())
        taken[name] = {s.id for s in part.sensors}
    merged = list(output_rows(run_regions(dataset, trackers, taken, RegionMerge(regions))))

    def whole_of(changed):
        return list(output_rows(run_tracker(dataset, make_tracker("mcmcda", changed, TrackerOptions()),
                                            sensors={s.id for s in changed.sensors})))

    runs = [("regions merged", merged), ("whole, another seed", again),
            ("whole, sensors moved by up to 1 cm", whole_of(moved(deployment, 0.01 / deployment.metres_per_unit, seed))),
            ("whole, sensors listed in another order", whole_of(reordered(deployment, seed)))]
    silent = without_silent(deployment, dataset)
    if silent is not None:
        runs.append(("whole, less one sensor that never detected", whole_of(silent)))
    runs.append(("whole, less its 4 corner sensors", whole_of(without_corners(deployment))))
    out = {}
    for label, rows in runs:
        a = agreement(whole, rows)
        out[label] = {"same count": a.count_equal / a.scans, "within 0.5 m": a.within(0.5), "max gap": a.max_gap,
                      "switches": a.switches, "switches redecided": a.switches_redecided, "split": len(a.split),
                      "joined": len(a.joined)}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=seeds, default=seeds("20-29"), metavar="A-B")
    parser.add_argument("--regions", default="2x2")
    parser.add_argument("--cache", default=str(REPO / "benchmarks" / ".cache"))
    parser.add_argument("--band", type=float, metavar="D", help="width of the border band whose sensors a region "
                        "takes too, units (as basestation --band; default: three of each sensor's sensing ranges)")
    args = parser.parse_args(argv)
    results = []
    for seed in args.seeds:
        folder = Path(args.cache) / f"regions-{args.regions}-{seed}"
        if not (folder / "events.csv").exists():
            subprocess.run([sys.executable, "-m", "bintrack.cli", "simulate", "darpa-grid", "--regions", args.regions,
                            "--seed", str(seed), "--out", str(folder)], check=True, capture_output=True)
        result = compare(folder, args.band, seed)
        results.append(result)
        print(f"seed {seed}: " + "; ".join(f"{label}: " + ", ".join(f"{k} {v:.3g}" for k, v in r.items())
                                           for label, r in result.items()), flush=True)
    print()
    print(f"| {len(results)} seeds ({args.regions} regions) | same count at a scan | paired within 0.5 m | max gap, m "
          "| identity switches | pairs decided afresh: switches | split | joined |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for label in dict.fromkeys(label for r in results for label in r):
        cells = []
        had = [r[label] for r in results if label in r]
        for key in ("same count", "within 0.5 m", "max gap", "switches", "switches redecided", "split", "joined"):
            values = [h[key] for h in had]
            sd = statistics.stdev(values) if len(values) > 1 else 0.0
            pct = key in ("same count", "within 0.5 m")
            cells.append(f"{100 * statistics.mean(values):.1f} ± {100 * sd:.1f} %" if pct
                         else f"{statistics.mean(values):.2f} ± {sd:.2f}")
        seeds_note = "" if len(had) == len(results) else f" ({len(had)} of the seeds)"
        print(f"| {label}{seeds_note} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
