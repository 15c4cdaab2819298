"""Paper 000 Figs. 7 and 8 with the paper's setting: the sector tracker beside omni and the baselines.

Setting (paper 000 §V.A): 300 nodes uniform on 800 × 800 (``sector-300``), ideal sensing,
R = 50 … 150 in steps of 25, target speed R/15 units/s, linear, circular and random-turn
trajectories in the central 650 × 650 square, 10 runs (seeds) per cell, 95 % confidence
intervals. Each run simulates the same nodes and path three times, with s = 1, 4 and 12
sectors (random offsets), and runs on them:

* **omni** — the arc tracker (paper 001, the paper's "original binary sensing method" [6]) on
  the s = 1 data, and the four baselines of §V.B on the same data (given the speed R/15);
  as in the paper, the best baseline is taken over all four on the linear trajectory and is
  equal weight on the others ("(2)–(4) are restricted to the linear trajectory");
* **4-sector** and **12-sector** — the sector tracker on the s = 4 and s = 12 data (with
  ``--radial``, beyond the paper, also with ``radial=True``: estimates at changes of sector too).

Prints, per trajectory, Fig. 7 (location error / R, mean ± 95 % CI) side by side with the
ratios the paper states in words (omni / 12-sector "nearly 2", best baseline / 12-sector "≈ 8 at
R = 50 … ≈ 16 for dense networks", 4-sector better than omni everywhere); Fig. 8 (the ratio of
the increase in messages to the increase in accuracy for 1→4, 4→12 and 1→12 sectors); and the
sector tracker's processing time per message for s = 4 and s = 12 with the neighbour lists
built beforehand (the deployment stage), beside the time of that neighbour-sector match.
Writes ``docs/paper000_fig7.png``, ``docs/paper000_fig8.png`` and ``docs/paper000_timing.png``.

Run: ``nice -n 5 .venv/bin/python benchmarks/paper000.py [--runs 10] [--jobs 2] [--quick] [--radial]``
(≈ 10 min on 2 shared cores; ``--quick``: 2 runs at R = 50, 100, 150; ``--radial``: also the
sector tracker with ``radial=True``, ≈ 1.5× the time)
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

from bintrack.evaluation.metrics import mean_ci

RANGES = (50, 75, 100, 125, 150)
QUICK_RANGES = (50, 100, 150)
TRAJECTORIES = ("linear", "circular", "random")
SECTORS = (1, 4, 12)
BASELINES = ("equal-weight", "distance-weight", "duration-weight", "line-fit")
COLUMNS = ("omni", "4-sector", "12-sector", "best baseline")
# Paper 000 §V.C in words (Fig. 7 gives the values only as a plot)
PAPER_OMNI_OVER_12 = 2.0  # "the ratio of accuracy of twelve-sector … to our original … is nearly 2"
PAPER_BASELINE_OVER_12 = {50: "≈ 8", 150: "≈ 16"}  # "grows from nearly 8 (R = 50) to around 16 for dense networks"
STEPS = ((1, 4), (4, 12), (1, 12))
TIMING_R = 100
TIMING_SEEDS = 3


def _tracker(name: str, deployment, speed: float | None = None):
    from bintrack import trackers

    if hasattr(trackers, "TrackerOptions"):
        return trackers.make_tracker(name, deployment, trackers.TrackerOptions(speed=speed))
    return trackers.make_tracker(name, deployment, speed=speed)


def _dataset(tmp: str, trajectory: str, sensing_range: float, sectors: int, seed: int):
    from bintrack.formats import open_dataset, write_dataset
    from bintrack.sim.scenarios import simulate

    result = simulate("sector-300", seed=seed, sensing_range=sensing_range, sectors=sectors, trajectory=trajectory)
    return open_dataset(write_dataset(Path(tmp) / f"s{sectors}", *result))


def _error(dataset, name: str, speed: float | None = None, radial: bool = False) -> float:
    """Mean location error / R of tracker ``name`` (the sector tracker ``radial`` if asked) on ``dataset``."""
    from bintrack.evaluation.eval_report import evaluate
    from bintrack.formats import write_tracks
    from bintrack.pipeline import output_rows, run_tracker
    from bintrack.trackers.arc.sector_tracker import SectorTracker

    tracker = SectorTracker(dataset.deployment, radial=True) if radial else _tracker(name, dataset.deployment, speed)
    tracks = dataset.path / f"{name}{'-radial' if radial else ''}.csv"
    write_tracks(tracks, output_rows(run_tracker(dataset, tracker)))
    return float(evaluate(dataset, tracks).value("location_error_over_R_mean"))


def _messages(dataset) -> int:
    """Messages the nodes broadcast: one per transition (paper 000 §II)."""
    from bintrack.transition_detector import TransitionDetector

    detector = TransitionDetector(dataset.deployment)
    return sum(detector.update(e) is not None for e in dataset.events())


def one_run(job: tuple[str, int, int, bool]) -> tuple[tuple[str, int], dict[str, float], dict[int, int]]:
    """One seed of one (trajectory, R) cell: every column's error / R and the message counts."""
    trajectory, sensing_range, seed, radial = job
    errors, messages = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for sectors in SECTORS:
            dataset = _dataset(tmp, trajectory, float(sensing_range), sectors, seed)
            messages[sectors] = _messages(dataset)
            if sectors == 1:
                errors["omni"] = _error(dataset, "arc")
                for name in BASELINES:
                    errors[name] = _error(dataset, name, sensing_range / 15.0)
            else:
                errors[f"{sectors}-sector"] = _error(dataset, "sector")
                if radial:
                    errors[f"{sectors}-sector radial"] = _error(dataset, "sector", radial=True)
    return (trajectory, sensing_range), errors, messages


