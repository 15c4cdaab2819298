"""Paper 001 Figs. 14–18 and §5.3's message count: the arc tracker beside the four baselines.

Setting (paper 001 §5.2–§5.4): 800 nodes uniform on 800 × 800, R = 40 … 150, target speed R/15
units/s, trajectories in the central 650 × 650 square (``uniform-800``). Prints, beside the
paper's figures:

1. Fig. 14 — ideal model, linear trajectory: location error / R (mean ± 95 % CI) of the arc
   tracker and the baselines (equal, distance, duration weight, line fit; given the speed R/15)
   on the same runs, and the ratio best baseline / arc at each R;
2. Fig. 15 — imperfect model (R_in = 0.9 R), detection law eq. 25 (linear) and eq. 26
   (exponential): the same;
3. §5.4 (Figs. 16–17) — R = 40, linear path, constant speed R/15 (scenario 1) or sudden speed
   changes to multiples of R/15 (scenario 2, ``--trajectory speed-changes``), ideal and
   imperfect (eq. 25) model: mean and max |v_est − v_true| of the arc tracker's rows that carry
   a velocity;
4. §5.3, eq. 27 — the transitions (= broadcast messages) in events.csv for a random trajectory
   of the same length D at R = 40 and R = 150 (same seeds, so the same node layout), beside
   4RρD with ρ = 800 / 800².

and writes two plots (Figs. 14–15 and Figs. 16–17).

Run: ``.venv/bin/python benchmarks/paper001_figures.py [--runs 10] [--velocity-runs 10]
[--message-runs 20] [--jobs 2]``
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from bintrack.evaluation.metrics import mean_ci

RANGES = (40, 60, 80, 100, 120, 150)
TRACKERS = ("arc", "equal-weight", "distance-weight", "duration-weight", "line-fit")
BASELINE_NAMES = TRACKERS[1:]
# (model, law) of Fig. 14 (ideal) and Fig. 15 (imperfect, eq. 25 and eq. 26)
MODELS = (("ideal", None), ("imperfect", "linear"), ("imperfect", "exponential"))
MODEL_LABELS = {("ideal", None): "Fig. 14 — ideal model",
                ("imperfect", "linear"): "Fig. 15 — imperfect model, eq. 25 (linear law)",
                ("imperfect", "exponential"): "Fig. 15 — imperfect model, eq. 26 (exponential law)"}
# paper 001 Table I, ideal row (the arc tracker on the linear trajectory), error / R
PAPER_ARC_TABLE_I = {40: 0.061681, 60: 0.027515, 80: 0.017458, 100: 0.011750, 120: 0.009465, 150: 0.007501}
# §5.3.2 in words: best baseline / arc
PAPER_RATIO = {
    "ideal": {40: "nearly 3", 150: "slightly < 7"},
    "imperfect": {40: "> 3"},
}
PAPER_RATIO_DEFAULT = {"ideal": "3 … 7", "imperfect": "> 2"}
# §5.4: (mean, max) |v_est − v_true|, units/s
PAPER_VELOCITY = {("ideal", "linear"): (0.0764, 0.2842), ("ideal", "speed-changes"): (2.6295, 6.8021),
                  ("imperfect", "linear"): (0.1210, 0.3713), ("imperfect", "speed-changes"): (3.6283, 11.5240)}
VELOCITY_R = 40.0
SCENARIO_LABELS = {"linear": "scenario 1: constant speed R/15", "speed-changes": "scenario 2: speed changes"}
# §5.3: messages for the same random trajectory at R = 40 and R = 150
PAPER_MESSAGES = {40: 474, 150: 1759}
MESSAGE_RANGES = (40, 150)
NODES, SIDE = 800, 800.0
RHO = NODES / SIDE**2
CENTRAL_SIDE = 650.0  # the default path length of a linear crossing of the central square


def _dataset(tmp: str, **options):
    from bintrack.formats import open_dataset, write_dataset
    from bintrack.sim.scenarios import simulate

    result = simulate("uniform-800", **options)
    return open_dataset(write_dataset(Path(tmp) / "d", *result))


def location_job(job):
    """One run of Fig. 14/15: location error / R of every tracker on the same dataset."""
    from bintrack.evaluation.eval_report import evaluate
    from bintrack.formats import write_tracks
    from bintrack.pipeline import output_rows, run_tracker
    from bintrack.trackers import TrackerOptions, make_tracker

    _, model, law, sensing_range, seed = job
    values = {}
    with tempfile.TemporaryDirectory() as tmp:
        dataset = _dataset(tmp, seed=seed, sensing_range=float(sensing_range), trajectory="linear", model=model,
                           law=law)
        for name in TRACKERS:
            speed = None if name == "arc" else sensing_range / 15.0
            tracks = dataset.path / f"{name}.csv"
            write_tracks(tracks, output_rows(run_tracker(dataset, make_tracker(name, dataset.deployment, TrackerOptions(speed=speed)))))
            values[name] = float(evaluate(dataset, tracks).value("location_error_over_R_mean"))
    return job, values


def velocity_job(job):
    """One run of §5.4: the arc tracker's |v_est − v_true| and, for the plot, its speed series."""
    from bintrack.evaluation.metrics import truth_paths, velocity_errors
    from bintrack.pipeline import output_rows, run_tracker
    from bintrack.trackers import make_tracker

    _, model, law, trajectory, seed = job
    with tempfile.TemporaryDirectory() as tmp:
        dataset = _dataset(tmp, seed=seed, sensing_range=VELOCITY_R, trajectory=trajectory, model=model, law=law)
        rows = list(output_rows(run_tracker(dataset, make_tracker("arc", dataset.deployment))))
        (path,) = truth_paths(dataset.truth()).values()
    errors = velocity_errors(rows, path)
    rows = [r for r in rows if r.vx is not None and r.vy is not None and path.exists(r.t)]
    t = np.array([r.t for r in rows])
    v_est = np.array([math.hypot(r.vx, r.vy) for r in rows])
    true_speed = np.hypot(*np.diff(path.xy, axis=0).T) / np.diff(path.t)
    return job, errors, (t, v_est, path.t, true_speed)


