"""How long ``bintrack calibrate`` takes on large fields of PIR sensors, beside a baseline revision.

    .venv/bin/python benchmarks/calibrate_speed.py [--grids 10,20] [--runs 3] [--baseline REV]

For each grid G: ``bintrack simulate darpa-grid --grid G --period 0.5 --duration 300 --people
G/3 --pd 0.8 --pfa 0.002`` (G² sensors sampled at 2 Hz for 5 minutes), its deployment and
events copied without truth.csv, then ``bintrack calibrate`` with the default bootstrap (100
resamples) timed by the wall clock, ``--runs`` times. With ``--baseline REV`` the same command of
that revision (checked out in a temporary git worktree, run with its ``shared/`` first on the
path) is timed in turns with this tree's, run for run, and printed beside it: median seconds,
the ratio baseline / this tree, and whether the two wrote the same deployment.json byte for byte.
The machine should be otherwise idle: the figures are wall-clock seconds.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_support import REPO, say


def simulate(folder: Path, grid: int) -> Path:
    """The blind dataset (deployment and events, no truth) of a G × G field, in ``folder``."""
    full, blind = folder / f"grid{grid}", folder / f"grid{grid}-blind"
    subprocess.run([sys.executable, "-m", "bintrack.cli", "simulate", "darpa-grid", "--grid", str(grid), "--period", "0.5",
                    "--duration", "300", "--people", str(max(1, grid // 3)), "--pd", "0.8", "--pfa", "0.002",
                    "--seed", "0", "--out", str(full)], check=True, capture_output=True)
    blind.mkdir()
    for name in ("deployment.json", "events.csv"):
        shutil.copyfile(full / name, blind / name)
    return blind


def timed(shared: Path, dataset: Path, out: Path) -> float:
    """Wall seconds of ``bintrack calibrate dataset --out out`` with ``shared`` first on the path."""
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(shared)}
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "bintrack.cli", "calibrate", str(dataset), "--out", str(out)],
                   check=True, capture_output=True, env=env)
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", default="10,20", help="grid sizes G (G² sensors), comma-separated (default 10,20)")
    parser.add_argument("--runs", type=int, default=3, help="timed runs of each (default 3)")
    parser.add_argument("--baseline", metavar="REV", help="a git revision to time beside this tree")
    args = parser.parse_args()
    try:
        grids = [int(g) for g in args.grids.split(",")]
    except ValueError:
        parser.error(f"--grids: not comma-separated whole numbers: {args.grids!r}")
    if args.baseline and subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", "-q", f"{args.baseline}^{{commit}}"],
                                        capture_output=True).returncode:
        parser.error(f"--baseline: no such revision in {REPO}: {args.baseline}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        trees = {"this tree": REPO / "shared"}
        if args.baseline:
            worktree = work / "baseline"
            subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(worktree), args.baseline], check=True)
            trees = {f"baseline {args.baseline}": worktree / "shared", **trees}
        try:
            rows = []
            for grid in grids:
                say(f"grid {grid}: simulating {grid * grid} sensors …")
                dataset = simulate(work, grid)
                seconds = {name: [] for name in trees}
                outs = {name: work / f"fit-{grid}-{k}" for k, name in enumerate(trees)}
                for run in range(args.runs):
                    for name, shared in trees.items():
                        say(f"grid {grid}: {name}, run {run + 1} of {args.runs} …")
                        seconds[name].append(timed(shared, dataset, outs[name]))
                fits = {(out / "deployment.json").read_bytes() for out in outs.values()}
                rows.append((grid, {name: statistics.median(s) for name, s in seconds.items()}, len(fits) == 1))
        finally:
            if args.baseline:
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(worktree)], check=False)
    names = list(trees)
    print(f"bintrack calibrate, 5 minutes at 2 Hz, 100 bootstrap resamples; median wall seconds of {args.runs} runs")
    print(f"{'sensors':>8} " + " ".join(f"{name:>22}" for name in names)
          + (f" {'ratio':>7} {'same fit':>9}" if len(names) == 2 else ""))
    for grid, median, same in rows:
        line = f"{grid * grid:>8} " + " ".join(f"{median[name]:>22.1f}" for name in names)
        if len(names) == 2:
            line += f" {median[names[0]] / median[names[1]]:>6.2f}x {'yes' if same else 'NO':>9}"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
