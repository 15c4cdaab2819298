"""Real PIR: the tracker's choices tried on the selection sets only (issue 38, second round).

    .venv/bin/python benchmarks/real_pir_choices.py [--data ../shared/realdata/irtracking] [--seeds N] [--sim-seeds K] [--jobs 2] [--variant NAME]

Never r1-medium (the sequence reported by ``benchmarks/real_sensors.py``). The sets:

* ``r1-easy``: the recording, calibrated from the detections alone, mcmcda seeds 0..N−1;
* ``sim``: r1-easy's annotated people walked again through its fitted sensors (``bintrack
  simulate recording --like``: disk footprints, per-sensor pd and pfa), seeds 1..4;
* ``soft``: the same, but each sensor's footprint soft (paper 001's linear law from 0.6 R to
  1.5 R, R the fitted radius), then calibrated again from the simulated detections alone with
  the stated 0.7 m as the only prior, seeds 1..3 (its firing rate against distance matches the
  real one to 1.5 m);
* ``crowd``/``crowd-soft``: as ``sim``/``soft`` with a denser room: every second person of
  r1-easy walks a second time, mirrored across the room (x → 8.6 − x) and 50 s later (wrapping
  round), 5.1 people on average and up to 7, as crowded as r1-medium is said to be.

Each simulated set is tracked with mcmcda seed 0, or seeds 0..K−1 with ``--sim-seeds K``.

Each variant changes one setting of :mod:`bintrack.trackers.multi.pir_settings`, gives the
tracks a fixed lag (:mod:`bintrack.trackers.multi.fixed_lag`), or gives the deployment the room's
floor plan (``FLOOR_PLANS``); printed per set:
mean MOTA, count error, GOSPA (c = 2 m), FP, FN, identity switches (CLEAR MOT at 1.5 m, greedy,
area [0, 8] × [0, 14] m, as ``benchmarks/real_sensors.py``).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

VARIANTS = {
    "today's settings": ({}, {}),
    "soft count, sigma = R/2": ({"soft_count": 0.5}, {}),
    "soft count, sigma = 0.8 R": ({"soft_count": 0.8}, {}),
    "no shared reports": ({"shared": False}, {}),
    "published from 3 reports (confirmation)": ({}, {"min_reports": 3}),
    "a track's blob never split": ({"expected_split_gain": float("inf")}, {}),
    "new target at 4 nats, not 2": ({"min_gain": 4.0}, {}),
    "birth rate 3e-4 per m2, not 1e-3": ({}, {"birth_rate": 3e-4}),
    "report pd 0.7, not 0.6": ({}, {"pd": 0.7}),
    "q 0.1, not 0.035": ({}, {"process_noise": 0.1}),
    "q 0.5, not 0.035": ({}, {"process_noise": 0.5}),
    "q 0.02 (paper 004's outdoor walkers), not 0.035": ({}, {"process_noise": 0.02}),
    "q 0.03, not 0.035": ({}, {"process_noise": 0.03}),
    "q 0.04, not 0.035": ({}, {"process_noise": 0.04}),
    "window 10 scans, not 5": ({}, {"window": 10}),
    "new track speed 1.0 m/s, not 1.5": ({}, {"initial_speed": 1.0}),
    "blob split at 5 nats, not 8": ({"expected_split_gain": 5.0}, {}),
    "track kept 8 missed scans, not 5": ({}, {"max_misses": 8}),
    "entries from one report (1 m, 4 nats)": ({}, {"entry_depth": 1.0, "entry_gain": 4.0}),
    "exits at the walls (1 m)": ({}, {"exit_depth": 1.0}),
    "16 chains, not 8": ({}, {"chains": 16}),
    "32 chains": ({}, {"chains": 32}),
    "1000 iterations per chain, not 500": ({}, {"n_mc": 1000}),
    "16 chains of 1000": ({}, {"chains": 16, "n_mc": 1000}),
    "bars scaled with the sensors' evidence (1.7 nats)": ({"evidence_reference": 1.7}, {}),
    "pd and false-report rate estimated online (50 scans)": ({}, {"adapt_rates": 50}),
    "a new target from one detection (n_d 1, not 2)": ({"threshold": 1}, {}),
    "n_d 1, and a new target at 4 nats, not 2": ({"threshold": 1, "min_gain": 4.0}, {}),
    "a shared copy for a hidden track within 1.5 ranges of the report, not 1": ({"shared_gap": 1.5}, {}),
    "the same within 2 ranges": ({"shared_gap": 2.0}, {}),
    "the same within 3 ranges": ({"shared_gap": 3.0}, {}),
    "shared copies for 4 scans without a report, not 2": ({"shared_unreported": 4}, {}),
    "within 2 ranges, for 4 scans": ({"shared_gap": 2.0, "shared_unreported": 4}, {}),
    "a track shown 1 scan past its last report, not 2": ({}, {"coast": 1}),
    "a track shown 3 scans past its last report, not 2": ({}, {"coast": 3}),
    "soft footprints of 0.4 R for the reports, not R/2": ({"soft_spread": 0.4}, {}),
    "soft footprints of 0.6 R": ({"soft_spread": 0.6}, {}),
    **{f"fixed lag {n} scans ({n / 2:g} s)": ({}, {}, n) for n in (2, 4, 6, 8, 10, 12, 20)},
    "lag 6, births anywhere (not 10 x fewer inside)": ({}, {"birth_inside": 1.0}, 6),
    "lag 6, births inside 0.3 x": ({}, {"birth_inside": 0.3}, 6),
    "lag 6, coast 1": ({}, {"coast": 1}, 6),
    "lag 6, smoothed with the chain's q (0.035, not 0.1)": ({}, {"smooth_noise": 0.035}, 6),
    "lag 6, smoothed with q 0.3": ({}, {"smooth_noise": 0.3}, 6),
    "lag 6, shared copies within 2 ranges": ({"shared_gap": 2.0}, {}, 6),
    "lag 6, blob split at 5 nats": ({"expected_split_gain": 5.0}, {}, 6),
    "no track kept for a person standing still (still_misses 0, not 40)": ({}, {"still_misses": 0}),
    "standing still: prior 0.05, not 0.01": ({}, {"still_prior": 0.05}),
    "standing still up to 12 scans (6 s), not 40": ({}, {"still_misses": 12}),
    "lag 6, no track kept for a person standing still": ({}, {"still_misses": 0}, 6),
    "lag 6, q 0.02, not 0.035": ({}, {"process_noise": 0.02}, 6),
    "targets detected independently (multiplicity)": ({"multiplicity": True}, {}),
    "multiplicity, a track's target kept on 0 nats, not 1": ({"multiplicity": True, "expected_gain": 0.0}, {}),
    "multiplicity, 0 nats, blob split at 6 nats": ({"multiplicity": True, "expected_gain": 0.0, "expected_split_gain": 6.0}, {}),
    "copies only where the scan does not rule the hidden track out (-4 nats)": ({"shared_support": -4.0}, {}),
    "multiplicity, and copies that need evidence (-4 nats)": ({"multiplicity": True, "shared_support": -4.0}, {}),
    "multiplicity, 0 nats, copies that need evidence (-4 nats)": ({"multiplicity": True, "expected_gain": 0.0, "shared_support": -4.0}, {}),
    "multiplicity, a track's blob split at 12 nats, not 8": ({"multiplicity": True, "expected_split_gain": 12.0}, {}),
    "multiplicity, a track's blob never split": ({"multiplicity": True, "expected_split_gain": float("inf")}, {}),
    "multiplicity, 0 nats, blob split at 12 nats": ({"multiplicity": True, "expected_gain": 0.0, "expected_split_gain": 12.0}, {}),
    "multiplicity, a track's target kept on 2 nats, not 1": ({"multiplicity": True, "expected_gain": 2.0}, {}),
    "multiplicity, a track's target kept on 3 nats": ({"multiplicity": True, "expected_gain": 3.0}, {}),
    "re-identified within 16 s, not 8": ({}, {"reidentify": 16.0}),
    "re-identified within 4 s": ({}, {"reidentify": 4.0}),
    "a person shown from their first report up to 2 m inside the field, not 1": ({}, {"entry_depth": 2.0}),
    "the same up to 3 m": ({}, {"entry_depth": 3.0}),
    "the room's floor plan: obstacles and doors": ({}, {}),
    "the floor plan's obstacles only": ({}, {}),
    "the floor plan's doors only": ({}, {}),
    "the doors only, births elsewhere 0.03 x, not 0.1": ({}, {"birth_inside": 0.03}),
    "births 0.03 x farther than 1.5 m from the walls, not 0.1": ({}, {"birth_inside": 0.03}),
    "no count from the firings (before)": ({"count_switch": None}, {}),
    "the count's people from one detection, unchecked": ({"count_soft": None}, {}),
    "the count's people checked with soft footprints of 0.8 R, not 0.9": ({"count_soft": 0.8}, {}),
    "the same with R": ({"count_soft": 1.0}, {}),
    "the same with 1.1 R": ({"count_soft": 1.1}, {}),
    "the same with 1.25 R": ({"count_soft": 1.25}, {}),
    "someone comes or goes 0.005 per scan, not 0.02": ({"count_switch": 0.005}, {}),
    "someone comes or goes 0.05 per scan": ({"count_switch": 0.05}, {}),
}
"""name → (FusionConfig changes, MCMCDAConfig changes[, fixed lag in scans: ``bintrack track --lag``])"""
FLOOR_PLANS = {"the room's floor plan: obstacles and doors": "all", "the floor plan's obstacles only": "obstacles",
               "the floor plan's doors only": "doors",
               "the doors only, births elsewhere 0.03 x, not 0.1": "doors"}
"""variants tracked with the room's floor plan (``FLOOR_PLAN``; a crowd set's mirrored people walk
a room whose obstacles are those of both the room and its mirror image, and its doors both)"""
FLOOR_PLAN = Path(__file__).resolve().with_name("irtracking_floor_plan.json")
"""the room's obstacles and doors, transcribed from the recording's layout drawing (its y axis
pointing down the page; the sensor table's up)"""
ROOM_WIDTH = 8.6  # m: the crowd sets' mirror is x → ROOM_WIDTH − x
KEYS = ("mota", "target_count_error_mean", "gospa_mean", "false_positives", "misses", "mismatches")


def bintrack(*args: str) -> None:
    done = subprocess.run([sys.executable, "-m", "bintrack.cli", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"bintrack {' '.join(args)} failed: {done.stderr.strip()}")


def calibrate_blind(stated: Path, events: Path, truth: Path, out: Path) -> Path:
    blind = out.with_name(out.name + "-blind")
    blind.mkdir()
    shutil.copyfile(stated / "deployment.json", blind / "deployment.json")
    shutil.copyfile(events, blind / "events.csv")
    bintrack("calibrate", str(blind), "--out", str(out))
    shutil.copyfile(truth, out / "truth.csv")
    return out


def crowd_truth(fitted: Path, out: Path) -> Path:
    """``fitted`` with a denser truth.csv (module text)."""
    rows = list(csv.DictReader((fitted / "truth.csv").open()))
    end = max(float(r["t"]) for r in rows)
    ids = sorted({r["target"] for r in rows}, key=lambda k: (len(k), k))
    extra = []
    for r in rows:
        if r["target"] not in ids[::2]:
            continue
        t, tag = float(r["t"]) + 50.0, "m"
        if t > end:
            t, tag = t - end - 0.5, "w"
        extra.append({"t": f"{round(t * 2) / 2:g}", "target": tag + r["target"], "x": f"{ROOM_WIDTH - float(r['x']):.6f}", "y": r["y"]})
    out.mkdir()
    shutil.copyfile(fitted / "deployment.json", out / "deployment.json")
    shutil.copyfile(fitted / "events.csv", out / "events.csv")
    with (out / "truth.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["t", "target", "x", "y"])
        w.writeheader()
        w.writerows(sorted(rows + extra, key=lambda r: (float(r["t"]), r["target"])))
    return out


def mirrored_plan(plan: dict) -> dict:
    """A crowd set's floor plan: the obstacles of both ``plan`` and its mirror image (x → 8.6 − x),
    where neither the people nor their mirrored copies walk, and the doors of both."""
    mirror = [{**a, "xmin": ROOM_WIDTH - a["xmax"], "xmax": ROOM_WIDTH - a["xmin"]} for a in plan["obstacles"]]
    both = []
    for a in plan["obstacles"]:
        for b in mirror:
            box = {"xmin": max(a["xmin"], b["xmin"]), "ymin": max(a["ymin"], b["ymin"]),
                   "xmax": min(a["xmax"], b["xmax"]), "ymax": min(a["ymax"], b["ymax"])}
            if box["xmin"] < box["xmax"] and box["ymin"] < box["ymax"]:
                both.append(box)
    return {"obstacles": both, "doors": plan["doors"] + [[ROOM_WIDTH - x, y] for x, y in plan["doors"]]}


def soft_like(like: Path, out: Path) -> Path:
    """``like`` with each sensor's footprint soft: linear law from 0.6 R to 1.5 R."""
    out.mkdir()
    d = json.loads((like / "deployment.json").read_text())
    for s in d["sensors"]:
        r = s["range"]
        s.update(range_in=round(0.6 * r, 4), range=round(1.5 * r, 4), detection_law="linear")
    (out / "deployment.json").write_text(json.dumps(d))
    for f in ("events.csv", "truth.csv"):
        shutil.copyfile(like / f, out / f)
    return out


def datasets(data: Path, work: Path, seeds: int, sim_seeds: int = 1) -> list[tuple[str, Path, int]]:
    from real_sensors import import_sequence

    stated = import_sequence(data, "r1-easy", work / "stated", "--range", "0.7")
    fitted = calibrate_blind(stated, stated / "events.csv", stated / "truth.csv", work / "r1-easy")
    runs = [("r1-easy", fitted, seed) for seed in range(seeds)]
    plan = json.loads(FLOOR_PLAN.read_text())
    crowd = crowd_truth(fitted, work / "crowd-like")
    for name, like in (("sim", fitted), ("crowd", crowd)):
        for s in range(1, 5 if name == "sim" else 4):
            bintrack("simulate", "recording", "--like", str(like), "--seed", str(s), "--out", str(work / f"{name}{s}"))
            runs.extend((name, work / f"{name}{s}", k) for k in range(sim_seeds))
        soft = soft_like(like, work / f"{name}-soft-like")
        for s in range(1, 4):
            raw = work / f"{name}-soft{s}-raw"
            bintrack("simulate", "recording", "--like", str(soft), "--seed", str(s), "--out", str(raw))
            fit = calibrate_blind(stated, raw / "events.csv", raw / "truth.csv", work / f"{name}-soft{s}")
            runs.extend((f"{name}-soft".replace("sim-", ""), fit, k) for k in range(sim_seeds))
    for name, path, _ in runs:
        (path / "floor_plan.json").write_text(json.dumps(mirrored_plan(plan) if name.startswith("crowd") else plan))
    return runs


def score(variant: str, dataset: Path, seed: int) -> dict:
    from bintrack.deployment_model import FloorPlan
    from bintrack.evaluation.eval_report import evaluate
    from bintrack.formats import open_dataset, write_tracks
    from bintrack.pipeline import output_rows, run_tracker
    from bintrack.trackers.multi.fixed_lag import FixedLagSmoother
    from bintrack.trackers.multi.fusion_config import FusionConfig
    from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
    from bintrack.trackers.multi.pir_settings import pir_settings
    from bintrack.trackers.multi.tracker import MCMCDATracker

    ds = open_dataset(dataset)
    deployment = ds.deployment
    if variant in FLOOR_PLANS:
        plan = FloorPlan.model_validate(json.loads((dataset / "floor_plan.json").read_text()))
        part = FLOOR_PLANS[variant]  # "all", or the one part of the plan kept
        if part != "all":
            plan = plan.model_copy(update={k: [] for k in ("doors", "obstacles") if k != part})
        deployment = deployment.model_copy(update={"floor_plan": plan})
    fusion, config = pir_settings(deployment, FusionConfig(), MCMCDAConfig())
    f, c, *lag = VARIANTS[variant]
    tracker = MCMCDATracker(deployment, fusion=replace(fusion, **f), config=replace(config, seed=seed, **c))
    if lag:
        tracker = FixedLagSmoother(tracker, *lag)
    with tempfile.TemporaryDirectory() as tmp:
        tracks = Path(tmp) / "tracks.csv"
        write_tracks(tracks, output_rows(run_tracker(ds, tracker)))
        figures = evaluate(ds, tracks, gospa_c=2.0, area=(0, 0, 8, 14)).as_dict()
    return {k: figures[k] for k in KEYS}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "irtracking")
    parser.add_argument("--seeds", type=int, default=5, help="mcmcda seeds on r1-easy (default 5)")
    parser.add_argument("--sim-seeds", type=int, default=1, help="mcmcda seeds on each simulated set (default 1)")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--variant", action="append", choices=list(VARIANTS)[1:], metavar="NAME",
                        help="only this variant beside today's settings (repeatable; default: all of them)")
    args = parser.parse_args()
    if not (args.data / "r1-easy.txt").exists():
        print(f"skipped: the recording is not in {args.data}")
        return 0
    from bench_support import say

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        say("real_pir_choices: importing r1-easy, calibrating it and simulating the selection sets")
        runs = datasets(args.data, Path(tmp), args.seeds, args.sim_seeds)
        chosen = [next(iter(VARIANTS)), *args.variant] if args.variant else list(VARIANTS)
        jobs = [(v, name, path, seed) for v in chosen for name, path, seed in runs]
        results = []
        with ProcessPoolExecutor(args.jobs) as pool:
            for done, result in enumerate(pool.map(score, *zip(*[(v, p, s) for v, _, p, s in jobs])), 1):
                results.append(result)
                say(f"  [{time.perf_counter() - started:6.0f} s] tracked and scored: {done}/{len(jobs)}")
    table: dict = defaultdict(lambda: defaultdict(list))
    for (v, name, _, _), r in zip(jobs, results):
        table[v][name].append(r)
    print("Real PIR choices on the selection sets (never r1-medium): means over runs")
    print(f"{'variant':<42} {'set':<11} {'runs':>4} {'MOTA':>6} {'count':>6} {'GOSPA':>6} {'FP':>6} {'FN':>6} {'IDSW':>5}")
    for v, sets in table.items():
        for name, rs in sets.items():
            m = {k: statistics.mean(r[k] for r in rs) for k in KEYS}
            print(f"{v:<42} {name:<11} {len(rs):>4} {m['mota']:>6.3f} {m['target_count_error_mean']:>6.3f} "
                  f"{m['gospa_mean']:>6.3f} {m['false_positives']:>6.1f} {m['misses']:>6.1f} {m['mismatches']:>5.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
