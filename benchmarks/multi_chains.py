"""Why 4 MCMCDA chains per scan (the default) and not 1: per grid of the suite of
``benchmarks/multi_target.py``, mean GOSPA and identity switches over sampler seeds (bars from
the lowest to the highest seed), one chain beside four.

Reads two ``--json`` records of ``multi_target.py --only chains1|chains4`` (or its full run,
whose ``default`` is the default), writes ``--plot`` (default docs/multi_chains.png) and prints
the per-grid figures and the means over each half.

Run: ``.venv/bin/python benchmarks/multi_chains.py ONE.json FOUR.json``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bench_support import DOCS

DEFAULT_PLOT = DOCS / "multi_chains.png"


def per_grid(record: dict) -> dict[str, list[dict]]:
    """Grid name → its scores per sampler seed (the one variant of ``record``)."""
    return {key.split("/")[0]: scores for key, scores in record["ours"].items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("one", type=Path, help="record with one chain per scan")
    parser.add_argument("four", type=Path, help="record with four chains per scan")
    parser.add_argument("--plot", type=Path, default=DEFAULT_PLOT)
    args = parser.parse_args(argv)
    runs = {"1 chain": per_grid(json.loads(args.one.read_text())),
            "4 chains": per_grid(json.loads(args.four.read_text()))}
    grids = sorted(set.intersection(*(set(r) for r in runs.values())), key=lambda n: (n[0] != "t", n))
    if not grids:
        print("multi_chains: the two records share no grid", file=sys.stderr)
        return 1
    print(f"{'grid':<7}" + "".join(f" {label + ' GOSPA':>18} {'switches':>14}" for label in runs))
    for n in grids:
        cells = []
        for r in runs.values():
            g = [s["gospa"] for s in r[n]]
            w = [s["switches"] for s in r[n]]
            cells.append(f" {np.mean(g):8.2f} ({min(g):.2f}-{max(g):.2f}) {np.mean(w):6.1f} ({min(w):.0f}-{max(w):.0f})")
        print(f"{n:<7}" + "".join(cells))
    for half in ("t", "h"):
        group = [n for n in grids if n[0] == half]
        if not group:
            continue
        line = []
        for label, r in runs.items():
            seeds = range(min(len(r[n]) for n in group))
            g = [np.mean([r[n][k]["gospa"] for n in group]) for k in seeds]
            w = [sum(r[n][k]["switches"] for n in group) for k in seeds]
            line.append(f"{label}: GOSPA {np.mean(g):.2f} (seeds {min(g):.2f}-{max(g):.2f}), "
                        f"switches summed {np.mean(w):.1f} ({min(w):.0f}-{max(w):.0f})")
        print(f"{'tuning' if half == 't' else 'held-out'} half, {len(group)} grids: " + "; ".join(line))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    x = np.arange(len(grids))
    for (label, r), dx, colour in zip(runs.items(), (-0.12, 0.12), ("C0", "C3")):
        for ax, field in zip(axes, ("gospa", "switches")):
            v = [[s[field] for s in r[n]] for n in grids]
            mean = np.array([np.mean(a) for a in v])
            lo, hi = np.array([min(a) for a in v]), np.array([max(a) for a in v])
            ax.errorbar(x + dx, mean, yerr=[mean - lo, hi - mean], fmt="o", color=colour, capsize=3,
                        label=f"{label}: mean over seeds, bar min-max")
    for ax, title in zip(axes, ("mean GOSPA (c = 10 m, p = 2), m", "identity switches")):
        ax.set_xticks(x, grids, fontsize=8)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small")
    fig.suptitle("MCMCDA, one chain against four per scan (MAP over the chains)")
    fig.tight_layout()
    args.plot.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.plot, dpi=110)
    print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