def message_job(job):
    """One run of §5.3: transitions in events.csv for a random path of length ``distance``."""
    from bintrack.evaluation.metrics import truth_paths
    from bintrack.sim.scenarios import simulate
    from bintrack.transition_detector import TransitionDetector

    _, distance, sensing_range, seed = job
    speed = sensing_range / 15.0
    deployment, events, truth = simulate("uniform-800", seed=seed, sensing_range=float(sensing_range),
                                         trajectory="random", speed=speed, duration=distance / speed)
    detector = TransitionDetector(deployment)
    times = [e.t for e in events if detector.update(e) is not None]
    (path,) = truth_paths(truth).values()
    inner = sum(path.start < t < path.end for t in times)
    # eq. 27 counts crossings of full circles; near the field's edge part of the circle of
    # radius R about the target holds no sensors: the expected count is 4Rρ ∫ f ds, f the
    # fraction of that circle inside the field (Crofton: crossings per unit length = 2ρ·|arc|/π).
    steps = max(2, int(math.ceil(path.length)))
    xy = path.position(np.linspace(path.start, path.end, steps + 1))
    mid = (xy[1:] + xy[:-1]) / 2
    ds = np.hypot(*np.diff(xy, axis=0).T)
    angles = np.linspace(0.0, 2 * math.pi, 360, endpoint=False)
    cx = mid[:, :1] + sensing_range * np.cos(angles)
    cy = mid[:, 1:] + sensing_range * np.sin(angles)
    inside = ((cx >= 0) & (cx <= SIDE) & (cy >= 0) & (cy <= SIDE)).mean(axis=1)
    expected = 4 * sensing_range * RHO * float((inside * ds).sum())
    return job, (len(times), inner, path.length, expected)




def _cost(job) -> float:
    """Rough relative run time, to start the long jobs first."""
    if job[0] == "loc":
        return job[3] ** 2.5
    if job[0] == "vel":
        return 40.0**2.5 * 3
    return job[2] * job[1] / 100


