"""How well could any tracker place the people of the real ceiling-PIR recording from its
sensors? An oracle's GOSPA beside the acceptance's 1.2 m (issue: real sensors).

    .venv/bin/python benchmarks/real_pir_bound.py [--data ../shared/realdata/irtracking] [--q 0.5] [--spread 0.5] [--floor-plan PLAN.json]

For each public sequence: the chain a user runs (``bintrack import``, then ``bintrack calibrate``
of a copy without truth.csv: the sensor model from the detections alone), then an oracle that is
*given* what our tracker must find, so that its error is what the sensors leave. Each annotated
person is followed by their own Bayes filter on the room's 0.1 m cells:

* the likelihood of a sample is that of the soft footprints the tracker reports with
  (p_i(d) = 1 − (1 − pfa_i)(1 − pd_i·e^(−d²/2σ_i²)), σ_i = R_i/2;
  :mod:`bintrack.trackers.multi.soft_footprint`), over every sensor's firing and silence,
  given **the other people at their true positions**; with ``--floor-plan``, a person is a
  thousand times less likely inside one of the room's obstacles;
* the motion is a random walk with the annotated people's own RMS step per sample and axis,
  started at the person's first annotated place, on the cells (exact); or a constant-velocity
  model (white acceleration ``--q``) with 3000 particles; the count and identities are the truth's;
* **online**: the filtered posterior mean at each sample; **smoothed**: the forward–backward
  posterior mean (the grid) or the mean of 300 trajectories drawn backwards (the particles):
  offline, any lag.

Each is written as tracks.csv and scored by ``bintrack eval --gospa-c 2 --area 0,0,8,14`` on
the calibrated dataset, as ``benchmarks/real_sensors.py`` scores ours (about 3 minutes). Nothing
is fitted to the scores but q, the lower-scoring of two tried. The oracle knows the count, the identities, the entries and the others' positions, so its GOSPA
estimates a floor for any tracker with this sensor model, not a figure to reach (a better
footprint or motion model could go lower; the annotation's own error is in it too).

The count is given to those oracles, so their count error says nothing. For the count, the
filter on how many sensors fire (``benchmarks/real_pir_count.py``; the tracker's
:class:`~bintrack.trackers.multi.firing_count.FiringCount`) is given what only the truth knows:
its slope a (firing sensors per person) and false alarms b by least squares on the true count,
and then the a, b and switch (chance per sample that someone comes or goes) of a grid whose count
error against the truth itself is lowest, fitted to the very sequence it is scored on.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_pir_count import count_filter, firings_and_counts  # noqa: E402
from real_sensors import EVAL, SEQUENCES, bintrack, stated_and_calibrated  # noqa: E402

from bintrack.calibration.sample_series import sample_series  # noqa: E402
from bintrack.deployment_model import DiskSensor, FloorPlan  # noqa: E402
from bintrack.floor_plan import FloorShape  # noqa: E402
from bintrack.formats import TrackRow, open_dataset, read_floor_plan, write_tracks  # noqa: E402
from bintrack.trackers.multi.pir_settings import PIR_PROCESS_NOISE, PIR_SPREAD  # noqa: E402
from bintrack.trackers.multi.soft_footprint import SoftFootprint  # noqa: E402

CELL = 0.1  # m
TARGET = 1.2  # the acceptance's GOSPA (c = 2 m), m
CV_NOISE = 0.5  # m²/s³: of the two tried, 0.035 (the tracker's) and 0.5, the one whose oracle does better
PARTICLES = 3000
DRAWS = 300
OBSTACLE = 1e-3  # an obstacle cell's likelihood beside a free one's (--floor-plan)
COUNT_SWITCH = 0.02  # per sample: the tracker's (FusionConfig.count_switch under pir_settings)
GRID_A = np.arange(1.0, 2.3001, 0.05)  # firing sensors per person
GRID_B = (0.0, 0.1, 0.2, 0.35, 0.5, 0.8)  # firing sensors of an empty room
GRID_SWITCH = (0.005, 0.01, 0.02, 0.05)
ORACLES = ("random walk, online", "random walk, smoothed", "constant velocity, online", "constant velocity, smoothed")


def likelihoods(dataset: Path, spread: float, plan: FloorPlan | None = None) -> tuple[np.ndarray, dict[str, list[tuple[float, np.ndarray, np.ndarray]]], tuple]:
    """The room's cells (m), and per person: (t, true position, the likelihood over the cells of
    their being there given the sample's firings and silences and the others at their true
    places, normalised) for each annotated sample; and the grid's shape. ``spread``: σ_i / R_i.
    With ``plan``, a cell inside an obstacle is a thousand times less likely (the annotation,
    clicked by hand, puts a person inside one now and then)."""
    data = open_dataset(dataset)
    sensors = [s for s in data.deployment.sensors if isinstance(s, DiskSensor)]
    series = sample_series(data.deployment, data.events())
    positions = np.array([(s.x, s.y) for s in sensors])
    soft = SoftFootprint(positions, np.array([s.range for s in sensors]) * spread,
                         np.array([s.pd for s in sensors]), np.array([s.pfa for s in sensors]))
    r = data.deployment.region
    xs, ys = np.arange(r.xmin + CELL / 2, r.xmax, CELL), np.arange(r.ymin + CELL / 2, r.ymax, CELL)
    cells = np.array([(x, y) for x in xs for y in ys])
    reach = float(np.hypot(r.xmax - r.xmin, r.ymax - r.ymin))
    standing = np.ones(len(cells)) if plan is None else np.where(FloorShape(plan).free(cells), 1.0, OBSTACLE)
    by_time = defaultdict(list)
    for row in data.truth():
        by_time[row.t].append(row)
    out = defaultdict(list)
    for t, rows in sorted(by_time.items()):
        k = int(round((t - series.t0) / series.period))
        if not 0 <= k < len(series.status):
            continue
        truth = np.array([(row.x, row.y) for row in rows])
        for i, row in enumerate(rows):
            log_l = soft.log_likelihood(cells, series.status[k], np.delete(truth, i, axis=0), reach)
            like = np.exp(log_l - log_l.max()) * standing
            out[row.target].append((t, truth[i], like / like.sum()))
    return cells, out, (len(xs), len(ys))


def step_spread(people: dict) -> float:
    """RMS per-axis displacement of the annotated people between consecutive samples, m."""
    steps = [np.diff(np.array([p for _, p, _ in samples]), axis=0) for samples in people.values() if len(samples) > 1]
    return float(np.sqrt(np.mean(np.concatenate(steps) ** 2)))


def grid_filter(cells: np.ndarray, shape: tuple, samples: list, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """The Bayes filter of one person's position on the cells (a random walk of ``spread`` m per
    sample and axis, started at their first annotated place): the filtered and the smoothed
    (forward–backward) posterior means, one row per sample (m)."""
    def blur(p: np.ndarray) -> np.ndarray:  # one step of the walk, forwards or backwards
        return gaussian_filter(p.reshape(shape), spread / CELL, mode="constant").ravel()

    start = np.exp(-0.5 * ((cells - samples[0][1]) ** 2).sum(axis=1) / spread ** 2)
    forward, prior = [], start / start.sum()
    for k, (_, _, like) in enumerate(samples):
        post = prior * like
        post = post / post.sum() if post.sum() > 0 else prior
        forward.append(post)
        prior = blur(post)
        prior /= prior.sum()
    filtered_means = np.array([f @ cells for f in forward])
    beta = np.ones(len(cells))
    smoothed_means = np.zeros_like(filtered_means)
    for k in range(len(samples) - 1, -1, -1):
        post = forward[k] * beta
        smoothed_means[k] = post @ cells / post.sum()
        if k:
            beta = blur(beta * samples[k][2])
            beta /= beta.max()
    return filtered_means, smoothed_means


def particle_filter(cells: np.ndarray, shape: tuple, samples: list, spread: float, q: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The same person followed with a constant-velocity model instead (white acceleration q,
    m²/s³, per axis; ``PARTICLES`` particles started at their first annotated place with
    ``spread`` m and at rest with 1 m/s per axis): the filtered posterior means and the means of
    ``DRAWS`` trajectories drawn backwards (forward filtering, backward simulation), m."""
    lo, hi = cells.min(axis=0) - CELL / 2, cells.max(axis=0) + CELL / 2
    n = PARTICLES

    def cell_of(points: np.ndarray) -> np.ndarray:
        ij = np.clip(np.floor((points - lo) / CELL).astype(int), 0, np.array(shape) - 1)
        return ij[:, 0] * shape[1] + ij[:, 1]

    def noise_cov(dt: float) -> np.ndarray:  # of (position, velocity) on one axis over dt s
        return q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])

    def noise(dt: float, size: int) -> np.ndarray:
        chol = np.linalg.cholesky(noise_cov(dt))
        return (rng.standard_normal((size, 2, 2)) @ chol.T)  # (size, axis, [p, v])

    state = np.zeros((n, 2, 2))  # particle, axis, (position, velocity)
    state[:, :, 0] = samples[0][1] + spread * rng.standard_normal((n, 2))
    state[:, :, 1] = rng.standard_normal((n, 2))
    particles, weights, filtered_means = [], [], []
    for k, (t, _, like) in enumerate(samples):
        if k:
            dt = t - samples[k - 1][0]
            idx = rng.choice(n, size=n, p=weights[-1])
            state = particles[-1][idx].copy()
            state[:, :, 0] += dt * state[:, :, 1]
            state += noise(dt, n)
        inside = np.all((state[:, :, 0] >= lo) & (state[:, :, 0] <= hi), axis=1)  # people stay in the room
        w = np.where(inside, like[cell_of(state[:, :, 0])], 0.0) + 1e-300
        w /= w.sum()
        particles.append(state)
        weights.append(w)
        filtered_means.append(w @ state[:, :, 0])
    draws = np.zeros((len(samples), DRAWS, 2))
    pick = rng.choice(n, size=DRAWS, p=weights[-1])
    chosen = particles[-1][pick]
    draws[-1] = chosen[:, :, 0]
    for k in range(len(samples) - 2, -1, -1):
        dt = samples[k + 1][0] - samples[k][0]
        inv = np.linalg.inv(noise_cov(dt))
        ahead = particles[k].copy()
        ahead[:, :, 0] += dt * ahead[:, :, 1]
        d = chosen[:, None, :, :] - ahead[None, :, :, :]  # draw, particle, axis, (p, v)
        log_t = -0.5 * np.einsum("dnai,ij,dnaj->dn", d, inv, d)
        log_w = np.log(weights[k])[None, :] + log_t
        prob = np.exp(log_w - log_w.max(axis=1, keepdims=True))
        prob /= prob.sum(axis=1, keepdims=True)
        pick = np.array([rng.choice(n, p=row) for row in prob])
        chosen = particles[k][pick]
        draws[k] = chosen[:, :, 0]
    return np.array(filtered_means), draws.mean(axis=1)


