"""Piecewise-linear trajectory from weighted location estimates (paper 001 §3.2.4, §3.3.4, §5.5).

The paper (§3.2.4): a node caches ``k`` estimates, splits them from the oldest into groups of
``n``, fits the first group with the weighted least-squares line (eq. 3, weight eq. 2 or 4) and
compares its slope with the line of the next group; while the two differ by less than ``eps``
there is no turn and the group joins the current segment (which is refitted), otherwise the
group starts a new segment. §5.5 uses k = 30, n = 6, ε = 0.2.

What is implemented here keeps k, n, ε and the group-by-group segmentation, with these stated
departures from the letter of §3.2.4:

1. **Orthogonal fit, angles.** The fit is the weighted *orthogonal* least-squares line (eq. 3
   minimises vertical offsets y − a·x − b, which fails for steep paths) and ``eps`` compares
   direction angles (rad) rather than slopes a; the two agree for near-horizontal lines.

2. **The turn test looks at two groups, not one.** On the arc tracker's estimates the eq. 2
   weights span two orders of magnitude (8 … 650 at R = 40), so the line of one group of 6
   rests on its one or two heaviest estimates, and the estimates of one group come from a few
   neighbouring nodes whose errors are correlated; the literal test then finds 6–10 false turns
   on a straight path. Here the candidate direction is that of the line through the *two* most
   recent groups (2n estimates, about twice the baseline): a group is held pending until the
   next one arrives; if the line through both turns away from the current segment, the turn is
   declared and the two groups start the new segment (less the part of the pending group that
   item 4 gives back to the old one), else the pending group joins the current segment and the
   new one becomes pending. A turn must therefore persist over two groups. The first segment
   is born from the first two groups.

3. **A turn must also be significant.** Besides differing by more than ``eps``, the angle
   between the candidate line and the segment's line must exceed ``z`` standard errors.
   Noise model: the estimate lies on its final arc, within R·arc/2 = π·R/w of the target
   (w = 2π/arc, eq. 2), so its error scales as 1/w: σ_i = c / w_i. For the weighted line
   (weights w_i, as eq. 3) the variance of its direction is then
   c² · Σ s_i² / (Σ w_i s_i²)², s_i the along-line positions about the weighted centre (units),
   for the segment (over its cached estimates) and for the candidate; the two variances add.
   c (units) is estimated robustly from the segment's cached estimates as
   median |w_i · d_i| / 0.6745, d_i their perpendicular offsets from the segment's line —
   a median because under the imperfect model a few estimates carry eq. 4 weights that
   their errors do not justify. With noise-free points c = 0 and the test reduces to the ε test. ``z`` = 3 is the
   default: errors within a group are correlated, so the standard error computed as if they
   were independent is optimistic, and a generous z compensates.

4. **The turn point is refined.** When a turn is declared the pending group usually straddles
   it. Its estimates are split between the old segment and the new one where the weighted
   squared distances (eq. 3's Q) to the old line and to the line refitted to the rest are
   least (a change-point search over the n + 1 possible splits), so the new segment starts
   where the path actually turned.

5. **Assembly over time, memory bounded by the cache.** A node sees its estimates as a stream;
   a segment grows group by group while there is no turn, for as long as that lasts. Its line
   is the weighted orthogonal fit to *all* its estimates, kept as six running weighted moments
   (Σw, Σwx, Σwy, Σwx², Σwxy, Σwy²), so that a long straight run is fitted as one line; the
   cache holds the current segment's last ``k`` estimates (and its first n, for where it
   starts) for the noise scale and the turn test. A finished segment keeps its moments and its
   first and last n estimates (for its ends). Consecutive segments are joined where their
   lines cross when that lies between them, else end to end.
   :func:`trajectory_from_estimates` runs this over a whole stream; :func:`fit_trajectory`
   over only the last ``k`` estimates (what a node's cache alone gives).

6. **Turns are checked again on the full lines.** When a segment is finished, and when the
   trajectory is read, a segment whose line (fitted to all its estimates) differs from the
   previous segment's by less than ``eps`` is merged into it: by the §3.2.4 criterion there
   was no turn. (The test of item 2 compares the segment with a line through 2n estimates
   only; the merged line is the better-determined one.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DEFAULT_CACHE = 30  # k
DEFAULT_GROUP = 6  # n
DEFAULT_EPS = 0.2  # ε, rad
DEFAULT_Z = 3.0  # significance of a turn, standard errors

_MAD_TO_SIGMA = 0.6745  # median |x| of a standard normal


@dataclass(frozen=True)
class Line:
    """A weighted orthogonal least-squares line: ``centre`` (units) and unit ``direction``,
    oriented along the time order of its points."""

    centre: np.ndarray
    direction: np.ndarray

    def project(self, xy: np.ndarray) -> np.ndarray:
        """Arc length (units) of the projections of ``xy`` on the line, from ``centre``."""
        return (np.asarray(xy, dtype=float) - self.centre) @ self.direction

    def offset(self, xy: np.ndarray) -> np.ndarray:
        """Signed perpendicular distance (units) of ``xy`` from the line, positive on its left."""
        normal = np.array([-self.direction[1], self.direction[0]])
        return (np.asarray(xy, dtype=float) - self.centre) @ normal

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


def direction_variance(line: Line, xy: np.ndarray, weights: np.ndarray) -> float:
    """Variance (rad² per unit² of c²) of the direction of ``line``, fitted to ``xy`` with
    ``weights`` (eq. 3), when estimate i has perpendicular error σ_i = c / w_i:
    Σ s_i² / (Σ w_i s_i²)², s_i the along-line positions about the weighted centre (units).
    Infinite when the points do not spread along the line."""
    w = np.asarray(weights, dtype=float)
    s = line.project(xy)
    s = s - (w * s).sum() / w.sum()
    spread = (w * s * s).sum()
    return float((s * s).sum() / spread**2) if spread > 0 else float("inf")


def noise_scale(line: Line, xy: np.ndarray, weights: np.ndarray) -> float:
    """Robust estimate of c (units) in σ_i = c / w_i from the offsets d_i of ``xy`` from
    ``line``: median |w_i · d_i| / 0.6745."""
    return float(np.median(np.abs(np.asarray(weights, dtype=float) * line.offset(xy))) / _MAD_TO_SIGMA)


def _angle_between(a: float, b: float) -> float:
    return float(abs(np.angle(np.exp(1j * (a - b)))))


@dataclass
class _Segment:
    """One segment being grown: running weighted moments of all its estimates (about the
    first one, for conditioning), its first ``group`` estimates and its last ``cache``."""

    start: int  # index of its first estimate in the stream
    cache: int
    group: int
    origin: np.ndarray = field(default=None)
    moments: np.ndarray = field(default_factory=lambda: np.zeros(6))
    count: int = 0
    first_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    w: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add(self, xy: np.ndarray, w: np.ndarray) -> None:
        if len(xy) == 0:
            return
        if self.origin is None:
            self.origin = xy[0].copy()
        p = xy - self.origin
        self.moments += [w.sum(), (w * p[:, 0]).sum(), (w * p[:, 1]).sum(), (w * p[:, 0] ** 2).sum(),
                         (w * p[:, 0] * p[:, 1]).sum(), (w * p[:, 1] ** 2).sum()]
        self.count += len(xy)
        if len(self.first_xy) < self.group:
            self.first_xy = np.vstack([self.first_xy, xy])[: self.group]
        self.xy = np.vstack([self.xy, xy])[-self.cache:]
        self.w = np.concatenate([self.w, w])[-self.cache:]

    @property
    def end(self) -> int:
        return self.start + self.count

    def _trimmed(self) -> _Segment:
        """A finished copy keeping only its last ``group`` estimates (its end) besides the moments
        and the first ones."""
        return _Segment(self.start, self.cache, self.group, self.origin.copy(), self.moments.copy(), self.count,
                        self.first_xy.copy(), self.xy[-self.group:].copy(), self.w[-self.group:].copy())

    def merged(self, later: _Segment) -> _Segment:
        """This segment and the ``later`` one that follows it as one segment (their moments
        summed about this one's origin)."""
        total, sx, sy, sxx, sxy, syy = later.moments
        dx, dy = later.origin - self.origin
        shifted = np.array([total, sx + dx * total, sy + dy * total, sxx + 2 * dx * sx + dx * dx * total,
                            sxy + dx * sy + dy * sx + dx * dy * total, syy + 2 * dy * sy + dy * dy * total])
        return _Segment(self.start, self.cache, self.group, self.origin.copy(), self.moments + shifted,
                        self.count + later.count, np.vstack([self.first_xy, later.first_xy])[: self.group],
                        np.vstack([self.xy, later.xy])[-self.cache:], np.concatenate([self.w, later.w])[-self.cache:])

    def line(self) -> Line:
        """The weighted orthogonal least-squares line of all the segment's estimates (eq. 3),
        oriented from its first estimate towards its last."""
        total, sx, sy, sxx, sxy, syy = self.moments
        if self.count < 2 or not total > 0:
            raise ValueError("a line needs at least two points with positive total weight")
        mx, my = sx / total, sy / total
        cov = np.array([[sxx / total - mx * mx, sxy / total - mx * my],
                        [sxy / total - mx * my, syy / total - my * my]])
        direction = np.linalg.eigh(cov)[1][:, -1]
        if (self.xy[-1] - self.first_xy[0]) @ direction < 0:
            direction = -direction
        return Line(self.origin + [mx, my], direction)

    def piece(self) -> tuple[Line, np.ndarray, np.ndarray]:
        """Its line and the two ends (units): the extreme projections of its first and last
        cached estimates."""
        line = self.line()
        s = np.concatenate([line.project(self.first_xy), line.project(self.xy)])
        return line, line.point(s.min()), line.point(s.max())


class TrajectoryFitter:
    """The trajectory estimate of one node, fed its estimates in time order (see the module
    docstring for the rules). ``cache`` = k, ``group`` = n, ``eps`` = ε (rad), ``z`` the
    significance of a turn (standard errors; 0 disables the check)."""

    def __init__(self, cache: int = DEFAULT_CACHE, group: int = DEFAULT_GROUP, eps: float = DEFAULT_EPS,
                 z: float = DEFAULT_Z):
        if group < 2:
            raise ValueError("groups need at least two points")
        if cache < 2 * group:
            raise ValueError("the cache must hold at least two groups")
        self.cache, self.group, self.eps, self.z = cache, group, eps, z
        self._done: list[_Segment] = []
        self._current: _Segment | None = None
        self._pending: tuple[np.ndarray, np.ndarray] | None = None  # one group awaiting the next
        self._filling: list[tuple[float, float, float]] = []  # the group being collected

    def add(self, x: float, y: float, weight: float) -> None:
        """One estimate (units) with its eq. 2/4 weight (> 0)."""
        if not (weight > 0 and np.isfinite(weight)):
            raise ValueError("weights must be positive and finite")
        self._filling.append((float(x), float(y), float(weight)))
        if len(self._filling) == self.group:
            self._take_group()

    def _take_group(self) -> None:
        block = np.array(self._filling, dtype=float)
        self._filling = []
        group = (block[:, :2], block[:, 2])
        if self._pending is None:
            self._pending = group
            return
        if self._current is None:  # the first segment is born from two groups
            self._current = _Segment(0, self.cache, self.group)
            self._current.add(*self._pending)
            self._current.add(*group)
            self._pending = None
            return
        self._test(group)

    def _is_turn(self, candidate: Line, xy: np.ndarray, w: np.ndarray) -> bool:
        segment = self._current
        line = segment.line()
        angle = _angle_between(candidate.angle, line.angle)
        if not angle > self.eps:
            return False
        if self.z <= 0:
            return True
        c = noise_scale(line, segment.xy, segment.w)
        if c == 0:  # noise-free: the ε test alone
            return True
        sd = c * np.sqrt(direction_variance(candidate, xy, w) + direction_variance(line, segment.xy, segment.w))
        return bool(angle > self.z * sd)

    def _test(self, group: tuple[np.ndarray, np.ndarray]) -> None:
        pending_xy, pending_w = self._pending
        xy = np.vstack([pending_xy, group[0]])
        w = np.concatenate([pending_w, group[1]])
        candidate = fit_line(xy, w)
        if not self._is_turn(candidate, xy, w):
            self._current.add(pending_xy, pending_w)
            self._pending = group
            return
        split = self._split(self._current.line(), pending_xy, pending_w, group)
        self._current.add(pending_xy[:split], pending_w[:split])
        self._done = self._closed(self._done, self._current)
        self._current = _Segment(self._current.end, self.cache, self.group)
        self._current.add(pending_xy[split:], pending_w[split:])
        self._current.add(*group)
        self._pending = None

    @staticmethod
    def _split(old: Line, xy: np.ndarray, w: np.ndarray, after: tuple[np.ndarray, np.ndarray]) -> int:
        """How many of the pending estimates ``xy`` still belong to the old segment: the split j
        minimising Σ w·d² of the first j to the ``old`` line plus the least Σ w·d² of the rest
        together with the estimates ``after`` them to their own line (a change-point search)."""
        to_old = np.concatenate([[0.0], np.cumsum(w * old.offset(xy) ** 2)])
        costs = []
        for j in range(len(xy) + 1):
            rest_xy = np.vstack([xy[j:], after[0]])
            rest_w = np.concatenate([w[j:], after[1]])
            if len(rest_xy) < 2:
                costs.append(np.inf)
                continue
            line = fit_line(rest_xy, rest_w)
            costs.append(to_old[j] + (rest_w * line.offset(rest_xy) ** 2).sum())
        return int(np.argmin(costs))

    def _closed(self, done: list[_Segment], segment: _Segment) -> list[_Segment]:
        """``done`` with ``segment`` appended, or merged into the last one when their lines,
        both fitted to all their estimates, differ by less than ``eps`` after all: no turn
        by the §3.2.4 criterion (the turn test compared against a short candidate line)."""
        if done and _angle_between(done[-1].line().angle, segment.line().angle) < self.eps:
            return done[:-1] + [done[-1].merged(segment)._trimmed()]
        return done + [segment._trimmed()]

    def _segments(self) -> list[_Segment]:
        """The segments with everything seen so far, the last partial group and a pending
        group included (a lone pending group is tested against the current segment)."""
        done, current, pending = list(self._done), self._current, self._pending
        tail = np.array(self._filling, dtype=float).reshape(-1, 3)
        if pending is not None and len(tail):
            pending = (np.vstack([pending[0], tail[:, :2]]), np.concatenate([pending[1], tail[:, 2]]))
        elif len(tail):
            pending = (tail[:, :2], tail[:, 2])
        if pending is None:
            return self._closed(done, current) if current is not None else done
        if current is None:
            segment = _Segment(0, self.cache, self.group)
            segment.add(*pending)
            return [segment] if segment.count >= 2 else []
        # copy the current segment so that reading the trajectory does not change the state
        current = _copy_segment(current)
        if len(pending[0]) >= 2 and self._turns_alone(current, pending):
            split = self._split(current.line(), *pending, (np.zeros((0, 2)), np.zeros(0)))
            current.add(pending[0][:split], pending[1][:split])
            rest = (pending[0][split:], pending[1][split:])
            if len(rest[0]) >= 2:
                new = _Segment(current.end, self.cache, self.group)
                new.add(*rest)
                return self._closed(self._closed(done, current), new)
            current.add(*rest)
            return self._closed(done, current)
        current.add(*pending)
        return self._closed(done, current)

    def _turns_alone(self, current: _Segment, pending: tuple[np.ndarray, np.ndarray]) -> bool:
        saved = self._current
        self._current = current
        try:
            return self._is_turn(fit_line(*pending), *pending)
        finally:
            self._current = saved

    def runs(self) -> list[slice]:
        """The estimates (as slices of the stream) that each segment is fitted to."""
        return [slice(s.start, s.end) for s in self._segments()]

    def polyline(self) -> np.ndarray:
        """The trajectory so far: the polyline (units, (m, 2)) through the segments' ends and
        their joins; the estimates themselves when there are fewer than two."""
        segments = self._segments()
        if not segments:
            tail = np.array(self._filling, dtype=float).reshape(-1, 3)[:, :2]
            return tail.copy()
        pieces = [s.piece() for s in segments]
        vertices = [pieces[0][1]]
        for (a, _, a_end), (b, b_start, _) in zip(pieces, pieces[1:]):
            vertices.append(_join(a, a_end, b, b_start))
        vertices.append(pieces[-1][2])
        return np.array(vertices)


def _copy_segment(segment: _Segment) -> _Segment:
    copy = _Segment(segment.start, segment.cache, segment.group, segment.origin, segment.moments.copy(),
                    segment.count, segment.first_xy.copy(), segment.xy.copy(), segment.w.copy())
    return copy


def _fitter(xy: np.ndarray, weights: np.ndarray, cache: int, group: int, eps: float, z: float) -> TrajectoryFitter:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    weights = np.asarray(weights, dtype=float)
    if len(weights) != len(xy):
        raise ValueError("one weight per estimate")
    fitter = TrajectoryFitter(cache, group, eps, z)
    for (x, y), w in zip(xy, weights):
        fitter.add(x, y, w)
    return fitter


def trajectory_from_estimates(xy: np.ndarray, weights: np.ndarray, k: int = DEFAULT_CACHE, n: int = DEFAULT_GROUP,
                              eps: float = DEFAULT_EPS, z: float = DEFAULT_Z) -> np.ndarray:
    """The whole trajectory (units, polyline (m, 2)) a node builds from its stream of estimates
    ``xy`` (units, time order) with their eq. 2/4 ``weights``: §3.2.4 with cache ``k``, groups
    of ``n``, turn threshold ``eps`` (rad) and turn significance ``z`` (module docstring)."""
    return _fitter(xy, weights, k, n, eps, z).polyline()


def segment_groups(xy: np.ndarray, weights: np.ndarray, group: int = DEFAULT_GROUP,
                   eps: float = DEFAULT_EPS, z: float = DEFAULT_Z) -> list[slice]:
    """The runs of points (as slices of ``xy``) that the §3.2.4 fit (as amended in the module
    docstring) fits with one line each, all of ``xy`` being in the cache."""
    if group < 2:
        raise ValueError("groups need at least two points")
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) < 2:
        return []
    return _fitter(xy, weights, max(len(xy), 2 * group), group, eps, z).runs()


def fit_trajectory(xy: np.ndarray, weights: np.ndarray, cache: int = DEFAULT_CACHE, group: int = DEFAULT_GROUP,
                   eps: float = DEFAULT_EPS, z: float = DEFAULT_Z) -> np.ndarray:
    """The estimated trajectory through the last ``cache`` estimates only (what a node's cache
    alone gives) as a polyline (units). ``xy`` are location estimates in time order,
    ``weights`` their eq. 2/4 weights."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)[-cache:]
    weights = np.asarray(weights, dtype=float)[-cache:]
    if len(xy) < 2:
        return xy.copy()
    return _fitter(xy, weights, max(cache, 2 * group), group, eps, z).polyline()


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