def run(runs: int, velocity_runs: int, message_runs: int, distances: list[float], jobs: int,
        plot: Path | None, velocity_plot: Path | None) -> int:
    work = [("loc", m, law, r, s) for m, law in MODELS for r in RANGES for s in range(runs)]
    work += [("vel", m, law, tr, s) for m, law in (("ideal", None), ("imperfect", "linear"))
             for tr in ("linear", "speed-changes") for s in range(velocity_runs)]
    work += [("msg", d, r, s) for d in distances for r in MESSAGE_RANGES for s in range(message_runs)]
    work.sort(key=_cost, reverse=True)
    functions = {"loc": location_job, "vel": velocity_job, "msg": message_job}
    location: dict[tuple, dict[str, list[float]]] = {}
    velocity: dict[tuple, list[np.ndarray]] = {}
    series: dict[tuple, tuple] = {}
    messages: dict[tuple, list[tuple[int, int, float]]] = {}
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(functions[job[0]], job) for job in work]
        for done, future in enumerate(as_completed(futures), start=1):
            job, *out = future.result()
            if job[0] == "loc":
                cell = location.setdefault(job[1:4], {name: [] for name in TRACKERS})
                for name, value in out[0].items():
                    cell[name].append(value)
            elif job[0] == "vel":
                velocity.setdefault(job[1:4], []).append(out[0])
                if job[4] == 0:
                    series[job[1:4]] = out[1]
            else:
                messages.setdefault(job[1:3], []).append(out[0])
            if done % 10 == 0 or done == len(work):
                print(f"\r{done}/{len(work)} runs ({time.monotonic() - started:.0f} s)", end="", file=sys.stderr,
                      flush=True)
    print(file=sys.stderr)
    elapsed = time.monotonic() - started

    for model, law in MODELS:
        _location_table(model, law, location, runs)
    _velocity_table(velocity, velocity_runs)
    _message_table(messages, distances, message_runs)
    print(f"\nwall time {elapsed:.0f} s with {jobs} worker processes")
    if plot is not None:
        _plot_location(location, plot)
        print(f"plot: {plot}")
    if velocity_plot is not None:
        _plot_velocity(series, velocity_plot)
        print(f"plot: {velocity_plot}")
    return 0


def _location_table(model, law, location, runs) -> None:
    print(f"\n{MODEL_LABELS[(model, law)]}, linear trajectory: location error / R, mean ± 95 % CI over {runs} runs "
          "(the same runs for every tracker)")
    header = (f"{'R':>4} | " + " | ".join(f"{n:>17}" for n in TRACKERS)
              + f" | {'best baseline':>15} | {'best/arc':>8} | {'paper best/arc':>14}"
              + (f" | {'paper arc (T. I)':>16}" if model == "ideal" else ""))
    print(header)
    print("-" * len(header))
    for r in RANGES:
        cell = location[(model, law, r)]
        means = {name: mean_ci(cell[name]) for name in TRACKERS}
        best = min(BASELINE_NAMES, key=lambda n: means[n][0])
        paper = PAPER_RATIO[model].get(r, PAPER_RATIO_DEFAULT[model])
        print(f"{r:>4} | " + " | ".join(f"{m:.4f} ± {h:.4f}".rjust(17) for m, h in means.values())
              + f" | {best:>15} | {means[best][0] / means['arc'][0]:>8.2f} | {paper:>14}"
              + (f" | {PAPER_ARC_TABLE_I[r]:>16.4f}" if model == "ideal" else ""))


def _velocity_table(velocity, runs) -> None:
    print(f"\n§5.4 velocity, arc tracker, R = {VELOCITY_R:g}, linear path: |v_est − v_true| (units/s) over "
          f"{runs} runs")
    header = (f"{'model':>22} | {'scenario':>32} | {'rows':>5} | {'mean':>6} | {'median':>6} | {'p95':>6} | {'max, run 0':>10} | "
              f"{'max, median run':>15} | {'max, all runs':>13} | {'paper mean / max':>16}")
    print(header)
    print("-" * len(header))
    for model, law in (("ideal", None), ("imperfect", "linear")):
        for trajectory in ("linear", "speed-changes"):
            per_run = velocity[(model, law, trajectory)]
            pooled = np.concatenate(per_run)
            run_max = [float(e.max()) for e in per_run if e.size]
            paper = PAPER_VELOCITY[(model, trajectory)]
            label = model if law is None else f"{model} (eq. 25)"
            print(f"{label:>22} | {SCENARIO_LABELS[trajectory]:>32} | {pooled.size:>5} | {pooled.mean():>6.4f} | "
                  f"{np.median(pooled):>6.4f} | {np.percentile(pooled, 95):>6.4f} | {per_run[0].max():>10.4f} | {np.median(run_max):>15.4f} | "
                  f"{pooled.max():>13.4f} | {paper[0]:>7.4f} / {paper[1]:.4f}")


