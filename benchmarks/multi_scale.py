"""How the multi-target tracker's time per scan grows with people and nodes (issue 21, part 4).

Grids of ``bintrack simulate darpa-grid`` scaled in proportion: 10 people on 12 × 12 nodes
(the paper's grid), 30 on 21 × 21 and 100 on 38 × 38 (about 14 nodes per person), and 100 on
50 × 50 (more nodes, the same people). People enter ``entry gap`` s apart so that about half of
them are in the field at its busiest, as with 10 people 10 s apart on the paper's grid
(gap ≈ crossing time / (people / 2)); straight walks, one crossing, the paper's sensors
(8 m, pd 0.7, pfa 0.05, 0.5 s).

Our tracker (``bintrack track DIR --tracker mcmcda``, defaults) reads each grid from 25 s
before the moment the most people are in the field to 10 s after it, so it meets people
already in the field; after a warm-up of 15 s (30 scans, in which their tracks form), the
CPU time of the process (``time.process_time``, so that other work on a shared machine does
not count) spent in the fusion (scan intake, eq. (4) and the target fit, ``ScanFusion``) and of the
online MCMCDA (``OnlineMCMCDA.step`` and the expected targets handed to the fusion) is taken
per scan over the 20 s around that moment. Printed per grid: the most people present,
reports per scan, mean and p95 ms per scan of each part and of both, as a fraction of the 0.5 s period (below 1: real
time on one core). ``--profile`` adds the functions that dominate on the largest grid
(cProfile, by own time; it slows that grid's figures). Writes a log-log plot (``--plot``, default docs/multi_scale.png).

Simulated grids are cached under ``/tmp/bintrack-multi-scale`` (simulating the 100-person
grids takes minutes). Tracking took about 9 min wall on 2 cores shared with other work (load
10–15); ``--quick`` stops at 30 people; ``--chains 1`` times one MCMCDA chain per scan
instead of the default 4.

Run: ``nice -n 10 .venv/bin/python benchmarks/multi_scale.py [--quick] [--profile] [--chains N]``
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench_support import DOCS, say

DEFAULT_PLOT = DOCS / "multi_scale.png"
DEFAULT_CACHE = Path("/tmp/bintrack-multi-scale")
SPEED = 1.25  # m/s, the mean walking speed of darpa-grid
# (people, nodes per side)
GRIDS = ((10, 12), (30, 21), (100, 38), (100, 50))
# The tracker reads each grid from WARM_UP + BEFORE_PEAK s before the moment the most people are
# in the field to AFTER_PEAK s after it; times are taken after the warm-up.
WARM_UP, BEFORE_PEAK, AFTER_PEAK = 15.0, 10.0, 10.0


def entry_gap(people: int, side: int) -> float:
    """s between entries so that about half the people are in the field at once."""
    crossing = (side - 1) * 5.0 / SPEED
    return round(crossing / (people / 2), 1)


def dataset(people: int, side: int, cache: Path) -> Path:
    from bintrack.formats import write_dataset
    from bintrack.sim import simulate

    gap = entry_gap(people, side)
    folder = cache / f"p{people}-g{side}-gap{gap}"
    if not (folder / "truth.csv").exists():
        say(f"simulating darpa-grid --people {people} --grid {side} --entry-gap {gap}")
        sim = simulate("darpa-grid", 1, people=people, grid=side, entry_gap=gap)
        tmp = folder.with_name(folder.name + ".part")
        write_dataset(tmp, sim.deployment, sim.events, sim.truth)
        tmp.rename(folder)
    return folder


class Clock:
    """Wraps a bound method and adds the process CPU time it takes to ``totals[key]`` (s): CPU
    time, not wall time, so that other work on a shared machine does not count."""

    def __init__(self, method, totals: dict, key: str):
        self.method, self.totals, self.key = method, totals, key

    def __call__(self, *args, **kwargs):
        start = time.process_time()
        try:
            return self.method(*args, **kwargs)
        finally:
            self.totals[self.key] += time.process_time() - start


@dataclass
class Run:
    people: int
    side: int
    scans: int
    busiest: int
    reports: float
    fusion_ms: np.ndarray
    mcmcda_ms: np.ndarray
    period: float
    gospa: float


def run(people: int, side: int, path: Path, profile: bool, chains: int | None = None) -> tuple[Run, str]:
    from bintrack.formats import TrackRow, open_dataset, read_truth
    from bintrack.bus_payloads import PositionReports, TrackSet
    from bintrack.evaluation.metrics import multi_target_scores, truth_paths
    from bintrack.pipeline import run_tracker
    from bintrack.trackers import make_tracker

    data = open_dataset(path)
    paths = truth_paths(read_truth(path / "truth.csv"))
    grid_t = np.arange(0.0, max(p.end for p in paths.values()), 1.0)
    present_t = np.array([sum(bool(p.exists(t)) for p in paths.values()) for t in grid_t])
    peak = int(present_t.max())
    peak_t = float(grid_t[np.argmax(present_t)])
    start, measured, until = peak_t - WARM_UP - BEFORE_PEAK, peak_t - BEFORE_PEAK, peak_t + AFTER_PEAK
    data = Window(data, start)
    tracker = make_tracker("mcmcda", data.deployment)
    if chains is not None:
        from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
        from bintrack.trackers.multi.tracker import MCMCDATracker

        tracker = MCMCDATracker(data.deployment, config=MCMCDAConfig(chains=chains))
    totals = {"fusion": 0.0, "mcmcda": 0.0}
    fusion, mcmcda = tracker.fusion, tracker.mcmcda
    fusion.update = Clock(fusion.update, totals, "fusion")
    fusion.flush = Clock(fusion.flush, totals, "fusion")
    fusion.fuse = Clock(fusion.fuse, totals, "fusion")
    mcmcda.step = Clock(mcmcda.step, totals, "mcmcda")
    mcmcda.expected = Clock(mcmcda.expected, totals, "mcmcda")
    fusion_ms, mcmcda_ms, counts, rows, times = [], [], [], [], []
    last = dict(totals)
    profiler = cProfile.Profile() if profile else None
    if profiler:
        profiler.enable()
    for out in run_tracker(data, tracker):
        if isinstance(out, PositionReports):
            counts.append(len(out.reports))
        elif isinstance(out, TrackSet):  # one per scan, after its reports
            if out.t > until:
                break
            fusion_ms.append(1e3 * (totals["fusion"] - last["fusion"]))
            mcmcda_ms.append(1e3 * (totals["mcmcda"] - last["mcmcda"]))
            last = dict(totals)
            times.append(out.t)
            rows += [TrackRow(out.t, k.track, k.x, k.y) for k in out.tracks]
    text = ""
    if profiler:
        profiler.disable()
        buffer = io.StringIO()
        pstats.Stats(profiler, stream=buffer).sort_stats("tottime").print_stats(12)
        text = buffer.getvalue()
    times = np.array(times)
    busy = times >= measured  # after the warm-up: the tracks of the people present have formed
    scored = list(times[busy])
    m = multi_target_scores([r for r in rows if r.t >= measured], paths, 10.0, 2.0, times=scored)
    period = float(np.median(np.diff(times)))
    return Run(people, side, int(busy.sum()), peak, float(np.mean(np.array(counts[:len(times)])[busy])),
               np.array(fusion_ms)[busy], np.array(mcmcda_ms)[busy], period, m.gospa_mean), text


class Window:
    """A dataset read from ``start`` (s) on: the tracker meets the people already in the field."""

    def __init__(self, dataset, start: float):
        self.deployment, self._dataset, self._start = dataset.deployment, dataset, start

    def events(self):
        return (e for e in self._dataset.events() if e.t >= self._start)


def plot(runs: list[Run], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    x = np.array([r.busiest for r in runs], dtype=float)
    for label, get, marker in (("fusion", lambda r: r.fusion_ms, "o"), ("MCMCDA", lambda r: r.mcmcda_ms, "s"),
                               ("fusion + MCMCDA", lambda r: r.fusion_ms + r.mcmcda_ms, "^")):
        mean = np.array([get(r).mean() for r in runs])
        p95 = np.array([np.percentile(get(r), 95) for r in runs])
        line, = ax.loglog(x, mean, marker + "-", label=f"{label}, mean")
        ax.loglog(x, p95, marker + ":", color=line.get_color(), alpha=0.7, label=f"{label}, p95")
    for r, xi in zip(runs, x):
        ax.annotate(f"{r.people} people\n{r.side}x{r.side}", (xi, (r.fusion_ms + r.mcmcda_ms).mean()),
                    textcoords="offset points", xytext=(4, -22), fontsize=7)
    ax.axhline(1e3 * runs[0].period, color="k", lw=1, label=f"scan period {runs[0].period:g} s")
    ax.set_xlabel("people in the field at the busiest scan")
    ax.set_ylabel("CPU ms per scan (one core)")
    ax.set_title("Multi-target tracker: time per scan against people and nodes")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="small")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 and 30 people only")
    parser.add_argument("--profile", action="store_true", help="cProfile the largest grid")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--plot", type=Path, default=DEFAULT_PLOT)
    parser.add_argument("--chains", type=int, help="MCMCDA chains per scan (default: the tracker's default, 4)")
    args = parser.parse_args(argv)
    args.cache.mkdir(parents=True, exist_ok=True)
    grids = GRIDS[:2] if args.quick else GRIDS
    runs, profile_text = [], ""
    for people, side in grids:
        path = dataset(people, side, args.cache)
        say(f"tracking {people} people on {side} x {side} nodes")
        start = time.perf_counter()
        r, text = run(people, side, path, args.profile and (people, side) == grids[-1], args.chains)
        say(f"  {time.perf_counter() - start:.0f} s")
        runs.append(r)
        profile_text = text or profile_text
        both = r.fusion_ms + r.mcmcda_ms
        say(f"  {people} people ({r.busiest} at once), {side} x {side}: fusion {r.fusion_ms.mean():.1f} ms, "
            f"MCMCDA {r.mcmcda_ms.mean():.1f} ms per scan, {both.mean() / (1e3 * r.period):.3f} of the period")
    head = (f"{'people':>6} {'nodes':>9} {'gap s':>5} {'scans':>5} {'most':>7} {'rep/scan':>8} "
            f"{'fusion ms':>10} {'MCMCDA ms':>10} {'both ms':>9} {'both p95':>8} {'of period':>9} {'p95 of period':>13} {'GOSPA':>6}")
    lines = ["CPU time per scan (one process), mean and p95 over the scans; fraction of the scan period "
             "(< 1: real time on one core), over the 20 s around the moment the most people are in the field "
             "(GOSPA over those scans)", head, "-" * len(head)]
    for r in runs:
        both = r.fusion_ms + r.mcmcda_ms
        lines.append(f"{r.people:6d} {f'{r.side}x{r.side}':>9} {entry_gap(r.people, r.side):5.1f} {r.scans:5d} "
                     f"{r.busiest:7d} {r.reports:8.1f} {r.fusion_ms.mean():10.1f} {r.mcmcda_ms.mean():10.1f} "
                     f"{both.mean():9.1f} {np.percentile(both, 95):8.1f} {both.mean() / (1e3 * r.period):9.3f} "
                     f"{np.percentile(both, 95) / (1e3 * r.period):13.3f} {r.gospa:6.2f}")
    if len(runs) >= 3:
        a, b = runs[0], runs[2]
        k = np.log(b.busiest / a.busiest)
        lines.append(f"growth from {a.people} to {b.people} people (busiest {a.busiest} -> {b.busiest}, log-log slope): "
                     f"fusion {np.log(b.fusion_ms.mean() / a.fusion_ms.mean()) / k:.2f}, "
                     f"MCMCDA {np.log(b.mcmcda_ms.mean() / a.mcmcda_ms.mean()) / k:.2f}")
    print("\n".join(lines), flush=True)
    plot(runs, args.plot)
    print(f"plot: {args.plot}")
    if profile_text:
        print(f"\nProfile of {grids[-1][0]} people on {grids[-1][1]} x {grids[-1][1]} (top by own time):\n{profile_text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
