"""Plane geometry for binary sensors: angles, circle intersections and crossing times.

Lengths are in deployment units (m, ft or unit), angles in radians measured counter-clockwise
from +x, times in seconds. A *linear segment* is the motion ``p(τ) = p0 + v·τ`` for
``0 ≤ τ ≤ duration``; a *circular arc* is ``p(τ) = centre + ρ·(cos φ, sin φ)`` with
``φ = φ0 + ω·τ`` (ω signed, rad/s). Crossing-time functions return the sorted times τ,
relative to the start of the motion, at which it meets a curve: a sensing circle, a sector
boundary (a ray from the sensor, only within the sensing radius) or a beam ``a·x + b·y = 1``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

TWO_PI = 2.0 * math.pi

# Roots this close outside [0, duration] (relative) are rounding, kept and clipped.
_REL_TOL = 1e-12

Vec = Sequence[float] | np.ndarray


def normalize_angle(theta):
    """``theta`` (rad, scalar or array) wrapped into [0, 2π)."""
    wrapped = np.mod(theta, TWO_PI)
    # mod of a tiny negative number rounds to exactly 2π
    wrapped = np.where(wrapped >= TWO_PI, 0.0, wrapped)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def circle_circle_intersections(c1: Vec, r1: float, c2: Vec, r2: float) -> np.ndarray:
    """Intersection points of two circles (centres ``c1``, ``c2``, radii ``r1``, ``r2``).

    Returns an array of shape (k, 2): k = 0 (apart, nested or concentric), 1 (tangent) or 2,
    the two points ordered counter-clockwise as seen from ``c1`` across the line of centres.
    """
    x1, y1 = float(c1[0]), float(c1[1])
    dx, dy = float(c2[0]) - x1, float(c2[1]) - y1
    d = math.hypot(dx, dy)
    if d == 0.0 or d > r1 + r2 or d < abs(r1 - r2):
        return np.empty((0, 2))
    # distance from c1 along the line of centres to the chord, and the half chord
    along = (d * d + r1 * r1 - r2 * r2) / (2.0 * d)
    half = math.sqrt(max(r1 * r1 - along * along, 0.0))
    ux, uy = dx / d, dy / d
    mx, my = x1 + along * ux, y1 + along * uy
    if half == 0.0:
        return np.array([[mx, my]])
    return np.array([[mx + half * uy, my - half * ux], [mx - half * uy, my + half * ux]])


def circle_circle_angles(c1: Vec, r1: float, c2: Vec, r2: float) -> np.ndarray:
    """Angles in [0, 2π) on circle 1 (seen from ``c1``) of its intersections with circle 2."""
    points = circle_circle_intersections(c1, r1, c2, r2)
    return normalize_angle(np.arctan2(points[:, 1] - c1[1], points[:, 0] - c1[0]))


def _in_window(tau: np.ndarray, duration: float) -> np.ndarray:
    """The roots within [0, duration] (rounding slack allowed), clipped and sorted."""
    slack = _REL_TOL * max(1.0, abs(duration))
    tau = np.asarray(tau, dtype=float)
    tau = tau[(tau >= -slack) & (tau <= duration + slack)]
    return np.sort(np.clip(tau, 0.0, duration))


def segment_circle_times(p0: Vec, v: Vec, duration: float, centre: Vec, radius: float) -> np.ndarray:
    """Times τ in [0, duration] at which ``p0 + v·τ`` is at distance ``radius`` from ``centre``.

    Solved about the time of closest approach, τ* ± √(r² − h²)/|v| with h the miss distance
    (a quadratic, numerically stable for far-away circles). A tangent gives one time.
    """
    vx, vy = float(v[0]), float(v[1])
    speed2 = vx * vx + vy * vy
    if speed2 == 0.0:
        return np.empty(0)
    rx, ry = float(p0[0]) - float(centre[0]), float(p0[1]) - float(centre[1])
    t_star = -(rx * vx + ry * vy) / speed2
    h2 = (rx * vy - ry * vx) ** 2 / speed2
    gap = radius * radius - h2
    if gap < 0.0:
        return np.empty(0)
    half = math.sqrt(gap / speed2)
    roots = [t_star] if half == 0.0 else [t_star - half, t_star + half]
    return _in_window(np.array(roots), duration)


def segment_line_times(p0: Vec, v: Vec, duration: float, a: float, b: float) -> np.ndarray:
    """Times τ in [0, duration] at which ``p0 + v·τ`` is on the line a·x + b·y = 1 (paper 003 eq. 1)."""
    rate = a * float(v[0]) + b * float(v[1])
    if rate == 0.0:
        return np.empty(0)
    return _in_window(np.array([(1.0 - a * float(p0[0]) - b * float(p0[1])) / rate]), duration)


def segment_ray_times(p0: Vec, v: Vec, duration: float, origin: Vec, angle: float, length: float) -> np.ndarray:
    """Times τ in [0, duration] at which ``p0 + v·τ`` crosses the ray from ``origin`` at ``angle``.

    Only crossings within ``length`` of the origin count (a sector boundary inside the sensing
    radius). Motion along the ray itself never crosses it.
    """
    ux, uy = math.cos(angle), math.sin(angle)
    rx, ry = float(p0[0]) - float(origin[0]), float(p0[1]) - float(origin[1])
    vx, vy = float(v[0]), float(v[1])
    rate = vx * uy - vy * ux
    if rate == 0.0:
        return np.empty(0)
    tau = _in_window(np.array([-(rx * uy - ry * ux) / rate]), duration)
    along = (rx + vx * tau) * ux + (ry + vy * tau) * uy
    return tau[(along >= 0.0) & (along <= length)]


def harmonic_angles(A: float, B: float, C: float) -> np.ndarray:
    """Angles φ in [0, 2π) with A·cos φ + B·sin φ = C: none, one (tangent) or two, sorted."""
    amplitude = math.hypot(A, B)
    if amplitude == 0.0 or abs(C) > amplitude:
        return np.empty(0)
    base = math.atan2(B, A)
    spread = math.acos(max(-1.0, min(1.0, C / amplitude)))
    if spread == 0.0:
        return np.array([normalize_angle(base)])
    return np.sort(normalize_angle(np.array([base - spread, base + spread])))


def arc_angle_times(phi0: float, omega: float, duration: float, phis: np.ndarray) -> np.ndarray:
    """Times τ in [0, duration] at which φ0 + ω·τ ≡ φ (mod 2π) for any φ in ``phis``."""
    if omega == 0.0 or len(phis) == 0:
        return np.empty(0)
    first = normalize_angle(np.sign(omega) * (np.asarray(phis, dtype=float) - phi0)) / abs(omega)
    # an angle reached just before τ = 0 by rounding is reached at τ = 0
    first = np.where(first * abs(omega) > TWO_PI - 1e-12, 0.0, first)
    turn = TWO_PI / abs(omega)
    times = [first + k * turn for k in range(int(duration // turn) + 2)]
    return _in_window(np.concatenate(times), duration)


def arc_circle_times(centre: Vec, rho: float, phi0: float, omega: float, duration: float,
                     c: Vec, r: float) -> np.ndarray:
    """Times τ in [0, duration] at which the arc is at distance ``r`` from ``c``.

    |C + ρ·u(φ) − c|² = r² reduces to A·cos φ + B·sin φ = K, solved analytically.
    """
    dx, dy = float(centre[0]) - float(c[0]), float(centre[1]) - float(c[1])
    phis = harmonic_angles(2.0 * rho * dx, 2.0 * rho * dy, r * r - dx * dx - dy * dy - rho * rho)
    return arc_angle_times(phi0, omega, duration, phis)


def arc_line_times(centre: Vec, rho: float, phi0: float, omega: float, duration: float,
                   a: float, b: float) -> np.ndarray:
    """Times τ in [0, duration] at which the arc meets the line a·x + b·y = 1."""
    phis = harmonic_angles(a * rho, b * rho, 1.0 - a * float(centre[0]) - b * float(centre[1]))
    return arc_angle_times(phi0, omega, duration, phis)


def arc_ray_times(centre: Vec, rho: float, phi0: float, omega: float, duration: float,
                  origin: Vec, angle: float, length: float) -> np.ndarray:
    """Times τ in [0, duration] at which the arc crosses the ray from ``origin`` at ``angle``,
    within ``length`` of the origin."""
    ux, uy = math.cos(angle), math.sin(angle)
    dx, dy = float(centre[0]) - float(origin[0]), float(centre[1]) - float(origin[1])
    # cross(p − origin, u) = 0  ⇔  ρ·uy·cos φ − ρ·ux·sin φ = dy·ux − dx·uy
    phis = harmonic_angles(rho * uy, -rho * ux, dy * ux - dx * uy)
    tau = arc_angle_times(phi0, omega, duration, phis)
    phi = phi0 + omega * tau
    along = (dx + rho * np.cos(phi)) * ux + (dy + rho * np.sin(phi)) * uy
    return tau[(along >= 0.0) & (along <= length)]


def box_exit_distance(point: Vec, direction: Vec, xmin: float, ymin: float, xmax: float, ymax: float) -> float:
    """Distance from ``point`` (inside the box) along the unit ``direction`` to the box border."""
    best = math.inf
    for p, d, lo, hi in ((point[0], direction[0], xmin, xmax), (point[1], direction[1], ymin, ymax)):
        if d > 0:
            best = min(best, (hi - p) / d)
        elif d < 0:
            best = min(best, (lo - p) / d)
    return float(best)
