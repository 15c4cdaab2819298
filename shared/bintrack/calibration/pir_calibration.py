"""Each disk sensor's footprint radius, pd, pfa and hold time estimated from its detections alone
(no truth), with bootstrap intervals; and, where truth exists, the same parameters fitted to it
for comparison.

The sensor model (the one :mod:`bintrack.sim` simulates for real PIR): sensor i reports 1 in a
sample with probability pd_i while a person is within r_i of it (or was, within the last hold_i
seconds), and with probability pfa_i otherwise.

Unsupervised estimates (sampling period P):

* hold: an on-run (consecutive samples reporting 1) lasts at least H + 1 samples when the output
  is held H·P s after a trigger. H + 1 is the shortest run length that carries at least 5 % of
  the sensor's runs (pooled over sensors when a sensor has fewer than ``MIN_RUNS`` runs).
* pd: a person passing through the footprint is seen in each sample with probability pd. Without
  hold, a sample between two firings of the same sensor is, nearly always, a sample in which
  the person is still there, so pd = n₁₁₁/(n₁₁₁ + n₁₀₁) over the triplets of samples (1, x, 1);
  shrunk per sensor towards the pooled value with ``PSEUDO_RUNS`` pseudo-triplets. With a hold
  of H ≥ 1 samples a miss hides inside the held output, and pd comes from the on-runs: an
  on-run minus its held part is geometric, P(G = g) = (1 − pd)·pd^(g − 1), MLE pd = 1 − 1/mean(G)
  (biased low where passages are short, since a run ends when the person leaves).
* pfa: firings of a sensor while no other sensor within 4 stated ranges of it fires for
  ±``QUIET_SAMPLES`` samples (isolated firings), over the samples where they are quiet; within
  2, then 1 stated range where fewer than ``MIN_QUIET`` of all samples are quiet (false alarms
  so frequent, or a field so busy, that a wide neighbourhood is never quiet).
* footprint radius: co-firing with the neighbours at known distances, over the triggered samples
  (each on-run without its held last H samples). Given that sensor i fires,
  the person is somewhere in its footprint, so neighbour j (at distance d) fires in the same
  sample with probability c_ij = pd_j·A(d, r)/(π r²) + b, A the area of the lens of two disks of
  radius r at distance d, b the background (other people, false alarms). r and b are fitted by
  weighted least squares to the pairs within ``PAIR_RANGES`` stated ranges whose sensors both
  fire at least once (a dead sensor says nothing of footprints), pooled, then r per
  sensor over the pairs it is in (shrunk towards the pooled r). The pooled search starts at
  twice the stated range, and again from the best of ``RADIUS_GRID`` radii where that one is
  better: below half the nearest pair's distance no pair overlaps, the fit is flat in r, and a
  search that steps there stops.

Intervals: a moving-block bootstrap over time (blocks of ``BLOCK`` samples), 2.5 % and 97.5 %;
none for a recording shorter than two blocks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar
from scipy.spatial.distance import cdist

from bintrack.calibration.sample_series import SampleSeries

MIN_RUNS = 8
PSEUDO_RUNS = 5.0
QUIET_RANGES = (4.0, 2.0, 1.0)
"""stated ranges: the neighbourhood that must be quiet for a firing to count as a false alarm,
the first of these that leaves ``MIN_QUIET`` of the samples quiet"""
MIN_QUIET = 0.05
"""of all the sensors' samples"""
QUIET_SAMPLES = 2
PAIR_RANGES = 5.0
BLOCK = 20
MIN_INTERVAL_SAMPLES = 2 * BLOCK
"""fewer samples get no intervals: every resample would be the recording itself, of width 0"""
RADIUS_GRID = 40
"""radii (geometric, 0.2 to 10 stated ranges) from the best of which the pooled fit starts again"""
RESTART_GAIN = 1e-3
"""... when that radius beats the first fit's sum of squares by at least this fraction"""
PFA_FLOOR = 1e-4
"""no estimate below this (per sample): a finite weight for a detection in the fusion"""


@dataclass(frozen=True)
class Estimate:
    """A value and its 95 % interval (None when not computed)."""

    value: float
    low: float | None = None
    high: float | None = None


@dataclass(frozen=True)
class SensorFit:
    """One sensor's fitted model: radius (units), pd and pfa (per sample), hold (s); ``still``
    (pd of a person standing still, as a fraction of pd) only from the truth."""

    id: str
    range: Estimate
    pd: Estimate
    pfa: Estimate
    hold: Estimate
    still: Estimate | None = None


