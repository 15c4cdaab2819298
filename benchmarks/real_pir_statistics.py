"""Real PIR sensors against the simulator's PIR model, side by side (issue: real sensors).

    .venv/bin/python benchmarks/real_pir_statistics.py [--data ../shared/realdata/irtracking] [--out docs] [--seeds N]

For each public sequence of the ceiling-PIR recording of Milan et al. (ACCV 2014 workshops): the
recording is imported, its sensors calibrated from the detections alone (``bintrack calibrate``'s
estimator, truth unused), and its annotated people walked again through the fitted sensors by
the simulator (``bintrack simulate recording --like``'s scenario; hold time, per-sensor footprint,
pd and pfa) with seeds 0..N−1. Printed and plotted, real beside simulated (mean and range over
the seeds): the firing rate of a sensor against the distance to the nearest person, and the
distributions of on-run and off-run lengths (consecutive samples reporting 1, resp. 0, between
two firings). Writes ``--out``/real_pir_statistics.png.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial.distance import cdist  # noqa: E402

from bintrack.calibration.pir_calibration import calibrate  # noqa: E402
from bintrack.calibration.sample_series import sample_series  # noqa: E402
from bintrack.formats import Event, TruthRow  # noqa: E402
from bintrack.importers.binary_matrix import matrix_events, read_sample_matrix, read_sensor_table  # noqa: E402
from bintrack.importers.cvml import read_cvml  # noqa: E402
from bintrack.deployment_model import Deployment, DiskSensor, Region  # noqa: E402
from bintrack.sim.engine import simulate_scenario  # noqa: E402
from bintrack.sim.recorded_paths import recording_scenario  # noqa: E402

PERIOD = 0.5
STATED = 0.7
BINS = np.array([0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0, 20.0])
MAX_RUN = 8


def load(data: Path, name: str) -> tuple[Deployment, list[Event], list[TruthRow], int]:
    sensors = read_sensor_table(data / "sensors.csv", columns=list(range(1, 44)))
    matrix = read_sample_matrix(data / f"{name}.txt", header_lines=1)
    deployment = Deployment(name=name, units="m", region=Region(xmin=0, ymin=0, xmax=8.6, ymax=14),
                            sensors=[DiskSensor(id=s.id, x=s.x, y=s.y, range=STATED, period=PERIOD) for s in sensors])
    truth = read_cvml(data / f"{name}_gt.xml", PERIOD, 0.025)
    return deployment, list(matrix_events(matrix, sensors, PERIOD)), truth, len(matrix)


def statistics(deployment: Deployment, events: list[Event], truth: list[TruthRow], samples: int) -> dict:
    series = sample_series(deployment, events)
    status = np.zeros((samples, len(series.ids)), dtype=np.int8)
    status[: len(series.status)] = series.status[:samples]
    if len(series.status) < samples:
        status[len(series.status):] = series.status[-1]
    times = np.arange(samples) * PERIOD
    by_target = defaultdict(list)
    for r in truth:
        by_target[r.target].append(r)
    nearest = np.full(status.shape, np.inf)
    for rows in by_target.values():
        t = np.array([r.t for r in rows])
        xy = np.array([(r.x, r.y) for r in rows])
        alive = (times >= t[0] - 1e-6) & (times <= t[-1] + 1e-6)
        p = np.stack([np.interp(times[alive], t, xy[:, 0]), np.interp(times[alive], t, xy[:, 1])], axis=1)
        nearest[alive] = np.minimum(nearest[alive], cdist(p, series.positions))
    nearest[np.isinf(nearest)] = BINS[-1] - 1e-6
    which = np.digitize(nearest, BINS) - 1
    rate = np.array([status[which == b].mean() if (which == b).any() else np.nan for b in range(len(BINS) - 1)])
    on, off = np.zeros(MAX_RUN + 1), np.zeros(MAX_RUN + 1)
    for i in range(status.shape[1]):
        padded = np.concatenate(([0], status[:, i], [0]))
        edges = np.diff(padded)
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        for a, b in zip(starts, ends):
            on[min(b - a, MAX_RUN)] += 1
        for a, b in zip(ends[:-1], starts[1:]):
            off[min(b - a, MAX_RUN)] += 1
    return {"rate": rate, "on": on[1:] / max(on.sum(), 1), "off": off[1:] / max(off.sum(), 1)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "irtracking")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs")
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    if not (args.data / "r1-easy.txt").exists():
        print(f"skipped: the recording is not in {args.data}")
        return 0
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5))
    for row, name in enumerate(("r1-easy", "r1-medium")):
        deployment, events, truth, samples = load(args.data, name)
        real = statistics(deployment, events, truth, samples)
        fit = calibrate(sample_series(deployment, events), STATED, boot=0)
        by_id = {f.id: f for f in fit.sensors}
        fitted = deployment.model_copy(update={"sensors": [s.model_copy(update={
            "range": by_id[s.id].range.value, "pd": by_id[s.id].pd.value, "pfa": by_id[s.id].pfa.value,
            "hold": by_id[s.id].hold.value}) for s in deployment.sensors]})
        window = (0.0, (samples - 1) * PERIOD)
        sims = []
        for seed in range(args.seeds):
            result = simulate_scenario(recording_scenario(fitted, truth, window), seed)
            sims.append(statistics(fitted, result.events, truth, samples))
        print(f"{name}: {len(events)} real transitions; simulated {args.seeds} seeds with the sensors fitted to the detections")
        for key, label, x, xlabel in (("rate", "firing rate", 0.5 * (BINS[:-1] + BINS[1:]), "distance to nearest person (m)"),
                                      ("on", "on-run length", np.arange(1, MAX_RUN + 1), "on-run length (samples of 0.5 s; last: ≥)"),
                                      ("off", "off-run length", np.arange(1, MAX_RUN + 1), "off-run length (samples of 0.5 s; last: ≥)")):
            sim = np.array([s[key] for s in sims])
            mean, lo, hi = np.nanmean(sim, 0), np.nanmin(sim, 0), np.nanmax(sim, 0)
            if key == "rate":
                labels = [f"{a:g}-{b:g}" for a, b in zip(BINS[:-1], BINS[1:])]
            else:
                labels = [str(int(v)) for v in x]
            print(f"  {label}:")
            print("    " + " ".join(f"{l:>9}" for l in labels))
            print("    " + " ".join(f"{v:>9.3f}" for v in real[key]) + "   real")
            print("    " + " ".join(f"{v:>9.3f}" for v in mean) + "   simulated, mean")
            print("    " + " ".join(f"{a:.2f}-{b:.2f}".rjust(9) for a, b in zip(lo, hi)) + "   simulated, range")
            ax = axes[row, ("rate", "on", "off").index(key)]
            ax.plot(x, real[key], "o-", color="k", label="real")
            ax.plot(x, mean, "s--", color="tab:orange", label=f"simulated (mean of {args.seeds})")
            ax.fill_between(x, lo, hi, color="tab:orange", alpha=0.25, label="simulated range")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("P(sensor on)" if key == "rate" else "fraction of runs")
            ax.set_title(f"{name}: {label}")
            if key == "rate":
                ax.set_xscale("log")
            ax.legend(fontsize=8)
    fig.tight_layout()
    out = args.out / "real_pir_statistics.png"
    fig.savefig(out, dpi=90)
    print(f"plot written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
