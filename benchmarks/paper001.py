"""Paper 001 Tables I–III with the paper's settings: the arc tracker's location error / R.

Setting (paper 001 §5.2, §5.6): 800 nodes uniform on 800 × 800, ideal disks, R = 40 … 150,
target speed R/15 units/s, trajectories (linear, circular, random turns) confined to the
central 650 × 650 square; fault models none, packet collision (gap 1e-4 s, abandon within
0.01 s), wrong reports (5 % / 1 %) and both; 10 runs (seeds) per cell, 95 % confidence
intervals. Prints ours beside the paper's value for every cell, and whether ours is within the
paper's value + 15 % (the issue's bar), and writes a plot like the paper's tables. Then,
unless ``--tables-only``, the rest of paper 001's figures with the same settings and seeds:
``paper001_figures.py`` (Figs. 14–15 with the four baselines, §5.4 velocity, §5.3 message
counts) and ``paper001_trajectory.py`` (§5.5 trajectory accuracy); each also runs alone.

Run: ``.venv/bin/python benchmarks/paper001.py [--runs 10] [--jobs 2] [--tables-only]`` (≈ 15 min)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bintrack.evaluation.metrics import mean_ci

RANGES = (40, 60, 80, 100, 120, 150)
TRAJECTORIES = ("linear", "circular", "random")
FAULTS = ("none", "collision", "wrong", "both")
FAULT_LABELS = {"none": "ideal sensing", "collision": "packet collision", "wrong": "wrong report",
                "both": "collision&wrong"}
# paper 001 Tables I (linear), II (circular), III (random): rows by fault model, columns by R
PAPER = {
    "linear": {
        "none": (0.061681, 0.027515, 0.017458, 0.011750, 0.009465, 0.007501),
        "collision": (0.061706, 0.027889, 0.017494, 0.012447, 0.010685, 0.008139),
        "wrong": (0.076377, 0.036045, 0.021637, 0.014421, 0.012025, 0.009898),
        "both": (0.077268, 0.038050, 0.022705, 0.015861, 0.013133, 0.011186),
    },
    "circular": {
        "none": (0.068974, 0.029909, 0.016972, 0.012357, 0.009378, 0.007449),
        "collision": (0.069416, 0.030191, 0.017090, 0.012962, 0.010335, 0.008778),
        "wrong": (0.080432, 0.039182, 0.022370, 0.015434, 0.012599, 0.009409),
        "both": (0.080896, 0.037735, 0.023686, 0.016244, 0.012954, 0.011477),
    },
    "random": {
        "none": (0.062041, 0.029779, 0.016823, 0.011575, 0.009336, 0.007970),
        "collision": (0.064382, 0.032705, 0.017623, 0.012588, 0.010028, 0.008748),
        "wrong": (0.074263, 0.034594, 0.022625, 0.015810, 0.012005, 0.010031),
        "both": (0.080263, 0.035148, 0.023778, 0.016603, 0.012753, 0.011027),
    },
}
MARGIN = 1.15  # ours must be ≤ paper × 1.15


def one_run(job: tuple[str, str, int, int]) -> tuple[tuple[str, str, int], float, list[float]]:
    """Simulate one cell's run; the arc tracker's mean location error / R and its final arcs (rad)."""
    from bintrack.evaluation.eval_report import evaluate
    from bintrack.formats import open_dataset, write_dataset, write_tracks
    from bintrack.pipeline import output_rows, run_tracker
    from bintrack.sim.scenarios import simulate
    from bintrack.trackers import make_tracker

    trajectory, faults, sensing_range, seed = job
    result = simulate("uniform-800", seed=seed, sensing_range=float(sensing_range), trajectory=trajectory,
                      faults=faults)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_dataset(Path(tmp) / "d", *result)
        dataset = open_dataset(folder)
        tracks = folder / "arc.csv"
        estimates = list(run_tracker(dataset, make_tracker("arc", dataset.deployment)))
        write_tracks(tracks, output_rows(estimates))
        value = evaluate(dataset, tracks).value("location_error_over_R_mean")
    return (trajectory, faults, sensing_range), float(value), [e.arc for e in estimates]




def run(runs: int, jobs: int, plot: Path | None) -> int:
    work = [(tr, f, r, seed) for tr in TRAJECTORIES for f in FAULTS for r in RANGES for seed in range(runs)]
    results: dict[tuple[str, str, int], list[float]] = {}
    arcs: dict[tuple[str, str, int], list[float]] = {}
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for done, (cell, value, cell_arcs) in enumerate(pool.map(one_run, work, chunksize=4), start=1):
            results.setdefault(cell, []).append(value)
            arcs.setdefault(cell, []).extend(cell_arcs)
            if done % 10 == 0 or done == len(work):
                print(f"\r{done}/{len(work)} runs ({time.monotonic() - started:.0f} s)", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)

    within = total = 0
    for table, trajectory in zip(("I", "II", "III"), TRAJECTORIES):
        print(f"\nTable {table} — {trajectory} trajectory: location error / R, paper | ours (mean ± 95 % CI, {runs} runs)")
        print(f"{'':18}" + "".join(f"{'R=' + str(r):>27}" for r in RANGES))
        for faults in FAULTS:
            cells = []
            for k, r in enumerate(RANGES):
                paper = PAPER[trajectory][faults][k]
                ours, half = mean_ci(results[(trajectory, faults, r)])
                ok = ours <= paper * MARGIN
                within += ok
                total += 1
                cells.append(f"{paper:.4f} | {ours:.4f}±{half:.4f}{' ' if ok else '!'}".rjust(27))
            print(f"{FAULT_LABELS[faults]:18}" + "".join(cells))
    print(f"\ncells within the paper's value + 15 %: {within}/{total} ('!' marks the others)")
    section4 = arcs[("random", "none", 40)]
    print(f"§4 simulation at ρR² = 2 (R = 40 here, ≡ 800 nodes on 20 × 20 with R = 1), random, ideal: mean "
          f"combination angle {np.mean(section4):.4f} rad over {len(section4)} estimates, accuracy "
          f"{np.mean(section4) / 2:.4f} rad (paper: 0.270, 0.135; analytic ε 0.155)")
    if plot is not None:
        _plot(results, plot)
        print(f"plot: {plot}")
    return 0


def _plot(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), layout="constrained", sharey=True)
    for ax, trajectory in zip(axes, TRAJECTORIES):
        for faults, colour in zip(FAULTS, ("C0", "C1", "C2", "C3")):
            mci = [mean_ci(results[(trajectory, faults, r)]) for r in RANGES]
            ax.errorbar(RANGES, [m for m, _ in mci], yerr=[h for _, h in mci], color=colour, marker="o", capsize=3,
                        label=f"{FAULT_LABELS[faults]} (ours)")
            ax.plot(RANGES, PAPER[trajectory][faults], color=colour, linestyle="--", marker="s", alpha=0.6,
                    label=f"{FAULT_LABELS[faults]} (paper)")
        ax.set_title(f"{trajectory} trajectory")
        ax.set_xlabel("sensing range R (units)")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("location error / R")
    axes[-1].legend(fontsize="x-small", loc="upper right")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="runs (seeds) per cell (default: %(default)s)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--plot", type=Path, default=Path("docs/paper001_tables.png"), help="PNG to write")
    parser.add_argument("--tables-only", action="store_true", help="only Tables I–III")
    args = parser.parse_args()
    status = run(args.runs, args.jobs, args.plot)
    if status or args.tables_only:
        return status
    import paper001_figures
    import paper001_trajectory

    print("\n" + "=" * 100)
    status = paper001_figures.run(args.runs, args.runs, 20, paper001_figures.default_distances(), args.jobs,
                                  Path("docs/paper001_fig14_15.png"), Path("docs/paper001_velocity.png"))
    print("\n" + "=" * 100)
    return status or paper001_trajectory.run(args.runs, args.jobs, Path("docs/paper001_trajectory.png"))


if __name__ == "__main__":
    sys.exit(main())