def best_baseline(trajectory: str, cell: dict[str, list[float]]) -> tuple[str, list[float]]:
    """The baseline with the lowest mean error: over all four on the linear path, else equal weight."""
    names = BASELINES if trajectory == "linear" else ("equal-weight",)
    name = min(names, key=lambda n: np.mean(cell[n]))
    return name, cell[name]


def fig8_ratios(messages: dict[int, float], errors: dict[int, float], a: int, b: int) -> tuple[float, float]:
    """Fig. 8: (increase in messages) / (increase in accuracy) from a to b sectors, as relative
    increases ((M_b − M_a)/M_a) / ((e_a − e_b)/e_b) and as factors (M_b/M_a) / (e_a/e_b);
    accuracy is 1 / error, so its relative increase is e_a/e_b − 1."""
    message_factor = messages[b] / messages[a]
    accuracy_factor = errors[a] / errors[b]
    relative = (message_factor - 1.0) / (accuracy_factor - 1.0) if accuracy_factor != 1.0 else math.inf
    return relative, message_factor / accuracy_factor


REPEATS = 3  # timed passes per dataset; the fastest counts (the machine is shared)


def _timed_pass(dataset, transitions) -> dict[str, float]:
    """One pass of ``transitions`` through a fresh sector tracker whose neighbour lists for the
    reporting nodes are built first (paper 000 §III.B.2, the deployment stage); times in s."""
    tracker = _tracker("sector", dataset.deployment)
    nodes = sorted({tracker.net.index[tr.sensor] for tr in transitions})
    started = time.perf_counter()
    lists = [tracker.sector_neighbours(i, j) for i in nodes for j in range(tracker.models[i].sectors)]
    match = time.perf_counter() - started
    estimate_step = [0.0]  # inside SectorTracker.estimate: eq. 1 over the list and the midpoint

    def timed(i: int, estimate=tracker.estimate):
        started = time.perf_counter()
        result = estimate(i)
        estimate_step[0] += time.perf_counter() - started
        return result

    tracker.estimate = timed
    estimates, spent = 0, {True: 0.0, False: 0.0}  # the calls that gave estimates / did not
    for call, argument in [*((tracker.update, tr) for tr in transitions), (tracker.flush, math.inf)]:
        started = time.perf_counter()
        made = len(call(argument))
        spent[made > 0] += time.perf_counter() - started
        estimates += made
    return dict(per_message=(spent[True] + spent[False]) / len(transitions),
                estimate_step=estimate_step[0] / max(estimates, 1), per_estimate=spent[True] / max(estimates, 1),
                per_status=spent[False] / max(len(transitions) + 1 - estimates, 1),
                match_per_list=match / len(lists), match_per_node=match / len(nodes),
                list_length=float(np.mean([len(entries) for entries in lists])))