def _message_table(messages, distances, runs) -> None:
    print(f"\n§5.3 messages (transitions in events.csv), random trajectory of length D, same seeds at both R, "
          f"{runs} runs, ρ = {NODES}/{SIDE:g}²")
    print("'all' counts every transition, including the reports of the sensors covering the target when it "
          "appears (t = t_entry) and disappears (t = t_exit); 'crossings' only those in between; '4RρD, field edge' "
          "is eq. 27 with the part of each circle outside the 800 × 800 field (no sensors there) left out")
    header = (f"{'D':>7} | {'R':>4} | {'path length':>11} | {'all':>15} | {'crossings':>15} | {'4RρD':>7} | "
              f"{'crossings/4RρD':>14} | {'4RρD, field edge':>16} | {'paper':>5}")
    print(header)
    print("-" * len(header))
    for distance in distances:
        means = {}
        for r in MESSAGE_RANGES:
            rows = messages[(distance, r)]
            total, inner, length, expected = (np.array(c, dtype=float) for c in zip(*rows))
            (mt, ht), (mi, hi) = mean_ci(total), mean_ci(inner)
            means[r] = (mt, mi)
            print(f"{distance:>7.0f} | {r:>4} | {length.mean():>11.1f} | {mt:>7.1f} ± {ht:>5.1f} | "
                  f"{mi:>7.1f} ± {hi:>5.1f} | {4 * r * RHO * distance:>7.1f} | {mi / (4 * r * RHO * distance):>14.3f} | "
                  f"{expected.mean():>16.1f} | {PAPER_MESSAGES[r]:>5}")
        print(f"{'':>7}   ratio R=150 / R=40: all {means[150][0] / means[40][0]:.3f}, crossings "
              f"{means[150][1] / means[40][1]:.3f}; paper {PAPER_MESSAGES[150] / PAPER_MESSAGES[40]:.3f}; "
              f"150/40 = {150 / 40:.3f}")


def _plot_location(location, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8), layout="constrained", sharey=True)
    for ax, (model, law) in zip(axes, MODELS):
        for name, colour in zip(TRACKERS, ("k", "C0", "C1", "C2", "C3")):
            mci = [mean_ci(location[(model, law, r)][name]) for r in RANGES]
            ax.errorbar(RANGES, [m for m, _ in mci], yerr=[h for _, h in mci], color=colour, marker="o", capsize=3,
                        linewidth=2 if name == "arc" else 1, label=name if name != "arc" else "arc (ours)")
        if model == "ideal":
            ax.plot(RANGES, [PAPER_ARC_TABLE_I[r] for r in RANGES], "k--", marker="s", alpha=0.5,
                    label="arc, paper Table I")
        ax.set_title(MODEL_LABELS[(model, law)], fontsize="medium")
        ax.set_xlabel("sensing range R (R_out), units")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="x-small")
    axes[0].set_ylabel("location error / R (mean ± 95 % CI)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


def _plot_velocity(series, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 7), layout="constrained")
    for row, (model, law) in enumerate((("ideal", None), ("imperfect", "linear"))):
        for col, trajectory in enumerate(("linear", "speed-changes")):
            ax = axes[row][col]
            t, v_est, t_true, v_true = series[(model, law, trajectory)]
            ax.step(t_true, np.append(v_true, v_true[-1]), where="post", color="k", label="real speed")
            ax.plot(t, v_est, ".", markersize=3, color="C3", label="estimated speed (arc tracker)")
            ax.set_title(f"{'ideal' if law is None else 'imperfect, eq. 25'}: {SCENARIO_LABELS[trajectory]} (seed 0)",
                         fontsize="medium")
            ax.set_xlabel("time (s)")
            ax.set_ylabel("speed (units/s)")
            ax.set_ylim(bottom=0)
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize="small")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


def default_distances() -> list[float]:
    """One side of the central square, and the D at which eq. 27 gives the paper's 474 at R = 40."""
    return [CENTRAL_SIDE, round(PAPER_MESSAGES[40] / (4 * 40 * RHO))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="runs (seeds) per R and model, Figs. 14–15 (default: %(default)s)")
    parser.add_argument("--velocity-runs", type=int, default=10, help="runs per §5.4 scenario (default: %(default)s)")
    parser.add_argument("--message-runs", type=int, default=20, help="runs per R for the message count (default: %(default)s)")
    parser.add_argument("--distance", type=float, action="append",
                        help="path length D of the message runs, units; repeatable (default: 650 — one side of the "
                             "central square — and the D at which eq. 27 gives the paper's 474 at R = 40)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--plot", type=Path, default=Path("docs/paper001_fig14_15.png"), help="PNG for Figs. 14–15")
    parser.add_argument("--velocity-plot", type=Path, default=Path("docs/paper001_velocity.png"),
                        help="PNG for Figs. 16–17")
    args = parser.parse_args()
    distances = args.distance or default_distances()
    return run(args.runs, args.velocity_runs, args.message_runs, distances, args.jobs, args.plot, args.velocity_plot)


if __name__ == "__main__":
    sys.exit(main())
