"""Real PIR: does a person who stops keep their track? (issue: real sensors, item 4)

    .venv/bin/python benchmarks/real_pir_stops.py [--data ../shared/realdata/irtracking] [--pause 6 --pause 12] [--still 0.1] [--seeds 1 2 3]

The recording's people keep walking, so stops are simulated: r1-easy is imported and calibrated
from the detections alone (as ``benchmarks/real_pir_choices.py`` does), then every second
annotated person pauses for ``--pause`` s halfway along their path (the rest of it shifted
later), and the people are walked again through the fitted sensors with a PIR that fades to
``--still`` for a still person (``bintrack simulate recording --like``; its trigger chance is
pd·(still + (1 − still)·min(1, v / 0.5 m/s))), simulation seeds 1–3 (``--seeds``; the
settings for people who stand still were chosen with 1–3 in view, so report others). Each set is tracked online
and with ``--lag 6``, and printed per pause: MOTA, count error, GOSPA (as the other real-PIR
benchmarks score), the share of the pauses' scans in which a track lies within 1.5 m of the
still person, and how many of the paused people have the same identity (the track nearest
them, within 2 m) in the 2 s before the pause and the 3 s after it.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from bintrack.evaluation.eval_report import evaluate
from bintrack.formats import open_dataset

PERIOD = 0.5
OPTIONS = {"online": (), "--lag 6": ("--lag", "6")}


def paused_like(fitted: Path, pause: float, still: float, out: Path) -> dict[str, tuple[float, float, float, float]]:
    """``out``: ``fitted`` whose every second person pauses ``pause`` s halfway and whose sensors
    fade to ``still``; returns person → (pause start, end, x, y)."""
    rows = defaultdict(list)
    for r in csv.DictReader((fitted / "truth.csv").open()):
        rows[r["target"]].append(r)
    new, pauses = [], {}
    for i, person in enumerate(sorted(rows, key=lambda k: (len(k), k))):
        path = sorted(rows[person], key=lambda r: float(r["t"]))
        if i % 2 == 0 or len(path) < 8:
            new += path
            continue
        m = len(path) // 2
        t0 = float(path[m]["t"])
        pauses[person] = (t0, t0 + pause, float(path[m]["x"]), float(path[m]["y"]))
        new += path[:m] + [{**path[m], "t": f"{t0 + PERIOD * j:g}"} for j in range(round(pause / PERIOD))]
        new += [{**r, "t": f"{float(r['t']) + pause:g}"} for r in path[m:]]
    out.mkdir()
    deployment = json.loads((fitted / "deployment.json").read_text())
    for sensor in deployment["sensors"]:
        sensor["still"] = still
    (out / "deployment.json").write_text(json.dumps(deployment))
    (out / "events.csv").write_text((fitted / "events.csv").read_text())
    with (out / "truth.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["t", "target", "x", "y"])
        w.writeheader()
        w.writerows(sorted(({k: r[k] for k in ("t", "target", "x", "y")} for r in new), key=lambda r: (float(r["t"]), r["target"])))
    return pauses


def stop_figures(tracks: Path, pauses: dict) -> tuple[int, int, int]:
    """(scans of the pauses with a track within 1.5 m, scans of the pauses, people whose nearest
    track within 2 m before the pause is the one after it)."""
    by_t = defaultdict(list)
    for r in csv.DictReader(tracks.open()):
        by_t[float(r["t"])].append((r["track"], float(r["x"]), float(r["y"])))

    def nearest(t: float, x: float, y: float, reach: float) -> str | None:
        near = [(math.hypot(x - a, y - b), k) for k, a, b in by_t.get(t, []) if math.hypot(x - a, y - b) <= reach]
        return min(near)[1] if near else None

    covered = scans = kept = 0
    for t0, t1, x, y in pauses.values():
        for j in range(round((t1 - t0) / PERIOD)):
            scans += 1
            covered += nearest(t0 + PERIOD * j, x, y, 1.5) is not None
        before = next((k for j in range(1, 5) if (k := nearest(t0 - PERIOD * j, x, y, 2.0))), None)
        after = next((k for j in range(0, 6) if (k := nearest(t1 + PERIOD * j, x, y, 2.0))), None)
        kept += before is not None and before == after
    return covered, scans, kept


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "irtracking")
    parser.add_argument("--pause", type=float, action="append", help="s each paused person stands still (default: 6 and 12)")
    parser.add_argument("--still", type=float, default=0.1, help="a still person's share of a walker's trigger chance (default 0.1)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="simulation seeds (default 1 2 3)")
    args = parser.parse_args()
    if not (args.data / "r1-easy.txt").exists():
        print(f"skipped: the recording is not in {args.data}")
        return 0
    from bench_support import say
    from real_pir_choices import bintrack, calibrate_blind
    from real_sensors import import_sequence

    started = time.perf_counter()
    results = defaultdict(list)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        say("real_pir_stops: importing r1-easy and calibrating it from the detections alone")
        stated = import_sequence(args.data, "r1-easy", work / "stated", "--range", "0.7")
        fitted = calibrate_blind(stated, stated / "events.csv", stated / "truth.csv", work / "r1-easy")
        for pause in args.pause or [6.0, 12.0]:
            like = work / f"pause{pause:g}-like"
            pauses = paused_like(fitted, pause, args.still, like)
            for seed in args.seeds:
                ds = work / f"pause{pause:g}-{seed}"
                bintrack("simulate", "recording", "--like", str(like), "--seed", str(seed), "--out", str(ds))
                for name, options in OPTIONS.items():
                    tracks = ds / f"tracks{''.join(options)}.csv"
                    bintrack("track", str(ds), "--tracker", "mcmcda", *options, "--out", str(tracks), "--no-progress")
                    s = evaluate(open_dataset(ds), tracks, gospa_c=2.0, area=(0, 0, 8, 14)).as_dict()
                    results[(pause, name)].append((s["mota"], s["target_count_error_mean"], s["gospa_mean"],
                                                   *stop_figures(tracks, pauses)))
                say(f"  [{time.perf_counter() - started:5.0f} s] pause {pause:g} s, seed {seed}: tracked online and with --lag 6")
    print(f"People who stop (r1-easy's people, every second one still for the pause, PIR fading to {args.still:g}), "
          f"simulation seeds {' '.join(map(str, args.seeds))}, means")
    print(f"{'pause':>6} {'tracker':<8} {'MOTA':>6} {'count':>6} {'GOSPA':>6} {'pause scans with a track':>25} {'same identity after':>20}")
    for (pause, name), rows in results.items():
        covered, scans, kept = (sum(r[i] for r in rows) for i in (3, 4, 5))
        print(f"{pause:>5g}s {name:<8} {statistics.mean(r[0] for r in rows):>6.3f} {statistics.mean(r[1] for r in rows):>6.3f} "
              f"{statistics.mean(r[2] for r in rows):>6.3f} {covered / scans:>25.2f} {kept:>14d} of {len(rows) * len(pauses):<3d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