def timing_run(job: tuple[str, int, int]) -> dict:
    """The sector tracker's processing time (s) for s = 4 and 12 on one path (fastest of
    ``REPEATS`` passes, s = 4 and 12 alternating): per message, per estimate (the calls that
    return estimates, over the estimates), in the estimate step alone, per other message (status
    updates only), and the neighbour-sector match per list (one node, one sector) and per node."""
    from bintrack.transition_detector import TransitionDetector

    trajectory, sensing_range, seed = job
    passes: dict[int, list[dict[str, float]]] = {s: [] for s in SECTORS[1:]}
    with tempfile.TemporaryDirectory() as tmp:
        data = {}
        for sectors in SECTORS[1:]:
            dataset = _dataset(tmp, trajectory, float(sensing_range), sectors, seed)
            detector = TransitionDetector(dataset.deployment)
            data[sectors] = dataset, [tr for e in dataset.events() if (tr := detector.update(e)) is not None]
        for _ in range(REPEATS):
            for sectors, (dataset, transitions) in data.items():
                passes[sectors].append(_timed_pass(dataset, transitions))
    return {s: {key: min(p[key] for p in runs) for key in runs[0]} for s, runs in passes.items()}


def run(runs: int, jobs: int, ranges: tuple[int, ...], docs: Path, radial: bool = False) -> int:
    work = [(tr, r, seed, radial) for tr in TRAJECTORIES for r in ranges for seed in range(runs)]
    errors: dict[tuple[str, int], dict[str, list[float]]] = {}
    messages: dict[tuple[str, int], dict[int, list[int]]] = {}
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for done, (cell, values, counts) in enumerate(pool.map(one_run, work), start=1):
            for name, value in values.items():
                errors.setdefault(cell, {}).setdefault(name, []).append(value)
            for s, count in counts.items():
                messages.setdefault(cell, {}).setdefault(s, []).append(count)
            print(f"\r{done}/{len(work)} runs ({time.monotonic() - started:.0f} s)", end="", file=sys.stderr,
                  flush=True)
    print(file=sys.stderr)

    print(f"Paper 000 Fig. 7 — location error / R, mean ± 95 % CI over {runs} runs; 300 nodes on 800 × 800.")
    print("The paper gives Fig. 7 only as a plot; its text states: 12-sector ≈ 2× more accurate than omni, "
          "≈ 8× than the best baseline at R = 50 growing to ≈ 16× in dense networks, 4-sector better than omni.")
    four_better = total = 0
    all_omni_ratio = []
    for trajectory in TRAJECTORIES:
        print(f"\n{trajectory} trajectory")
        print(f"{'R':>5}" + "".join(f"{c:>20}" for c in COLUMNS) + f"{'best is':>17}"
              + f"{'omni/12':>9}{'paper':>7}{'best/12':>9}{'paper':>7}{'omni/4':>8}")
        for r in ranges:
            cell = errors[(trajectory, r)]
            name, best = best_baseline(trajectory, cell)
            columns = [cell["omni"], cell["4-sector"], cell["12-sector"], best]
            text = "".join(f"{m:.4f} ± {h:.4f}".rjust(20) for m, h in map(mean_ci, columns))
            omni, four, twelve = (float(np.mean(c)) for c in columns[:3])
            all_omni_ratio.append(omni / twelve)
            four_better += four < omni
            total += 1
            print(f"{r:>5}{text}{name:>17}{omni / twelve:>9.2f}{PAPER_OMNI_OVER_12:>7.0f}"
                  f"{float(np.mean(best)) / twelve:>9.1f}{PAPER_BASELINE_OVER_12.get(r, ''):>7}{omni / four:>8.2f}")
    print(f"\n4-sector better than omni in {four_better}/{total} cells (paper: all); omni / 12-sector over all cells: "
          f"mean {np.mean(all_omni_ratio):.2f}, range {min(all_omni_ratio):.2f} … {max(all_omni_ratio):.2f} "
          "(paper ≈ 2)")

    if radial:
        _print_radial(errors, ranges)
    fig8 = _print_fig8(errors, messages, ranges)
    mean_t = _print_timing(runs)
    docs.mkdir(parents=True, exist_ok=True)
    _plot_fig7(errors, ranges, docs / "paper000_fig7.png")
    _plot_fig8(fig8, ranges, docs / "paper000_fig8.png")
    _plot_timing(mean_t, docs / "paper000_timing.png")
    print(f"\nplots: {docs / 'paper000_fig7.png'}, {docs / 'paper000_fig8.png'}, {docs / 'paper000_timing.png'}")
    return 0