@dataclass(frozen=True)
class Fit:
    """The fit of every sensor and the pooled one (``pooled.id`` is ``"all"``)."""

    method: str
    sensors: tuple[SensorFit, ...]
    pooled: SensorFit


def _runs(column: np.ndarray) -> np.ndarray:
    """Lengths of the on-runs of a 0/1 column that neither start at the first sample nor end at the last."""
    padded = np.concatenate(([0], column.astype(np.int8), [0]))
    edges = np.diff(padded)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    keep = (starts > 0) & (ends < len(column))
    return (ends - starts)[keep]


def _hold_samples(runs: np.ndarray) -> int:
    if runs.size == 0:
        return 0
    counts = np.bincount(runs)
    return int(np.flatnonzero(counts >= max(1.0, 0.05 * runs.size))[0]) - 1


def _without_hold(status: np.ndarray, hold: np.ndarray) -> np.ndarray:
    """The samples that were triggered rather than held: each on-run of sensor i loses its last
    ``hold[i]`` samples (at least its first sample stays)."""
    out = status.copy()
    for i in np.flatnonzero(hold > 0):
        padded = np.concatenate(([0], status[:, i].astype(np.int8), [0]))
        edges = np.diff(padded)
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            out[max(a + 1, b - hold[i]):b, i] = 0
    return out


def lens_fraction(d, r) -> np.ndarray:
    """A(d, r)/(π r²): the fraction of a disk of radius r that a second one at distance d overlaps."""
    d = np.minimum(np.asarray(d, dtype=float), 2 * r)
    area = 2 * r * r * np.arccos(d / (2 * r)) - 0.5 * d * np.sqrt(np.maximum(4 * r * r - d * d, 0.0))
    return area / (math.pi * r * r)


def _background(r: float, w: np.ndarray, c: np.ndarray, pdj: np.ndarray, d: np.ndarray) -> float:
    """The weighted least-squares b of c = pd_j·A(d, r)/(π r²) + b for a fixed r, within [0, 0.9]."""
    return float(np.clip(np.sum(w * (c - pdj * lens_fraction(d, r))) / np.sum(w), 0.0, 0.9))


def _pairs_of(ii: np.ndarray, jj: np.ndarray, n: int) -> list[np.ndarray]:
    """For each sensor 0..n−1, the indices (ascending) of the pairs (ii[p], jj[p]) of two
    different sensors it is part of: ``np.flatnonzero((ii == i) | (jj == i))`` for every i at once."""
    p = np.arange(len(ii))
    who, which = np.concatenate([ii, jj]), np.concatenate([p, p])
    order = np.lexsort((which, who))
    return np.split(which[order], np.searchsorted(who[order], np.arange(1, n)))