def oracle_tracks(cells: np.ndarray, shape: tuple, people: dict, q: float) -> tuple[dict[str, list[TrackRow]], float]:
    """Each oracle's tracks (track id: the person's), and the random walk's step (m)."""
    spread = step_spread(people)
    rng = np.random.default_rng(0)
    ids = {target: n for n, target in enumerate(sorted(people))}
    rows = {name: [] for name in ORACLES}
    for target, samples in people.items():
        means = (*grid_filter(cells, shape, samples, spread), *particle_filter(cells, shape, samples, spread, q, rng))
        for name, positions in zip(ORACLES, means):
            rows[name] += [TrackRow(t, ids[target], float(x), float(y), 0.0, 0.0)
                           for (t, _, _), (x, y) in zip(samples, positions)]
    return {name: sorted(r) for name, r in rows.items()}, spread


def count_oracles(dataset: Path) -> list[tuple[str, float, float, float, float]]:
    """The count of the people from how many sensors fire (``benchmarks/real_pir_count.py``'s
    filter, the tracker's :class:`FiringCount`), given what only the truth can give: a and b by
    least squares of the firing sensors on the true count (switch 0.02, the tracker's), and the
    a, b and switch of a grid whose count is nearest the truth. Rows (oracle, a, b, switch, count
    error per frame), people inside the scored area as ``bintrack eval --area`` counts them."""
    k, frames, n, _ = firings_and_counts(open_dataset(dataset))

    def error(a: float, b: float, switch: float) -> float:
        return float(np.abs(count_filter(k, a, b, switch)[0][frames] - n).mean())

    a, b = (float(v) for v in np.polyfit(n, k[frames], 1))
    best = min(((error(a_, b_, s), a_, b_, s) for a_ in GRID_A for b_ in GRID_B for s in GRID_SWITCH))
    return [("firings, the truth's a and b", a, b, COUNT_SWITCH, error(a, b, COUNT_SWITCH)),
            ("firings, the best of a grid", float(best[1]), best[2], best[3], best[0])]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared/realdata/irtracking")
    parser.add_argument("--spread", type=float, default=PIR_SPREAD,
                        help="the footprints' σ as a fraction of each sensor's fitted range (default: the tracker's, "
                        f"{PIR_SPREAD})")
    parser.add_argument("--q", type=float, default=CV_NOISE,
                        help=f"the constant-velocity oracle's white acceleration, m²/s³ (default {CV_NOISE}; at the "
                        f"tracker's {PIR_PROCESS_NOISE} its particles cannot follow a person's turns and lose them)")
    parser.add_argument("--floor-plan", type=Path, metavar="PLAN.json",
                        help="the room's floor plan: no oracle places a person inside its obstacles (e.g. "
                        "benchmarks/irtracking_floor_plan.json)")
    args = parser.parse_args()
    plan = read_floor_plan(args.floor_plan) if args.floor_plan else None
    if not (args.data / "sensors.csv").exists():
        print(f"skipped: the real recording is not at {args.data}")
        return 0
    print(f"GOSPA (c = 2 m), MOTA and count error of oracles given the true count, identities, entries and the "
          f"others' positions (footprints σ = {args.spread} R{', the floor plan' if plan else ''}); the acceptance asks GOSPA ≤ {TARGET} m of the real tracker")
    print(f"{'sequence':<10} {'oracle':<28} {'step m':>6} {'GOSPA m':>8} {'localisation m²':>16} {'MOTA':>7} {'MOTP':>6} {'count':>6}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in SEQUENCES:
            dataset = stated_and_calibrated(args.data, name, work)
            print(f"{name}: the likelihood of every person-sample (about a minute) ...", file=sys.stderr, flush=True)
            cells, people, shape = likelihoods(dataset, args.spread, plan)
            oracles, spread = oracle_tracks(cells, shape, people, args.q)
            for oracle, rows in oracles.items():
                path = work / f"{name}-{oracle.replace(' ', '-')}.csv"
                write_tracks(path, rows)
                s = json.loads(bintrack("eval", str(dataset), str(path), *EVAL, "--json").splitlines()[0])
                print(f"{name:<10} {oracle:<28} {spread:>6.2f} {s['gospa_mean']:>8.3f} {s['gospa_localisation_mean']:>16.3f} "
                      f"{100 * s['mota']:>6.1f}% {s['motp']:>6.3f} {s['target_count_error_mean']:>6.3f}", flush=True)
            for oracle, a, b, switch, count in count_oracles(dataset):
                print(f"{name:<10} {oracle:<28} {'':>6} {'':>8} {'':>16} {'':>7} {'':>6} {count:>6.3f}"
                      f"  (a {a:.2f}, b {b:.2f}, switch {switch})", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
