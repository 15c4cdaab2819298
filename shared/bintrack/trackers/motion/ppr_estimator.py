"""Projection pursuit regression, paper 002 §III.C: the direction u for which the counters are
best fit (least squares) by a non-decreasing function of s·u
(``scipy.optimize.isotonic_regression``); the fit depends only on the order of the
projections, so its minimum is reached on an arc of directions and, as in the paper, we take
the arc's middle ("the mean value of u"). Speed from the staircase along u: the slope γ of the
clipped ramp fitted to the counters against s·u (as for the plane), |v| = 1/(γ·Δt).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import isotonic_regression

from bintrack.trackers.motion.closer_farther import TWO_PI, VelocityFit, counters, unit_vector
from bintrack.trackers.motion.velocity_plane import clipped_fit


def _isotonic_sse(count: np.ndarray, projections: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best non-decreasing fit of ``count`` against each row of
    ``projections`` (M, N) (ties in the projection broken by sensor order)."""
    order = np.argsort(projections, axis=1, kind="stable")
    sse = np.empty(len(projections))
    for m, idx in enumerate(order):
        y = count[idx]
        sse[m] = float(((y - isotonic_regression(y).x) ** 2).sum())
    return sse


def _middle_of_best_run(angles: np.ndarray, best: np.ndarray, widths: np.ndarray) -> float:
    """Middle angle (rad) of the longest circular run of consecutive ``best`` intervals; interval
    m is centred at ``angles[m]`` with width ``widths[m]`` (angles sorted, covering the circle
    or an arc of it)."""
    m = len(angles)
    if best.all():
        return float(angles[0])
    # rotate so that the sequence starts just after a non-best entry: runs do not wrap
    shift = int(np.flatnonzero(~best)[0]) + 1
    order = np.roll(np.arange(m), -shift)
    runs: list[tuple[float, int, int]] = []
    start = None
    for pos, idx in enumerate(order):
        if best[idx] and start is None:
            start = pos
        if start is not None and (not best[idx] or pos == m - 1):
            end = pos if best[idx] else pos - 1
            members = order[start:end + 1]
            runs.append((float(widths[members].sum()), start, end))
            start = None
    _, start, end = max(runs, key=lambda r: (r[0], -r[1]))
    members = order[start:end + 1]
    # the arc from the first member's lower edge to the last member's upper edge
    lo = angles[members[0]] - widths[members[0]] / 2
    hi = angles[members[-1]] + widths[members[-1]] / 2
    if hi < lo:
        hi += TWO_PI
    return float(((lo + hi) / 2) % TWO_PI)


def ppr_direction(positions: np.ndarray, count: np.ndarray, grid: int = 720) -> float | None:
    """Heading (rad) u maximising the fit of ``count`` by a non-decreasing function of s·u
    (paper 002 §III.C, the PPR direction step).

    The isotonic least-squares fit depends on u only through the order of the projections s·u,
    so the criterion is piecewise constant in the angle and changes only where two sensors of
    different counters swap order. We scan ``grid`` equally spaced angles, then examine every
    order change within one grid step of the best run exactly, and return the middle of the
    best arc (the paper's "mean value of u" among the optimal ones). None when all counters
    are equal (no information)."""
    positions = np.asarray(positions, dtype=float)
    count = np.asarray(count, dtype=float)
    if len(count) < 2 or np.all(count == count[0]):
        return None
    centred = positions - positions.mean(axis=0)
    step = TWO_PI / grid
    theta = np.arange(grid) * step
    sse = _isotonic_sse(count, unit_vector(theta) @ centred.T)
    tol = 1e-9 * max(1.0, float(sse.min()))
    coarse = _middle_of_best_run(theta, sse <= sse.min() + tol, np.full(grid, step))
    # exact refinement: the order changes at angles φ with (s_i − s_j)·u(φ) = 0
    on = sse <= sse.min() + tol
    half_width = (np.count_nonzero(on) if not on.all() else grid) * step / 2 + 2 * step
    half_width = min(half_width, math.pi)
    i, j = np.triu_indices(len(count), k=1)
    differ = count[i] != count[j]
    d = centred[i[differ]] - centred[j[differ]]
    phi = np.arctan2(d[:, 1], d[:, 0]) + math.pi / 2
    critical = np.concatenate([phi, phi + math.pi])
    rel = (critical - coarse + math.pi) % TWO_PI - math.pi
    rel = np.unique(rel[np.abs(rel) < half_width])
    edges = np.concatenate([[-half_width], rel, [half_width]])
    widths = np.diff(edges)
    keep = widths > 1e-12
    mids = ((edges[:-1] + edges[1:]) / 2)[keep]
    widths = widths[keep]
    fine = _isotonic_sse(count, unit_vector(coarse + mids) @ centred.T)
    best = fine <= fine.min() + 1e-9 * max(1.0, float(fine.min()))
    if fine.min() > sse.min() + tol:  # cannot happen unless the arc was mis-located; keep the scan
        return coarse
    # within the local window, runs do not wrap: pick the widest run of best intervals
    best_run = (0.0, 0, 0)
    start = None
    for m in range(len(mids) + 1):
        if m < len(mids) and best[m]:
            start = m if start is None else start
        elif start is not None:
            width = float(widths[start:m].sum())
            if width > best_run[0]:
                best_run = (width, start, m - 1)
            start = None
    _, a, b = best_run
    lo = mids[a] - widths[a] / 2
    hi = mids[b] + widths[b] / 2
    return float((coarse + (lo + hi) / 2) % TWO_PI)


def staircase_speed(positions: np.ndarray, labels: np.ndarray, heading: float, period: float,
                    loss: str = "soft_l1", f_scale: float = 1.0) -> float | None:
    """Speed (units/s) from the staircase along a known heading u (paper 002 §III.C, the speed
    step): the counters are fit by the ramp clip(γ·(s·u) + c, 0, K) (robust least squares as in
    :func:`velocity_plane`, saturated sensors as bounds) and γ = 1/(|v|·Δt). None with fewer
    than two distinct unsaturated projections or a ramp that does not rise."""
    labels = np.asarray(labels)
    k = labels.shape[0]
    count = counters(labels).astype(float)
    inner = (count > 0) & (count < k)
    p = np.asarray(positions, dtype=float) @ unit_vector(heading)
    if inner.sum() < 2 or np.ptp(p[inner]) <= 0:
        return None
    centre, scale = float(p.mean()), float(p.std()) or 1.0
    design = np.column_stack([(p - centre) / scale, np.ones(len(p))])
    start = np.linalg.lstsq(design[inner], count[inner], rcond=None)[0]
    if start[0] <= 0:  # the unsaturated sensors alone do not rise: start from the class split
        start = np.array([k / max(np.ptp(design[:, 0]), 1e-12), k / 2.0])
    slope = clipped_fit(design, count, k, start, loss, f_scale)[0] / scale
    if not math.isfinite(slope) or slope <= 0:
        return None
    return float(1.0 / (slope * period))


def ppr_fit(positions: np.ndarray, labels: np.ndarray, period: float, grid: int = 720) -> VelocityFit | None:
    """Velocity by projection pursuit regression (paper 002 §III.C): heading from
    :func:`ppr_direction` on the counters of all sensors, speed from :func:`staircase_speed`."""
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.shape[0] < 2:
        return None
    heading = ppr_direction(positions, counters(labels), grid)
    if heading is None:
        return None
    speed = staircase_speed(positions, labels, heading, period)
    if speed is None:
        return None
    return VelocityFit.from_heading(heading, speed)
