"""Paper 001 §5.5 with the paper's settings: accuracy of the arc tracker's trajectory estimate.

Setting (paper 001 §5.2, §5.5): 800 nodes uniform on 800 × 800, R = 40, target speed R/15
units/s, linear / circular / random-turn trajectories in the central 650 × 650 square; ideal
disks, and the imperfect model with R_out = R, R_in = 0.9 R and the first (linear) detection
law; 10 runs (seeds 0–9) per cell. The arc tracker's estimates (``x, y, weight`` with weight eq.
2 or 4, in time order) are turned into a trajectory by
:func:`bintrack.trackers.arc.trajectory_fit.trajectory_from_estimates` with k = 30, n = 6, ε = 0.2 (§3.2.4 as
amended in that module's docstring).

Accuracy (§5.5): the area (units²) of the polygon formed by the estimated and the real
trajectory, divided by the length (units) of the real trajectory over the same time span (first
to last estimate). The area counts the regions the closed ring estimated + reversed(real)
winds around (non-zero winding number, whatever its sign: a crossing of the two paths does not
cancel area). :func:`bintrack.evaluation.metrics.area_between` counts every bounded face of that ring
instead, which for a circular trajectory of one full turn includes the disk inside the circle
whenever the estimate's ends overlap; its figure is printed too.

Estimates stamped at the instant the simulated target appears or vanishes (the simulation
switching every covering sensor at once: not boundary crossings) are left out; their number is
printed. Also printed, for reference: the figure of the raw polyline through the estimates.

Run: ``.venv/bin/python benchmarks/paper001_trajectory.py [--runs 10] [--jobs 2] [--plot docs/paper001_trajectory.png]``
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import shapely

from bintrack.evaluation.metrics import mean_ci

SENSING_RANGE = 40.0
TRAJECTORIES = ("linear", "circular", "random")
MODELS = ("ideal", "imperfect")
MODEL_LABELS = {"ideal": "ideal", "imperfect": "imperfect (R_in = 0.9 R, linear law)"}
# paper 001 §5.5: average accuracy (area / length) at 800 nodes, R = 40
PAPER = {
    "ideal": {"linear": 0.187, "circular": 1.227, "random": 1.704},
    "imperfect": {"linear": 0.287, "circular": 1.811, "random": 2.873},
}
K, N, EPS = 30, 6, 0.2  # paper 001 §5.5
LIFE_TOLERANCE = 1e-6  # s


def winding_number(ring: np.ndarray, point: np.ndarray) -> int:
    """How many times the closed polyline ``ring`` (units, first point repeated last) winds
    around ``point`` (units), counter-clockwise positive."""
    v = ring - point
    angles = np.arctan2(v[:, 1], v[:, 0])
    return int(round(np.angle(np.exp(1j * np.diff(angles))).sum() / (2 * math.pi)))


def enclosed_area(estimated: np.ndarray, real: np.ndarray) -> float:
    """Area (units²) of the polygon formed by two polylines run in the same direction: the
    faces of the ring estimated + reversed(real), noded at its self-intersections, around which
    the ring winds (any non-zero winding number counts once)."""
    ring = np.vstack([estimated, np.asarray(real)[::-1], np.asarray(estimated)[:1]])
    if len(ring) < 4:
        return 0.0
    noded = shapely.unary_union(shapely.LineString(ring))
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(noded)))
    area = 0.0
    for face in faces:
        inside = np.array(shapely.point_on_surface(face).coords[0])
        if winding_number(ring, inside) != 0:
            area += float(face.area)
    return area


def one_run(job: tuple[str, str, int]) -> dict:
    """Simulate one run, track it with ``arc``, fit the trajectory; figures and the data to plot."""
    from bintrack.formats import open_dataset, write_dataset
    from bintrack.bus_payloads import LocalEstimate
    from bintrack.evaluation.metrics import area_between, polyline_length, truth_paths
    from bintrack.pipeline import run_tracker
    from bintrack.sim.scenarios import simulate
    from bintrack.trackers import make_tracker
    from bintrack.trackers.arc.trajectory_fit import trajectory_from_estimates

    trajectory, model, seed = job
    options = {"law": "linear"} if model == "imperfect" else {}
    result = simulate("uniform-800", seed=seed, sensing_range=SENSING_RANGE, trajectory=trajectory, model=model,
                      **options)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = open_dataset(write_dataset(Path(tmp) / "d", *result))
        estimates = [e for e in run_tracker(dataset, make_tracker("arc", dataset.deployment))
                     if isinstance(e, LocalEstimate)]
        (path,) = truth_paths(dataset.truth()).values()
    estimates.sort(key=lambda e: e.t)
    inside = [e for e in estimates if path.start + LIFE_TOLERANCE < e.t < path.end - LIFE_TOLERANCE]
    if any(e.weight is None or not (e.weight > 0 and math.isfinite(e.weight)) for e in inside):
        raise ValueError(f"{job}: the arc tracker gave an estimate without a positive finite weight")
    xy = np.array([(e.x, e.y) for e in inside], dtype=float)
    weights = np.array([e.weight for e in inside], dtype=float)
    fitted = trajectory_from_estimates(xy, weights, k=K, n=N, eps=EPS)
    real = path.between(inside[0].t, inside[-1].t)
    length = polyline_length(real)
    return {
        "cell": (trajectory, model), "seed": seed,
        "fitted": enclosed_area(fitted, real) / length,
        "fitted_area_between": area_between(fitted, real) / length,
        "raw": enclosed_area(xy, real) / length,
        "segments": len(fitted) - 1, "estimates": len(inside), "dropped": len(estimates) - len(inside),
        "xy": xy, "polyline": fitted, "truth": path.between(path.start, path.end),
    }




def run(runs: int, jobs: int, plot: Path | None) -> int:
    work = [(trajectory, model, seed) for model in MODELS for trajectory in TRAJECTORIES for seed in range(runs)]
    results: dict[tuple[str, str], list[dict]] = {}
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for done, outcome in enumerate(pool.map(one_run, work), start=1):
            results.setdefault(outcome["cell"], []).append(outcome)
            print(f"\r{done}/{len(work)} runs ({time.monotonic() - started:.0f} s)", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)

    print(f"\nPaper 001 §5.5 — trajectory accuracy (area / length), 800 nodes, R = {SENSING_RANGE:g}, "
          f"k = {K}, n = {N}, ε = {EPS}; mean ± 95 % CI over {runs} runs (seeds 0–{runs - 1})")
    header = f"{'model':10} {'row':34}" + "".join(f"{t:>18}" for t in TRAJECTORIES)
    print(header)
    for model in MODELS:
        cells = {t: results[(t, model)] for t in TRAJECTORIES}
        rows = [
            ("paper", {t: f"{PAPER[model][t]:.3f}" for t in TRAJECTORIES}),
            ("ours, fitted trajectory", {t: "{:.3f} ± {:.3f}".format(*mean_ci([r["fitted"] for r in cells[t]]))
                                         for t in TRAJECTORIES}),
            ("ours, raw polyline of estimates", {t: "{:.3f} ± {:.3f}".format(*mean_ci([r["raw"] for r in cells[t]]))
                                                 for t in TRAJECTORIES}),
            ("ours, fitted, metrics.area_between", {t: "{:.3f} ± {:.3f}".format(
                *mean_ci([r["fitted_area_between"] for r in cells[t]])) for t in TRAJECTORIES}),
            ("segments per run (mean, min–max)", {t: "{:.1f} ({}–{})".format(
                np.mean([r["segments"] for r in cells[t]]), min(r["segments"] for r in cells[t]),
                max(r["segments"] for r in cells[t])) for t in TRAJECTORIES}),
            ("estimates per run (mean)", {t: f"{np.mean([r['estimates'] for r in cells[t]]):.0f}"
                                          for t in TRAJECTORIES}),
            ("estimates left out (total)", {t: f"{sum(r['dropped'] for r in cells[t])}" for t in TRAJECTORIES}),
        ]
        for label, values in rows:
            print(f"{model:10} {label:34}" + "".join(f"{values[t]:>18}" for t in TRAJECTORIES))
    if plot is not None:
        _plot(results, plot)
        print(f"\nplot: {plot}")
    return 0


def _typical(cell_results: list[dict]) -> dict:
    """The run whose fitted-trajectory figure is the median of its cell (the lower middle one)."""
    ordered = sorted(cell_results, key=lambda r: r["fitted"])
    return ordered[(len(ordered) - 1) // 2]


def _plot(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(MODELS), len(TRAJECTORIES), figsize=(15, 10.5))
    for row, model in enumerate(MODELS):
        for col, trajectory in enumerate(TRAJECTORIES):
            ax = axes[row][col]
            r = _typical(results[(trajectory, model)])
            ax.plot(*r["truth"].T, "-", color="black", lw=2.5, label="real trajectory")
            ax.plot(*r["xy"].T, ".", color="tab:gray", ms=4, label="location estimates")
            ax.plot(*r["polyline"].T, "-o", color="tab:red", lw=1.3, ms=3.5, label="estimated trajectory")
            ax.plot(*r["truth"][0], ">", color="black", ms=8)
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{trajectory}, {model} (seed {r['seed']}): area/length {r['fitted']:.3f} "
                         f"(paper {PAPER[model][trajectory]:.3f})", fontsize=9)
            ax.tick_params(labelsize=8)
    fig.suptitle(f"Paper 001 Figs. 19–20 setting: 800 nodes, R = {SENSING_RANGE:g}, k = {K}, n = {N}, ε = {EPS}; "
                 "typical (median) run per cell; top ideal, bottom imperfect (R_in = 0.9 R, linear law)", fontsize=10)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10, help="runs (seeds 0…runs−1) per cell")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--plot", type=Path, default=Path("docs/paper001_trajectory.png"), help="PNG to write")
    parser.add_argument("--no-plot", action="store_true", help="write no PNG")
    args = parser.parse_args(argv)
    return run(args.runs, args.jobs, None if args.no_plot else args.plot)


if __name__ == "__main__":
    sys.exit(main())
