"""Piecewise-linear trajectory from weighted location estimates (paper 001 §3.2.4, §5.5).

A node caches the last ``k`` estimates, splits them from the oldest into groups of ``n``,
fits the first group with the weighted least-squares line (eq. 3, weight eq. 2 or 4), then
compares it with the line of the next group: while the two directions differ by less than
``eps`` the trajectory has not turned and the group joins the current segment (which is
refitted); otherwise the group starts a new segment.

Two departures from the letter of eq. 3, both for lines of any direction: the fit is the
weighted *orthogonal* least-squares line (eq. 3 minimises vertical offsets y − a·x − b, which
fails for steep paths), and ``eps`` compares direction angles (rad) rather than slopes a — the
two agree for the near-horizontal lines where slopes are well defined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_CACHE = 30  # k
DEFAULT_GROUP = 6  # n
DEFAULT_EPS = 0.2  # ε


@dataclass(frozen=True)
class Line:
    """A weighted orthogonal least-squares line: ``centre`` (units) and unit ``direction``,
    oriented along the time order of its points."""

    centre: np.ndarray
    direction: np.ndarray

    def project(self, xy: np.ndarray) -> np.ndarray:
        """Arc length (units) of the projections of ``xy`` on the line, from ``centre``."""
        return (np.asarray(xy, dtype=float) - self.centre) @ self.direction

    def point(self, s) -> np.ndarray:
        return self.centre + np.multiply.outer(np.asarray(s, dtype=float), self.direction)

    @property
    def angle(self) -> float:
        """Direction of travel, rad in (−π, π]."""
        return float(np.arctan2(self.direction[1], self.direction[0]))


def fit_line(xy: np.ndarray, weights: np.ndarray) -> Line:
    """The line minimising Σ w_i · dist(p_i, line)² (weighted eq. 3), oriented from the first
    point towards the last. ``xy`` (units) in time order, ``weights`` ≥ 0, not all 0."""
    xy = np.asarray(xy, dtype=float)
    w = np.asarray(weights, dtype=float)
    if len(xy) < 2 or not w.sum() > 0:
        raise ValueError("a line needs at least two points with positive total weight")
    centre = (w[:, None] * xy).sum(axis=0) / w.sum()
    centred = (xy - centre) * np.sqrt(w)[:, None]
    direction = np.linalg.svd(centred, full_matrices=False)[2][0]
    if (xy[-1] - xy[0]) @ direction < 0:
        direction = -direction
    return Line(centre, direction)


def _angle_between(a: Line, b: Line) -> float:
    return float(abs(np.angle(np.exp(1j * (a.angle - b.angle)))))


def segment_groups(xy: np.ndarray, weights: np.ndarray, group: int = DEFAULT_GROUP,
                   eps: float = DEFAULT_EPS) -> list[slice]:
    """The runs of points (as slices of ``xy``) that §3.2.4 fits with one line each."""
    if group < 2:
        raise ValueError("groups need at least two points")
    n = len(xy)
    if n < 2:
        return []
    starts = list(range(0, n, group))
    if len(starts) > 1 and n - starts[-1] < 2:
        starts.pop()  # a lone last point joins the group before it
    bounds = [(s, starts[i + 1] if i + 1 < len(starts) else n) for i, s in enumerate(starts)]
    runs: list[slice] = []
    current = slice(*bounds[0])
    line = fit_line(xy[current], weights[current])
    for lo, hi in bounds[1:]:
        candidate = fit_line(xy[lo:hi], weights[lo:hi])
        if _angle_between(line, candidate) < eps:
            current = slice(current.start, hi)
            line = fit_line(xy[current], weights[current])
        else:
            runs.append(current)
            current = slice(lo, hi)
            line = candidate
    runs.append(current)
    return runs


def fit_trajectory(xy: np.ndarray, weights: np.ndarray, cache: int = DEFAULT_CACHE, group: int = DEFAULT_GROUP,
                   eps: float = DEFAULT_EPS) -> np.ndarray:
    """The estimated trajectory through the last ``cache`` estimates as a polyline (units).

    Each run of :func:`segment_groups` is fitted by a line and spans its points' projections;
    consecutive segments are joined where their lines cross when that lies between them, else
    end to end. ``xy`` are location estimates in time order, ``weights`` their eq. 2/4 weights.
    """
    xy = np.asarray(xy, dtype=float)[-cache:]
    weights = np.asarray(weights, dtype=float)[-cache:]
    runs = segment_groups(xy, weights, group, eps)
    if not runs:
        return xy.copy()
    pieces = []
    for run in runs:
        line = fit_line(xy[run], weights[run])
        s = line.project(xy[run])
        pieces.append((line, line.point(s.min()), line.point(s.max())))
    vertices = [pieces[0][1]]
    for (a, _, a_end), (b, b_start, _) in zip(pieces, pieces[1:]):
        vertices.append(_join(a, a_end, b, b_start))
    vertices.append(pieces[-1][2])
    return np.array(vertices)


def _join(a: Line, a_end: np.ndarray, b: Line, b_start: np.ndarray) -> np.ndarray:
    """Where segment a (ending at a_end) meets segment b (starting at b_start)."""
    matrix = np.column_stack([a.direction, -b.direction])
    if abs(np.linalg.det(matrix)) > 1e-9:
        s, _ = np.linalg.solve(matrix, b.centre - a.centre)
        crossing = a.point(s)
        gap = np.linalg.norm(a_end - b_start)
        if np.linalg.norm(crossing - a_end) <= gap + 1e-9 or np.linalg.norm(crossing - b_start) <= gap + 1e-9:
            return crossing
    return (a_end + b_start) / 2
