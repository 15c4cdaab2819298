"""The velocity plane of paper 002 §III.A: per-sensor counters of +1 periods form a staircase
over the sensor's projection on the heading; its tangent plane c ≈ g·s + c₀, fitted robustly
(``scipy.optimize.least_squares``, soft-L1 loss) to the sensors whose counter is neither 0
nor K (the saturated ones kept as bounds), gives heading g/|g| and speed 1/(|g|·Δt) (the
paper's v = 1/(tan θ·Δt)).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from bintrack.trackers.motion.closer_farther import VelocityFit, counters, full_rank, normaliser


def clipped_fit(design: np.ndarray, count: np.ndarray, k: int, start: np.ndarray, loss: str,
                f_scale: float) -> np.ndarray:
    """Robust least squares of ``count`` by clip(design·p, 0, k): the staircase's tangent plane
    (or ramp) with the saturated sensors (counter 0 or k) kept as bounds — a sensor ahead of the
    whole window must lie where the plane is at least k, one behind it where the plane is ≤ 0."""

    def residual(p):
        return np.clip(design @ p, 0.0, k) - count

    def jac(p):
        f = design @ p
        return design * ((f > 0.0) & (f < k))[:, None]

    return least_squares(residual, start, jac=jac, loss=loss, f_scale=f_scale).x


def velocity_plane(positions: np.ndarray, labels: np.ndarray, period: float,
                   loss: str = "soft_l1", f_scale: float = 1.0) -> VelocityFit | None:
    """Velocity from the tangent plane of the counters' staircase (paper 002 §III.A).

    With constant velocity, sensor s reports +1 while the target's projection on the heading u
    is below s·u, so its counter over K periods is ⌈(s·u − x₀·u)/(|v|Δt)⌉ clipped to [0, K]:
    a staircase whose tangent plane c = g·s + c₀ has g = u/(|v|·Δt). We fit clip(g·s + c₀, 0, K)
    to every sensor's counter by robust least squares (``least_squares`` with ``loss`` and
    ``f_scale`` in counts; the staircase's rounding is ±0.5 count), started from the ordinary
    least-squares plane of the sensors with 0 < counter < K; the saturated sensors act as
    bounds, which keeps short windows (few sensors changed sign) from tilting the plane. Then
    heading = g/|g| and speed = 1/(|g|·``period``) (units/s). None when fewer than three
    unsaturated sensors, all on one line, or a flat plane."""
    positions = np.asarray(positions, dtype=float)
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.shape[0] < 2:
        return None
    k = labels.shape[0]
    count = counters(labels).astype(float)
    inner = (count > 0) & (count < k)
    if not full_rank(positions[inner]):
        return None
    centre, scale = normaliser(positions)
    design = np.column_stack([(positions - centre) / scale, np.ones(len(positions))])
    start = np.linalg.lstsq(design[inner], count[inner], rcond=None)[0]
    fit = clipped_fit(design, count, k, start, loss, f_scale)
    gradient = fit[:2] / scale  # counts per unit
    norm = float(np.hypot(*gradient))
    if not math.isfinite(norm) or norm <= 0.0:
        return None
    return VelocityFit.from_heading(math.atan2(gradient[1], gradient[0]), 1.0 / (norm * period))