def _print_radial(errors, ranges) -> None:
    print("\nBeyond the paper: the sector tracker with radial=True, which also estimates at each change to an "
          "adjacent sector (on the boundary radius); error / R over all its estimates")
    print(f"{'trajectory':>11}{'R':>5}{'4-sector radial':>20}{'12-sector radial':>20}{'omni/12r':>10}{'omni/4r':>9}")
    for trajectory in TRAJECTORIES:
        for r in ranges:
            cell = errors[(trajectory, r)]
            omni = float(np.mean(cell["omni"]))
            columns = [cell["4-sector radial"], cell["12-sector radial"]]
            text = "".join(f"{m:.4f} ± {h:.4f}".rjust(20) for m, h in map(mean_ci, columns))
            print(f"{trajectory:>11}{r:>5}{text}{omni / np.mean(columns[1]):>10.2f}{omni / np.mean(columns[0]):>9.2f}")


def _print_fig8(errors, messages, ranges) -> dict[tuple[str, int, int], list[float]]:
    print("\nPaper 000 Fig. 8 — (increase in messages) / (increase in accuracy), accuracy = 1 / error; smaller is "
          "better. 'rel' = relative increases ((M_b − M_a)/M_a) / ((e_a − e_b)/e_b), 'fac' = factors "
          "(M_b/M_a) / (e_a/e_b). Paper: values only as a plot; 1→4 has its lowest ratio (most benefit) at R = 125.")
    fig8: dict[tuple[str, int, int], list[float]] = {}
    for trajectory in TRAJECTORIES:
        print(f"\n{trajectory} trajectory")
        print(f"{'R':>5}{'messages s=1':>14}{'s=4':>8}{'s=12':>8}"
              + "".join(f"{f'{a}→{b} rel':>11}{'fac':>7}" for a, b in STEPS))
        for r in ranges:
            m = {s: float(np.mean(messages[(trajectory, r)][s])) for s in SECTORS}
            cell = errors[(trajectory, r)]
            e = {1: float(np.mean(cell["omni"])), 4: float(np.mean(cell["4-sector"])),
                 12: float(np.mean(cell["12-sector"]))}
            text = ""
            for a, b in STEPS:
                rel, fac = fig8_ratios(m, e, a, b)
                fig8.setdefault((trajectory, a, b), []).append(rel)
                text += f"{rel:>11.2f}{fac:>7.2f}"
            print(f"{r:>5}{m[1]:>14.1f}{m[4]:>8.1f}{m[12]:>8.1f}{text}")
    return fig8


