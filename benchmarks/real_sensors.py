"""Real ceiling-PIR sensors (issue: real sensors): the whole chain on the two public sequences of
the recording of Milan, Roth, Schindler and Kudo, *Privacy Preserving Multi-target Tracking*
(ACCV 2014 workshops): 43 PIR sensors at 2 Hz, up to six people, hand-annotated positions.

    .venv/bin/python benchmarks/real_sensors.py [--data ../shared/realdata/irtracking] [--out docs] [--seeds N] [--floor-plan PLAN.json]

For each sequence, with the command line a user would type:

1. ``bintrack import`` the sample matrix, the sensor table and the CVML truth (stated footprint
   0.7 m, the only prior);
2. ``bintrack calibrate`` a copy *without* truth.csv (the detections alone), and the original
   with ``--supervised`` for comparison: the median over sensors of |calibrated − supervised| /
   supervised per parameter;
3. ``bintrack track --tracker mcmcda`` on the calibrated dataset (seeds 0..N−1: the MAP moves
   with the sampler's seed), online and with the fixed-lag smoother (``--lag 6``, 3 s), and
   ``bintrack eval --gospa-c 2 --area 0,0,8,14`` (CLEAR MOT with a 1.5 m hit threshold and
   greedy matching, as the authors score it).

Beside them, in the same run: the stated footprint alone (0.7 m, no pd/pfa, no calibration) and
the sensor model guessed from the truth before this work (range 1.5 m, pd 0.5, pfa 0.03), both
tracked with today's defaults; and the authors' published figures (their offline tracker, tuned
on these sequences). Settings of the real-PIR tracker were chosen on r1-easy; r1-medium is the
sequence reported. Writes ``--out``/real_r1_medium.png and real_r1_medium_lag.png (r1-medium:
truth and tracks, online and with the lag; seed 0).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SEQUENCES = ("r1-easy", "r1-medium")
AUTHORS = {"r1-easy": {"mota": 0.575, "motp": 0.538, "count": None},
           "r1-medium": {"mota": 0.529, "motp": 0.569, "count": None}}
AUTHORS_COUNT_ERROR = 0.76  # their mean over the three real sequences
EVAL = ["--gospa-c", "2", "--area", "0,0,8,14"]
LAG = ("--lag", "6")  # the fixed lag chosen on the selection sets (benchmarks/real_pir_choices.py): 3 s


def bintrack(*args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "bintrack.cli", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"bintrack {' '.join(args)} failed: {done.stderr.strip()}")
    return done.stdout


def import_sequence(data: Path, name: str, out: Path, *extra: str) -> Path:
    bintrack("import", str(data / f"{name}.txt"), "--sensors", str(data / "sensors.csv"), "--out", str(out),
             "--period", "0.5", "--columns", "1-43", "--header-lines", "1", "--region", "0,0,8.6,14",
             "--truth", str(data / f"{name}_gt.xml"), "--truth-scale", "25", "--truth-units", "mm", "--name", name, *extra)
    return out


def scores(dataset: Path, seed: int = 0, plot: Path | None = None, *options: str) -> dict:
    tracks = dataset / f"tracks-{seed}{''.join(options)}.csv"
    bintrack("track", str(dataset), "--tracker", "mcmcda", "--seed", str(seed), *options, "--out", str(tracks), "--no-progress")
    extra = ["--plot", str(plot)] if plot else []
    return json.loads(bintrack("eval", str(dataset), str(tracks), *EVAL, "--json", *extra).splitlines()[0])


def calibrated_blind(work: Path, imported: Path, name: str) -> Path:
    """``imported`` calibrated from a copy without truth.csv (the detections alone), truth.csv put
    back after the fit, for scoring only."""
    blind = work / f"{name}-blind"
    blind.mkdir()
    for f in ("deployment.json", "events.csv"):
        shutil.copyfile(imported / f, blind / f)
    fitted = work / f"{name}-calibrated"
    bintrack("calibrate", str(blind), "--out", str(fitted))
    shutil.copyfile(imported / "truth.csv", fitted / "truth.csv")
    return fitted


def stated_and_calibrated(data: Path, name: str, work: Path) -> Path:
    """``name`` imported with the hardware's stated footprint (0.7 m) as the only prior, then
    calibrated from its detections alone (:func:`calibrated_blind`)."""
    return calibrated_blind(work, import_sequence(data, name, work / f"{name}-imported", "--range", "0.7"), name)


def calibrated(work: Path, imported: Path, name: str) -> tuple[Path, dict]:
    fitted = calibrated_blind(work, imported, name)
    supervised = work / f"{name}-supervised"
    bintrack("calibrate", str(imported), "--out", str(supervised), "--supervised")
    a = {s["id"]: s for s in json.loads((fitted / "deployment.json").read_text())["sensors"]}
    b = {s["id"]: s for s in json.loads((supervised / "deployment.json").read_text())["sensors"]}
    agreement = {}
    for key in ("range", "pd", "pfa", "hold"):
        if key in ("range", "pd"):  # relative: median over sensors of |cal - sup| / sup
            diff = statistics.median(abs(a[i][key] - b[i][key]) / b[i][key] for i in a)
        else:  # pfa near 0 and hold often 0: absolute, median over sensors of |cal - sup|
            diff = statistics.median(abs(a[i][key] - b[i][key]) for i in a)
        agreement[key] = (diff, statistics.median(s[key] for s in a.values()), statistics.median(s[key] for s in b.values()))
    return fitted, agreement


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "irtracking")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--floor-plan", type=Path, metavar="PLAN.json",
                        help="import the room's floor plan too (e.g. benchmarks/irtracking_floor_plan.json; the plots "
                        "are then written as real_r1_medium_plan.png and real_r1_medium_lag_plan.png)")
    args = parser.parse_args()
    if not (args.data / "r1-easy.txt").exists():
        print(f"skipped: the recording is not in {args.data}")
        return 0
    from bench_support import say

    rows = []
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in SEQUENCES:
            say(f"real_sensors: {name}: importing it and calibrating it from the detections alone")
            plan = ("--floor-plan", str(args.floor_plan)) if args.floor_plan else ()
            stated = import_sequence(args.data, name, work / f"{name}-stated", "--range", "0.7", *plan)
            guessed = import_sequence(args.data, name, work / f"{name}-guessed", "--range", "1.5", "--pd", "0.5", "--pfa", "0.03",
                                      *plan)
            fitted, agreement = calibrated(work, stated, name)
            suffix = "_plan" if plan else ""
            plots = {(): args.out / f"real_r1_medium{suffix}.png", LAG: args.out / f"real_r1_medium_lag{suffix}.png"} \
                if name == "r1-medium" else {}
            runs = {(): [], LAG: []}
            for seed in range(args.seeds):
                for options in runs:
                    runs[options].append(scores(fitted, seed, plots.get(options) if seed == 0 else None, *options))
                say(f"  [{time.perf_counter() - started:6.0f} s] {name}: tracked and scored mcmcda seed {seed}, online and with {' '.join(LAG)}")
            rows.append((name, scores(stated), scores(guessed), runs, agreement))
    print("Real ceiling PIR (Milan et al. ACCV 2014 workshops), CLEAR MOT at 1.5 m (greedy), area [0,8]x[0,14] m, GOSPA c = 2 m")
    print("settings chosen on r1-easy; r1-medium is the sequence reported"
          + (f"; every run with the floor plan {args.floor_plan}" if args.floor_plan else "") + "\n")
    head = f"{'sequence':<10} {'run':<50} {'MOTA':>7} {'MOTP':>6} {'IDF1':>6} {'count err':>9} {'GOSPA':>6} {'FP':>4} {'FN':>4} {'IDSW':>4}"
    print(head)
    for name, stated, guessed, runs, _ in rows:
        def line(label, d):
            def v(key, width, digits=3):
                x = d.get(key)
                return f"{'n/a':>{width}}" if x is None else (f"{x:>{width}}" if isinstance(x, int) else f"{x:>{width}.{digits}f}")
            print(f"{name:<10} {label:<50} {v('mota', 7)} {v('motp', 6)} {v('idf1', 6)} {v('target_count_error_mean', 9)} "
                  f"{v('gospa_mean', 6)} {v('false_positives', 4)} {v('misses', 4)} {v('mismatches', 4)}")
        line("stated footprint 0.7 m, no calibration", stated)
        line("model guessed from truth (1.5 m, pd .5, pfa .03)", guessed)
        for options, seeds in runs.items():
            kind = f"{' '.join(options)}, " if options else "online, "
            for seed, d in enumerate(seeds):
                line(f"calibrated, {kind}mcmcda seed {seed}", d)
            for key, label in (("mota", "MOTA"), ("motp", "MOTP"), ("idf1", "IDF1"), ("target_count_error_mean", "count error"),
                               ("gospa_mean", "GOSPA"), ("gospa_localisation_mean", "GOSPA² localisation part"),
                               ("gospa_missed_mean", "GOSPA² missed part"), ("gospa_false_mean", "GOSPA² false part"),
                               ("misses", "FN"), ("false_positives", "FP"), ("mismatches", "IDSW")):
                values = [d[key] for d in seeds]
                spread = statistics.stdev(values) if len(values) > 1 else 0.0
                print(f"{name:<10}   calibrated, {kind}{label} over {len(seeds)} seeds: mean {statistics.mean(values):.3f} "
                      f"(sd {spread:.3f}), range {min(values):.3f}-{max(values):.3f}")
        a = AUTHORS[name]
        print(f"{name:<10} {'authors (offline, tuned on these sequences)':<50} {a['mota']:>7.3f} {a['motp']:>6.3f} {'':>6} "
              f"{AUTHORS_COUNT_ERROR:>9.2f}  (count error: their mean over three sequences)")
    print("\ncalibrated (detections alone) vs supervised (truth), sensor by sensor: median over sensors of |cal - sup| / sup "
          "(range, pd) or |cal - sup| (pfa, hold s), and the medians")
    for name, *_, agreement in rows:
        for key, (diff, med_a, med_b) in agreement.items():
            kind = "relative" if key in ("range", "pd") else "absolute"
            print(f"{name:<10} {key:<6} {kind} difference {diff:<10.4g} calibrated median {med_a:.4g}, supervised median {med_b:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
