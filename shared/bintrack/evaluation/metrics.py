"""Scores of tracking results against truth: pure functions over rows of the §6 formats.

Positions and distances are in the dataset's units, times in s, velocities in units/s.

* location error (paper 001 §5.3): distance between an estimate and the real location, also
  divided by the sensing range R;
* velocity error (paper 001 §5.4): |v_est − v_true|, its average and maximum;
* trajectory error (paper 001 §5.5): area of the polygon formed by the estimated and the real
  trajectory divided by the length of the real trajectory;
* GOSPA (Rahmathullah, García-Fernández, Svensson, FUSION 2017) per scan, its localisation,
  missed and false parts, the error in the number of targets and identity switches, for the
  multi-target tracks of paper 004;
* entry and exit point errors of line-sensor objects (paper 003 §7.2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from scipy import stats
from scipy.optimize import linear_sum_assignment

from bintrack.formats import ObjectRow, TrackRow, TruthRow
from bintrack.deployment_model import Deployment, DiskSensor, SectorSensor

# truth.csv is written with µs resolution: an estimate within this of a target's first or last
# truth time still sees the target.
TIME_TOLERANCE = 1e-6


# --------------------------------------------------------------------------- truth


@dataclass(frozen=True, eq=False)
class TruthPath:
    """One target's real path: truth.csv rows linearly interpolated in time.

    ``t`` (s, strictly increasing) and ``xy`` (units, shape (n, 2)) are the truth rows. The
    target exists only from its first to its last truth time.
    """

    target: str
    t: np.ndarray
    xy: np.ndarray

    @property
    def start(self) -> float:
        return float(self.t[0])

    @property
    def end(self) -> float:
        return float(self.t[-1])

    @property
    def length(self) -> float:
        """Length of the whole real path, units."""
        return polyline_length(self.xy)

    def exists(self, t) -> np.ndarray:
        """Whether the target exists at time(s) ``t`` (s): a boolean array shaped like ``t``."""
        t = np.asarray(t, dtype=float)
        return (t >= self.start - TIME_TOLERANCE) & (t <= self.end + TIME_TOLERANCE)

    def position(self, t) -> np.ndarray:
        """Position(s) at time(s) ``t`` (s), units, shape ``t.shape + (2,)``; NaN where absent."""
        t = np.asarray(t, dtype=float)
        clipped = np.clip(t, self.start, self.end)
        out = np.stack([np.interp(clipped, self.t, self.xy[:, 0]), np.interp(clipped, self.t, self.xy[:, 1])], axis=-1)
        out[~self.exists(t)] = np.nan
        return out

    def velocity(self, t) -> np.ndarray:
        """True velocity at time(s) ``t``, units/s: the slope of the truth segment holding ``t``
        (the later segment at a truth time, the last one at the end); zero for a single row;
        NaN where the target does not exist. Shape ``t.shape + (2,)``."""
        t = np.asarray(t, dtype=float)
        if len(self.t) < 2:
            out = np.zeros(t.shape + (2,))
        else:
            slopes = np.diff(self.xy, axis=0) / np.diff(self.t)[:, None]
            index = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(slopes) - 1)
            out = slopes[index]
        out[~self.exists(t)] = np.nan
        return out

    def between(self, t0: float, t1: float) -> np.ndarray:
        """The real path from ``t0`` to ``t1`` (s, clipped to the target's life), units, (k, 2):
        interpolated end points and every truth point in between."""
        t0, t1 = max(t0, self.start), min(t1, self.end)
        inner = (self.t > t0) & (self.t < t1)
        ends = self.position(np.array([t0, t1]))
        return np.vstack([ends[:1], self.xy[inner], ends[1:]])


def truth_paths(rows: Iterable[TruthRow]) -> dict[str, TruthPath]:
    """Group truth.csv rows into one :class:`TruthPath` per target (a repeated time keeps its
    first row)."""
    by_target: dict[str, list[TruthRow]] = {}
    for row in rows:
        by_target.setdefault(row.target, []).append(row)
    paths = {}
    for target in sorted(by_target):
        target_rows = sorted(by_target[target], key=lambda r: r.t)
        t = np.array([r.t for r in target_rows], dtype=float)
        xy = np.array([(r.x, r.y) for r in target_rows], dtype=float)
        t, first = np.unique(t, return_index=True)
        paths[target] = TruthPath(target, t, xy[first])
    return paths


def sensing_range(deployment: Deployment) -> float | None:
    """The sensing range R (units) of paper 001 §5.3: the median ``range`` (R_out) of the disk
    and sector sensors, or None when there are none."""
    ranges = [s.range for s in deployment.sensors if isinstance(s, (DiskSensor, SectorSensor))]
    return float(np.median(ranges)) if ranges else None


def polyline_length(xy: np.ndarray) -> float:
    """Length of the polyline through the points ``xy`` (k, 2), units."""
    xy = np.asarray(xy, dtype=float)
    return float(np.hypot(*np.diff(xy, axis=0).T).sum()) if len(xy) > 1 else 0.0


# --------------------------------------------------------------------------- summaries


@dataclass(frozen=True)
class ErrorStats:
    """Count, mean, median and maximum of a set of errors (NaN values are left out)."""

    n: int
    mean: float | None
    median: float | None
    max: float | None

    @classmethod
    def of(cls, values) -> ErrorStats:
        values = np.asarray(values, dtype=float)
        values = values[~np.isnan(values)]
        if len(values) == 0:
            return cls(0, None, None, None)
        return cls(len(values), float(values.mean()), float(np.median(values)), float(values.max()))


# --------------------------------------------------------------------------- single target


def mean_ci(values, level: float = 0.95) -> tuple[float, float]:
    """Mean of ``values`` and the half-width of its Student-t confidence interval at ``level``
    (NaN with fewer than two values): the "mean ± CI over runs" of the papers' figures."""
    a = np.asarray(values, dtype=float)
    if len(a) < 2:
        return float(a.mean()), float("nan")
    half = stats.t.ppf(0.5 + level / 2, len(a) - 1) * a.std(ddof=1) / math.sqrt(len(a))
    return float(a.mean()), float(half)


def location_errors(rows: Sequence[TrackRow], paths: Mapping[str, TruthPath]) -> np.ndarray:
    """Location error of each estimate (paper 001 §5.3), units: the distance from the row's
    position to the nearest target existing at the row's time; NaN where no target exists.

    Divide by :func:`sensing_range` for the paper's error/R.
    """
    t = np.array([r.t for r in rows], dtype=float)
    xy = np.array([(r.x, r.y) for r in rows], dtype=float).reshape(-1, 2)
    best = np.full(len(rows), np.inf)
    for path in paths.values():
        distance = np.hypot(*(xy - path.position(t)).T)
        best = np.fmin(best, distance)  # fmin ignores the NaN of an absent target
    best[np.isinf(best)] = np.nan
    return best


def velocity_errors(rows: Sequence[TrackRow], path: TruthPath) -> np.ndarray:
    """|v_est − v_true| (units/s) of paper 001 §5.4 for each row that has ``vx`` and ``vy`` and
    falls within the target's life; the true velocity is the truth path's slope
    (:meth:`TruthPath.velocity`)."""
    rows = [r for r in rows if r.vx is not None and r.vy is not None and path.exists(r.t)]
    if not rows:
        return np.zeros(0)
    v_est = np.array([(r.vx, r.vy) for r in rows], dtype=float)
    v_true = path.velocity(np.array([r.t for r in rows], dtype=float))
    return np.hypot(*(v_est - v_true).T)


def heading_speed_errors(rows: Sequence[TrackRow], path: TruthPath) -> tuple[np.ndarray, np.ndarray]:
    """For each row with a velocity within the target's life: the heading error |∠v_est − ∠v_true|
    (rad, in [0, π]) and the relative speed error | |v_est| − |v_true| | / |v_true| (paper 002's
    direction and speed errors); rows where the target stands still are skipped."""
    rows = [r for r in rows if r.vx is not None and r.vy is not None and path.exists(r.t)]
    if not rows:
        return np.zeros(0), np.zeros(0)
    v_est = np.array([(r.vx, r.vy) for r in rows], dtype=float)
    v_true = path.velocity(np.array([r.t for r in rows], dtype=float))
    speed_true = np.hypot(*v_true.T)
    moving = speed_true > 0
    v_est, v_true, speed_true = v_est[moving], v_true[moving], speed_true[moving]
    turn = np.arctan2(v_est[:, 1], v_est[:, 0]) - np.arctan2(v_true[:, 1], v_true[:, 0])
    heading = np.abs((turn + np.pi) % (2 * np.pi) - np.pi)
    return heading, np.abs(np.hypot(*v_est.T) - speed_true) / speed_true


def area_between(a: np.ndarray, b: np.ndarray) -> float:
    """Area (units²) enclosed between two polylines ``a`` and ``b`` run in the same direction:
    the ring a + reversed(b), closed, noded at its self-intersections; every region it encloses
    counts once, whatever its winding (a crossing of the two paths does not cancel area)."""
    ring = np.vstack([a, np.asarray(b)[::-1], np.asarray(a)[:1]])
    if len(ring) < 4:
        return 0.0
    noded = shapely.unary_union(shapely.LineString(ring))
    faces = shapely.polygonize(shapely.get_parts(noded))
    return float(shapely.area(faces))


def trajectory_error(rows: Sequence[TrackRow], path: TruthPath) -> float | None:
    """Trajectory error of paper 001 §5.5, units: the area of the polygon formed by the
    estimated path (the rows within the target's life, in time order) and the real path over
    the same time span, divided by the length of that real path.

    None with fewer than two estimates in the target's life or a real path of zero length.
    """
    rows = sorted((r for r in rows if path.exists(r.t)), key=lambda r: r.t)
    if len(rows) < 2:
        return None
    estimated = np.array([(r.x, r.y) for r in rows], dtype=float)
    real = path.between(rows[0].t, rows[-1].t)
    length = polyline_length(real)
    if length <= 0:
        return None
    return area_between(estimated, real) / length


# --------------------------------------------------------------------------- GOSPA


@dataclass(frozen=True)
class Gospa:
    """GOSPA between two finite sets of points with α = 2 (Rahmathullah et al. 2017).

    ``distance`` is in units; ``localisation``, ``missed`` and ``false`` are its p-th power
    parts (units^p): ``distance**p == localisation + missed + false``. ``pairs`` are the
    (estimate index, truth index) assignments closer than the cut-off c.
    """

    distance: float
    localisation: float
    missed: float
    false: float
    n_missed: int
    n_false: int
    pairs: tuple[tuple[int, int], ...]


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances between the points (m, 2) and (n, 2): an (m, n) array."""
    return np.hypot(*(a[:, None, :] - b[None, :, :]).transpose(2, 0, 1))


def gospa(estimates, truths, c: float, p: float = 2.0) -> Gospa:
    """GOSPA metric with cut-off ``c`` (units), order ``p`` and α = 2 between the estimated
    points (m, 2) and the true points (n, 2), units.

    An optimal assignment (``scipy.optimize.linear_sum_assignment`` on min(d, c)^p) pairs
    points; pairs at distance ≥ c count as one missed and one false point, c^p/2 each, as do
    the points left over. Empty vs one point gives (c^p/2)^(1/p).
    """
    if not c > 0:
        raise ValueError(f"GOSPA cut-off c must be positive, got {c}")
    if not p >= 1:
        raise ValueError(f"GOSPA order p must be at least 1, got {p}")
    estimates = np.asarray(estimates, dtype=float).reshape(-1, 2)
    truths = np.asarray(truths, dtype=float).reshape(-1, 2)
    pairs: tuple[tuple[int, int], ...] = ()
    localisation = 0.0
    if len(estimates) and len(truths):
        d = _distances(estimates, truths)
        est_idx, true_idx = linear_sum_assignment(np.minimum(d, c) ** p)
        within = d[est_idx, true_idx] < c
        pairs = tuple(zip(est_idx[within].tolist(), true_idx[within].tolist()))
        localisation = float((d[est_idx[within], true_idx[within]] ** p).sum())
    n_missed = len(truths) - len(pairs)
    n_false = len(estimates) - len(pairs)
    missed = c**p / 2 * n_missed
    false = c**p / 2 * n_false
    return Gospa(
        distance=(localisation + missed + false) ** (1 / p),
        localisation=localisation,
        missed=missed,
        false=false,
        n_missed=n_missed,
        n_false=n_false,
        pairs=pairs,
    )


@dataclass(frozen=True)
class Scan:
    """The score of one scan (one time ``t`` of tracks.csv): GOSPA between the tracks at ``t``
    and the targets existing at ``t``."""

    t: float
    gospa: Gospa
    n_tracks: int
    n_targets: int

    @property
    def count_error(self) -> int:
        return abs(self.n_tracks - self.n_targets)


@dataclass(frozen=True)
class MultiTargetScores:
    """Per-scan GOSPA (cut-off ``c`` in units, order ``p``, α = 2) and identity switches.

    The means are over scans and are None without scans.
    """

    c: float
    p: float
    scans: tuple[Scan, ...]
    identity_switches: int

    def _mean(self, values) -> float | None:
        return float(np.mean(list(values))) if self.scans else None

    @property
    def gospa_mean(self) -> float | None:
        """Mean GOSPA distance, units."""
        return self._mean(s.gospa.distance for s in self.scans)

    @property
    def localisation_mean(self) -> float | None:
        """Mean localisation part, units^p."""
        return self._mean(s.gospa.localisation for s in self.scans)

    @property
    def missed_mean(self) -> float | None:
        """Mean missed-target part, units^p."""
        return self._mean(s.gospa.missed for s in self.scans)

    @property
    def false_mean(self) -> float | None:
        """Mean false-track part, units^p."""
        return self._mean(s.gospa.false for s in self.scans)

    @property
    def missed_targets_mean(self) -> float | None:
        """Mean number of missed targets per scan."""
        return self._mean(s.gospa.n_missed for s in self.scans)

    @property
    def false_tracks_mean(self) -> float | None:
        """Mean number of false tracks per scan."""
        return self._mean(s.gospa.n_false for s in self.scans)

    @property
    def count_error_mean(self) -> float | None:
        """Mean |number of tracks − number of targets| per scan."""
        return self._mean(s.count_error for s in self.scans)

    @property
    def count_correct(self) -> float | None:
        """Fraction of scans with as many tracks as targets."""
        return self._mean(s.count_error == 0 for s in self.scans)


def multi_target_scores(rows: Sequence[TrackRow], paths: Mapping[str, TruthPath], c: float,
                        p: float = 2.0, times: Iterable[float] | None = None) -> MultiTargetScores:
    """Score multi-target tracks (paper 004) scan by scan.

    A scan is each distinct time of ``rows`` (and each of ``times``, the tracker's scan times,
    so that scans where it reported no track count too); at it, :func:`gospa` compares the track
    positions with the positions of the targets existing then.

    Identity switches are counted as CLEAR MOT's mismatches (Bernardin and Stiefelhagen, 2008):
    at each scan a target keeps the track it had if that track is still within ``c`` of it and
    not kept by another target; the others are paired by an optimal assignment within ``c``. A
    switch is a target paired with a track other than the one it last had (scans where it is
    unpaired do not reset that memory). Re-deciding the pairs from scratch each scan, as GOSPA
    does, would count two switches, and two more a scan later, whenever two well-tracked people
    pass within a metre or two of each other and noise decides which track is nearer to whom.
    """
    by_time: dict[float, list[TrackRow]] = {t: [] for t in (times or ())}
    for row in sorted(rows, key=lambda r: r.t):
        by_time.setdefault(row.t, []).append(row)
    by_time = dict(sorted(by_time.items()))
    scans = []
    last_track: dict[str, int] = {}
    switches = 0
    for t, group in by_time.items():
        present = [k for k, path in paths.items() if path.exists(t)]
        truths = np.array([paths[k].position(t) for k in present]).reshape(-1, 2)
        score = gospa([(r.x, r.y) for r in group], truths, c, p)
        for target, track in identity_pairs(group, present, truths, last_track, c).items():
            if target in last_track and last_track[target] != track:
                switches += 1
            last_track[target] = track
        scans.append(Scan(t, score, len(group), len(present)))
    return MultiTargetScores(c, p, tuple(scans), switches)


def identity_pairs(group: Sequence[TrackRow], present: Sequence, truths: np.ndarray,
                   last_track: Mapping, c: float) -> dict:
    """Target → track id at one scan, as CLEAR MOT pairs them: each target of ``present`` (at
    ``truths``, units) keeps the track of ``group`` it had (``last_track``) while that track is
    within ``c`` (units) and not kept by another target; the rest by an optimal assignment
    within ``c``."""
    if not group or not present:
        return {}
    d = _distances(np.array([(r.x, r.y) for r in group]), truths)
    row_of = {r.track: i for i, r in enumerate(group)}
    pairs: dict[str, int] = {}
    for j, target in sorted(enumerate(present), key=lambda jt: jt[1]):
        i = row_of.get(last_track.get(target, -1))
        if i is not None and d[i, j] < c and group[i].track not in pairs.values():
            pairs[target] = group[i].track
    rows = [i for i, r in enumerate(group) if r.track not in pairs.values()]
    cols = [j for j, k in enumerate(present) if k not in pairs]
    if rows and cols:
        sub = np.minimum(d[np.ix_(rows, cols)], c)
        for a, b in zip(*linear_sum_assignment(sub)):
            if sub[a, b] < c:
                pairs[present[cols[b]]] = group[rows[a]].track
    return pairs


# --------------------------------------------------------------------------- line-sensor objects


@dataclass(frozen=True)
class ObjectError:
    """Entry and exit point errors (units) of one line-sensor object (paper 003 §7.2)."""

    object: int
    target: str
    entry: float
    exit: float


def match_objects(objects: Sequence[ObjectRow], paths: Mapping[str, TruthPath]) -> list[tuple[ObjectRow, str]]:
    """Pair objects with targets one to one by time overlap: the assignment maximising the
    summed overlap (s) of [t_first, t_last] with the targets' lives; an object whose interval
    does not meet any unpaired target's life stays unmatched."""
    targets = list(paths)
    if not objects or not targets:
        return []
    first = np.array([o.t_first for o in objects])[:, None]
    last = np.array([o.t_last for o in objects])[:, None]
    start = np.array([paths[k].start for k in targets])[None, :]
    end = np.array([paths[k].end for k in targets])[None, :]
    overlap = np.minimum(last, end) - np.maximum(first, start)
    feasible = overlap >= -TIME_TOLERANCE
    # infeasible pairs cost more than any set of feasible ones, so they are chosen only when forced
    penalty = 1.0 + np.abs(overlap).sum()
    cost = np.where(feasible, -overlap, penalty)
    obj_idx, target_idx = linear_sum_assignment(cost)
    return [(objects[i], targets[j]) for i, j in zip(obj_idx, target_idx) if feasible[i, j]]


def entry_exit_errors(objects: Sequence[ObjectRow], paths: Mapping[str, TruthPath]) -> list[ObjectError]:
    """Entry and exit point errors (paper 003 §7.2), units, of the objects that
    :func:`match_objects` pairs with a target: the distances from the estimated entry and exit
    points to the target's first and last truth points. In object order."""
    errors = []
    for obj, target in sorted(match_objects(objects, paths), key=lambda pair: pair[0].object):
        path = paths[target]
        errors.append(
            ObjectError(
                obj.object,
                target,
                math.dist((obj.entry_x, obj.entry_y), path.xy[0]),
                math.dist((obj.exit_x, obj.exit_y), path.xy[-1]),
            )
        )
    return errors