def _print_timing(runs: int) -> dict[int, dict[str, float]]:
    timing_jobs = [(tr, TIMING_R, seed) for tr in TRAJECTORIES for seed in range(min(TIMING_SEEDS, runs))]
    timings = [timing_run(job) for job in timing_jobs]  # in this process, one at a time: steadier clocks
    print(f"\nSector tracker cost (R = {TIMING_R}, {len(timings)} runs, neighbour lists of the reporting nodes "
          f"built first; the fastest of {REPEATS} passes per run, averaged over the runs)")
    print("estimate step = eq. 1 over the list and the midpoint; per estimate = the whole call that gives an "
          "estimate (with paper 001's velocity update at the node and its neighbours); other = a status update")
    print(f"{'s':>4}{'per message (µs)':>18}{'estimate step (µs)':>20}{'per estimate (µs)':>19}"
          f"{'per other (µs)':>16}{'list length':>13}{'match per list (ms)':>21}{'match per node (ms)':>21}")
    mean_t = {}
    for s in SECTORS[1:]:
        t = {k: float(np.mean([run[s][k] for run in timings])) for k in timings[0][s]}
        mean_t[s] = t
        print(f"{s:>4}{t['per_message'] * 1e6:>18.1f}{t['estimate_step'] * 1e6:>20.1f}{t['per_estimate'] * 1e6:>19.1f}"
              f"{t['per_status'] * 1e6:>16.1f}"
              f"{t['list_length']:>13.1f}"
              f"{t['match_per_list'] * 1e3:>21.2f}{t['match_per_node'] * 1e3:>21.2f}")
    print(f"ratio s=12 / s=4: estimate step {mean_t[12]['estimate_step'] / mean_t[4]['estimate_step']:.2f}, "
          f"per message {mean_t[12]['per_message'] / mean_t[4]['per_message']:.2f}, per estimate "
          f"{mean_t[12]['per_estimate'] / mean_t[4]['per_estimate']:.2f}, neighbour match per node "
          f"{mean_t[12]['match_per_node'] / mean_t[4]['match_per_node']:.2f}")
    return mean_t


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_fig7(errors, ranges, path: Path) -> None:
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), layout="constrained", sharey=True)
    for ax, trajectory in zip(axes, TRAJECTORIES):
        for column, colour, marker in zip(COLUMNS, ("C0", "C1", "C2", "C3"), "osD^"):
            series = []
            for r in ranges:
                cell = errors[(trajectory, r)]
                values = best_baseline(trajectory, cell)[1] if column == "best baseline" else cell[column]
                series.append(mean_ci(values))
            label = column if column != "best baseline" else (
                "best baseline" if trajectory == "linear" else "equal weight")
            ax.errorbar(ranges, [m for m, _ in series], yerr=[h for _, h in series], color=colour, marker=marker,
                        capsize=3, label=label)
        ax.set_title(f"Fig. 7 — {trajectory} trajectory")
        ax.set_xlabel("sensing range R (units)")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small")
    axes[0].set_ylabel("location error / R (mean ± 95 % CI)")
    fig.savefig(path, dpi=110)


def _plot_fig8(fig8, ranges, path: Path) -> None:
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), layout="constrained", sharey=True)
    for ax, trajectory in zip(axes, TRAJECTORIES):
        for (a, b), colour in zip(STEPS, ("C0", "C1", "C2")):
            ax.plot(ranges, fig8[(trajectory, a, b)], color=colour, marker="o", label=f"{a} → {b} sectors")
        ax.set_title(f"Fig. 8 — {trajectory} trajectory")
        ax.set_xlabel("sensing range R (units)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    axes[0].set_ylabel("message increase / accuracy increase (relative)")
    fig.savefig(path, dpi=110)


def _plot_timing(mean_t, path: Path) -> None:
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    x = np.arange(3)
    for offset, s, colour in ((-0.2, 4, "C1"), (0.2, 12, "C2")):
        values = [mean_t[s][key] * 1e6 for key in ("estimate_step", "per_estimate", "per_message")]
        axes[0].bar(x + offset, values, width=0.4, color=colour, label=f"s = {s}")
    axes[0].set_xticks(x, ["estimate step\n(eq. 1 + midpoint)", "per estimate\n(with velocity)",
                           "per message\n(any transition)"])
    axes[0].set_ylabel("µs")
    axes[0].set_title("sector tracker: processing time, lists built")
    axes[0].legend()
    axes[1].bar([f"s = {s}" for s in mean_t], [mean_t[s]["match_per_node"] * 1e3 for s in mean_t],
                color=("C1", "C2"))
    axes[1].set_ylabel("ms")
    axes[1].set_title("neighbour-sector match per node (deployment stage)")
    fig.savefig(path, dpi=110)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=None, help="runs (seeds) per cell (default: 10, --quick: 2)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--quick", action="store_true", help="2 runs at R = 50, 100, 150")
    parser.add_argument("--radial", action="store_true",
                        help="also run the sector tracker with estimates at changes of sector (beyond the paper)")
    parser.add_argument("--docs", type=Path, default=Path("docs"), help="folder for the PNGs (default: %(default)s)")
    parser.add_argument("--timing-only", action="store_true", help="only the per-message timing and its plot")
    args = parser.parse_args()
    runs = args.runs if args.runs is not None else (2 if args.quick else 10)
    if args.timing_only:
        args.docs.mkdir(parents=True, exist_ok=True)
        _plot_timing(_print_timing(runs), args.docs / "paper000_timing.png")
        return 0
    return run(runs, args.jobs, QUICK_RANGES if args.quick else RANGES, args.docs, args.radial)


if __name__ == "__main__":
    sys.exit(main())
