"""The regions' merged tracks beside one base station over the whole field (DESIGN §9), over seeds.

    python benchmarks/region_merge.py [--seeds 20-29] [--regions 2x2]

For each seed, ``bintrack simulate darpa-grid --regions 2x2`` (3 people crossing region borders;
kept in ``--cache``), then offline with the objects the services run: mcmcda over the whole
field, mcmcda per region merged (``bintrack track --regions``), and — the noise floor of the
comparison — the whole field again with another mcmcda seed, and the whole field less the four
sensors nearest its corners, unplugged (what a small change of the data alone does). Per seed
and as mean ± standard deviation: scans with the same count of tracks, share of paired tracks
within 0.5 m, the largest gap, identity switches (a whole-field track, kept under one identity,
paired with another merged identity than at its previous scan: an identity lost at a border),
identities split (a whole-field track paired with more than one merged identity over the run,
which also counts the whole-field tracker's own changes of identity) and joined. The merge's defaults
(gate 5 m, hand-over 5 s, reach 8 m) and the band (two sensing ranges; ``--band`` to try
others) were chosen on seeds 10–13; report on others.
"""

from __future__ import annotations

import argparse
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


def compare(folder: Path, band: float | None = None) -> dict[str, dict]:
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
    plugged = without_corners(deployment)
    cornerless = list(output_rows(run_tracker(dataset, make_tracker("mcmcda", plugged, TrackerOptions()),
                                              sensors={s.id for s in plugged.sensors})))
    out = {}
    for label, rows in (("regions merged", merged), ("whole, another seed", again),
                        ("whole, less its 4 corner sensors", cornerless)):
        a = agreement(whole, rows)
        out[label] = {"same count": a.count_equal / a.scans, "within 0.5 m": a.within(0.5), "max gap": a.max_gap,
                      "switches": a.switches, "split": len(a.split), "joined": len(a.joined)}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=seeds, default=seeds("20-29"), metavar="A-B")
    parser.add_argument("--regions", default="2x2")
    parser.add_argument("--cache", default=str(REPO / "benchmarks" / ".cache"))
    parser.add_argument("--band", type=float, metavar="D", help="width of the border band whose sensors a region "
                        "takes too, units (as basestation --band; default: two of each sensor's sensing ranges)")
    args = parser.parse_args(argv)
    results = []
    for seed in args.seeds:
        folder = Path(args.cache) / f"regions-{args.regions}-{seed}"
        if not (folder / "events.csv").exists():
            subprocess.run([sys.executable, "-m", "bintrack.cli", "simulate", "darpa-grid", "--regions", args.regions,
                            "--seed", str(seed), "--out", str(folder)], check=True, capture_output=True)
        result = compare(folder, args.band)
        results.append(result)
        print(f"seed {seed}: " + "; ".join(f"{label}: " + ", ".join(f"{k} {v:.3g}" for k, v in r.items())
                                           for label, r in result.items()), flush=True)
    print()
    print(f"| {len(results)} seeds ({args.regions} regions) | same count at a scan | paired within 0.5 m | max gap, m "
          "| identity switches | split | joined |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for label in results[0]:
        cells = []
        for key in ("same count", "within 0.5 m", "max gap", "switches", "split", "joined"):
            values = [r[label][key] for r in results]
            sd = statistics.stdev(values) if len(values) > 1 else 0.0
            pct = key in ("same count", "within 0.5 m")
            cells.append(f"{100 * statistics.mean(values):.1f} ± {100 * sd:.1f} %" if pct
                         else f"{statistics.mean(values):.2f} ± {sd:.2f}")
        print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
