"""Harder conditions for ``benchmarks/multi_target.py`` (issue 42, item 2): each a row of grids
that differ from one base grid in one thing, scored like the held-out half.

The base is ``bintrack simulate darpa-grid`` with 7 people entering 6 s apart, walks curving,
one crossing, pd 0.7 and pfa 0.05 per sample, 6 of the 144 nodes dead (4 %), node jitter
±0.5 m, the 12 × 12 grid at 5 m. The rows change: pd (0.5, 0.9), pfa (0.01, 0.1), people
(2, 20), dead nodes (0 %, 20 %), people who stop (3 of the 7, 5–15 s), people walking in side-by-side
pairs (2 pairs of the 7), and the node spacing over the same field (16 × 16 at 3.5 m, 9 × 9
at 7 m; dead nodes 4 % of them). Every row uses the same simulation seeds
(``SEED`` + k), so rows differ in their condition, not in their draw of paths. Nothing here is
tuned: ours runs with its defaults and each Stone Soup tracker with the setting chosen on
the suite's tuning half.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

SEED = 3000
BASE = dict(people=7, pd=0.7, pfa=0.05, walk="curving", entry_gap=6.0, dead=6, node_jitter=0.5, crossings=1,
            pairs=0, stops=0)
ROWS: dict[str, dict] = {
    "base": {},
    "pd 0.5": {"pd": 0.5},
    "pd 0.9": {"pd": 0.9},
    "pfa 0.01": {"pfa": 0.01},
    "pfa 0.1": {"pfa": 0.1},
    "2 people": {"people": 2},
    "20 people": {"people": 20},
    "0 % dead": {"dead": 0},
    "20 % dead": {"dead": 29},
    "3 of 7 stop": {"stops": 3},
    "2 pairs walk together": {"pairs": 2},
    "denser: 3.5 m": {"grid": 16, "spacing": 3.5, "dead": 10},
    "sparser: 7 m": {"grid": 9, "spacing": 7.0, "dead": 3},
}
LOSS = 1.05  # a peer beats us in a row when our mean GOSPA exceeds its by more than 5 %


def grids(per_row: int) -> dict[str, list[dict]]:
    """Each row's ``bintrack simulate darpa-grid`` options (``seed`` first), ``per_row`` grids."""
    return {row: [dict(seed=SEED + k, **{**BASE, **change}) for k in range(per_row)] for row, change in ROWS.items()}


def table(gospa: dict, counts: dict, switches: dict, kinds: list[str]) -> tuple[str, list[str]]:
    """The rows' table and the rows we lose. ``gospa[row][tracker]``: per-grid mean GOSPA (ours:
    mean over sampler seeds); ``counts``, ``switches`` likewise (switches summed over the row)."""
    head = f"{'condition':<22} {'ours':>12} " + " ".join(f"{k:>12}" for k in kinds) + f" {'ours/best':>10} {'n err':>11} {'ID sw':>9}"
    lines = [head, "-" * len(head)]
    lost = []
    for row, by in gospa.items():
        cells = " ".join(f"{_ms(by[k]):>12}" if by.get(k) else f"{'-':>12}" for k in kinds)
        peers = {k: np.mean(by[k]) for k in kinds if by.get(k)}
        best = min(peers, key=peers.get) if peers else None
        ratio = np.mean(by["ours"]) / peers[best] if best else float("nan")
        if best and ratio > LOSS:
            lost.append(f"{row}: {best} {peers[best]:.2f} m against ours {np.mean(by['ours']):.2f} m ({ratio:.2f} x)")
        n = f"{np.mean(counts[row]['ours']):.2f}/{np.mean(counts[row][best]):.2f}" if best else "-"
        s = f"{sum(switches[row]['ours']):.0f}/{sum(switches[row][best]):.0f}" if best else "-"
        lines.append(f"{row:<22} {_ms(by['ours']):>12} {cells} {ratio:>10.3f} {n:>11} {s:>9}")
    return "\n".join(lines), lost


def _ms(values) -> str:
    return f"{np.mean(values):.2f}±{np.std(values):.2f}"


def plot(gospa: dict, kinds: list[str], path: Path) -> None:
    """Mean GOSPA per condition row, ours beside each tuned peer (bars: ± sd over the row's grids)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(gospa)
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(11, 4.8))
    trackers = ["ours", *kinds]
    width = 0.8 / len(trackers)
    for k, tracker in enumerate(trackers):
        mean = [np.mean(gospa[r][tracker]) if gospa[r].get(tracker) else np.nan for r in rows]
        sd = [np.std(gospa[r][tracker]) if gospa[r].get(tracker) else np.nan for r in rows]
        ax.bar(x - 0.4 + width * (k + 0.5), mean, width, yerr=sd, capsize=2,
               label="ours (defaults)" if tracker == "ours" else f"{tracker}, tuned on the suite's tuning half",
               color=f"C{k}", alpha=1.0 if tracker == "ours" else 0.75)
    ax.set_xticks(x, rows, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("mean GOSPA (c = 10 m, p = 2), m")
    ax.set_title("Harder conditions: one change from the base grid per row (bars: ± sd over the row's grids)")
    ax.set_ylim(0, ax.get_ylim()[1] * 1.25)  # room for the legend
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize="x-small", ncol=3, loc="upper left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