def _point_fit(status: np.ndarray, positions: np.ndarray, stated: float, period: float) -> tuple[np.ndarray, ...]:
    """Per-sensor and pooled (last entry) radius, pd, pfa, hold (s) of one sample matrix."""
    n = status.shape[1]
    runs = [_runs(status[:, i]) for i in range(n)]
    pooled_runs = np.concatenate(runs) if runs else np.zeros(0, int)
    h0 = max(_hold_samples(pooled_runs), 0)
    hold = np.array([_hold_samples(r) if r.size >= MIN_RUNS else h0 for r in runs] + [h0], dtype=float)
    hold = np.maximum(hold, 0)
    g_all = pooled_runs - h0
    g_all = g_all[g_all >= 1]
    pd0 = 1.0 - 1.0 / g_all.mean() if g_all.size else 0.5
    pd0 = min(max(pd0, 0.05), 0.99)
    pd = []
    for i in range(n):
        g = runs[i] - int(hold[i])
        g = g[g >= 1]
        pd.append(1.0 - (g.size + PSEUDO_RUNS) / (g.sum() + PSEUDO_RUNS / (1.0 - pd0)))
    pd = np.clip(np.array(pd + [pd0]), 0.05, 0.99)
    if len(status) >= 3:
        # without hold, a sample between two firings is a miss (1, 0, 1) or a hit (1, 1, 1) of a
        # person still there: pd = n111 / (n111 + n101), unbiased by how long a passage lasts
        a, b, c = status[:-2], status[1:-1], status[2:]
        n111 = ((a == 1) & (b == 1) & (c == 1)).sum(axis=0).astype(float)
        n101 = ((a == 1) & (b == 0) & (c == 1)).sum(axis=0).astype(float)
        if n111.sum() + n101.sum() > 0:
            t0 = n111.sum() / (n111.sum() + n101.sum())
            triplet = np.append((n111 + PSEUDO_RUNS * t0) / (n111 + n101 + PSEUDO_RUNS), t0)
            pd = np.where(hold == 0, np.clip(triplet, 0.05, 0.99), pd)

    distance = cdist(positions, positions)
    window = np.ones(2 * QUIET_SAMPLES + 1)
    # "full" cut to the samples, not "same": that one is as long as the window when the series is shorter
    busy = np.array([np.convolve(status[:, j], window)[QUIET_SAMPLES:QUIET_SAMPLES + len(status)] > 0
                     for j in range(n)]).T  # k × j
    for reach in QUIET_RANGES:
        near = (distance < reach * stated) & ~np.eye(n, dtype=bool)
        quiet_on, quiet_n = np.zeros(n), np.zeros(n)
        for i in range(n):
            quiet = ~busy[:, near[i]].any(axis=1)
            quiet_n[i] = quiet.sum()
            quiet_on[i] = status[quiet, i].sum()
        if quiet_n.sum() >= MIN_QUIET * status.size:
            break
    pfa0 = max(quiet_on.sum() / max(quiet_n.sum(), 1.0), PFA_FLOOR)
    pfa = np.maximum((quiet_on + 20.0 * pfa0) / (quiet_n + 20.0), PFA_FLOOR)
    pfa = np.append(pfa, pfa0)

    triggers = _without_hold(status, hold[:-1].astype(int))
    on = triggers.sum(axis=0).astype(float)
    co = triggers.T.astype(float) @ triggers.astype(float)
    ii, jj = np.nonzero((distance < PAIR_RANGES * stated) & ~np.eye(n, dtype=bool) & (on[:, None] > 0) & (on[None, :] > 0))
    d, c, w = distance[ii, jj], co[ii, jj] / np.maximum(on[ii], 1), on[ii]
    pdj = pd[jj]

    def sse(r, b, w=w, c=c, pdj=pdj, d=d):  # over all pairs, or over one sensor's (the arrays sliced)
        return float(np.sum(w * (c - (pdj * lens_fraction(d, r) + b)) ** 2))

    if d.size:
        bounds = [(0.2 * stated, 10 * stated), (0.0, 0.9)]
        res = minimize(lambda p: sse(p[0], p[1]), x0=[2 * stated, 0.05], bounds=bounds, method="L-BFGS-B")
        # Below half the nearest pair's distance no pair overlaps and the sse is flat in r: a
        # first step from 2·stated that lands there stops. Then start again from the best radius
        # of a grid, each with its least-squares b.
        grid = [(r, _background(r, w, c, pdj, d)) for r in np.geomspace(*bounds[0], RADIUS_GRID)]
        best = min((sse(r, b), r, b) for r, b in grid)
        if best[0] < res.fun * (1.0 - RESTART_GAIN):
            again = minimize(lambda p: sse(p[0], p[1]), x0=list(best[1:]), bounds=bounds, method="L-BFGS-B")
            res = again if again.fun < res.fun else res
        r0, b0 = float(res.x[0]), float(res.x[1])
    else:
        r0, b0 = stated, 0.0
    radius = []
    prior = 0.05 * max(w.sum(), 1.0) / max(n, 1)  # weight of the pooled radius, as a few pairs' worth
    for i, pairs in enumerate(_pairs_of(ii, jj, n)):
        if not pairs.size:
            radius.append(r0)
            continue
        own = w[pairs], c[pairs], pdj[pairs], d[pairs]
        fit = minimize_scalar(lambda r: sse(r, b0, *own) + prior * ((r - r0) / r0) ** 2,
                              bounds=(0.2 * stated, 10 * stated), method="bounded")
        radius.append(float(fit.x))
    radius = np.array(radius + [r0])
    return radius, pd, pfa, hold * period


def calibrate(series: SampleSeries, stated_range: float, *, boot: int = 200, seed: int = 0,
              progress: Callable[[int, int], None] | None = None) -> Fit:
    """The unsupervised fit of every sensor of ``series`` (see the module's text); ``stated_range``
    (units) is the only prior: the scale of the neighbourhoods and where the search starts.
    ``progress(done, total)`` is called after each of the bootstrap's fits."""
    if not stated_range > 0:
        raise ValueError(f"stated range must be positive, got {stated_range}")
    status, positions, period = series.status, series.positions, series.period
    point = _point_fit(status, positions, stated_range, period)
    rng = np.random.default_rng(seed)
    k = len(status)
    draws = []
    total = boot if k >= MIN_INTERVAL_SAMPLES else 0
    for done in range(1, total + 1):
        starts = rng.integers(0, k - BLOCK + 1, size=math.ceil(k / BLOCK))
        sample = np.concatenate([status[s:s + BLOCK] for s in starts])[:k]
        draws.append(np.array(_point_fit(sample, positions, stated_range, period)))
        if progress is not None:
            progress(done, total)
    draws = np.array(draws) if draws else None  # boot × 4 × (n + 1)

    def est(p: int, i: int) -> Estimate:
        if draws is None:
            return Estimate(float(point[p][i]))
        lo, hi = np.percentile(draws[:, p, i], [2.5, 97.5])
        return Estimate(float(point[p][i]), float(lo), float(hi))

    ids = list(series.ids) + ["all"]
    fits = [SensorFit(ids[i], est(0, i), est(1, i), est(2, i), est(3, i)) for i in range(len(ids))]
    return Fit("detections", tuple(fits[:-1]), fits[-1])


def calibrate_supervised(series: SampleSeries, truth: dict[str, tuple[np.ndarray, np.ndarray]],
                         max_range: float, *, still_speed: float = 0.3) -> Fit:
    """The same model fitted to the truth, per sensor by maximum likelihood: for each hold H·P
    (H = 0..4) and radius r (steps of 1/40 of ``max_range``, units), pd and pfa are the firing
    rates inside and outside "a person within r in the last H·P s", and the best pair (H, r) is
    kept. ``truth``: target → (times s, positions (n, 2) units), linearly interpolated, the
    target existing from its first to its last time. ``still``: the firing rate inside of people
    slower than ``still_speed`` units/s over that of the others."""
    times = series.times
    n = len(series.ids)
    dist = np.full((len(times), n), np.inf)
    slow = np.zeros((len(times), n), dtype=bool)
    for t, xy in truth.values():
        alive = (times >= t[0] - 1e-6) & (times <= t[-1] + 1e-6)
        if not alive.any():
            continue
        tt = times[alive]
        p = np.stack([np.interp(tt, t, xy[:, 0]), np.interp(tt, t, xy[:, 1])], axis=1)
        v = np.gradient(p, series.period, axis=0) if len(tt) > 1 else np.zeros_like(p)
        dd = cdist(p, series.positions)
        closer = dd < dist[alive]
        sub = dist[alive]
        sub[closer] = dd[closer]
        dist[alive] = sub
        s = slow[alive]
        s[closer] = (np.hypot(v[:, 0], v[:, 1])[:, None] < still_speed).repeat(n, axis=1)[closer]
        slow[alive] = s
    radii = np.linspace(max_range / 40, max_range, 40)
    fits, pooled = [], {"range": [], "pd": [], "pfa": [], "hold": [], "still": []}
    for i in range(n):
        y = series.status[:, i].astype(bool)
        best = None
        for h in range(5):
            dh = np.array([dist[max(0, k - h):k + 1, i].min() for k in range(len(times))])
            for r in radii:
                inside = dh < r
                a, b = inside.sum(), (~inside).sum()
                pd = min(max(y[inside].mean() if a else 0.5, 1e-3), 1 - 1e-3)
                pfa = min(max(y[~inside].mean() if b else PFA_FLOOR, PFA_FLOOR), 1 - 1e-3)
                ll = (y[inside].sum() * math.log(pd) + (a - y[inside].sum()) * math.log(1 - pd)
                      + y[~inside].sum() * math.log(pfa) + (b - y[~inside].sum()) * math.log(1 - pfa))
                if best is None or ll > best[0]:
                    best = (ll, h, float(r), pd, pfa, inside)
        _, h, r, pd, pfa, inside = best
        moving, still = inside & ~slow[:, i], inside & slow[:, i]
        ratio = (y[still].mean() / y[moving].mean()) if still.sum() >= 5 and y[moving].mean() > 0 else 1.0
        fits.append(SensorFit(series.ids[i], Estimate(r), Estimate(pd), Estimate(pfa), Estimate(h * series.period),
                              Estimate(float(min(ratio, 1.0)))))
        for key, value in (("range", r), ("pd", pd), ("pfa", pfa), ("hold", h * series.period), ("still", min(ratio, 1.0))):
            pooled[key].append(value)
    med = {k: Estimate(float(np.median(v))) for k, v in pooled.items()}
    return Fit("truth", tuple(fits), SensorFit("all", med["range"], med["pd"], med["pfa"], med["hold"], med["still"]))
