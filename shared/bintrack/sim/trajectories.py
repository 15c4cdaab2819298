"""Target trajectories as sequences of analytic segments: linear segments and circular arcs.

A :class:`Trajectory` exists from its entry time to its exit time (s); positions are in
deployment units, velocities in units/s. Crossing times with sensing circles, sector
boundary rays and beams are solved per segment in closed form (:mod:`bintrack.geometry`).
The generators draw the trajectory kinds of the papers from a numpy ``Generator``: linear,
circular and piecewise linear with random turns (paper 001 §5.2, paper 000 §V.A), constant
speed with sudden speed changes (paper 001 §5.4) and a random walk (paper 002).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

import numpy as np

from bintrack import geometry
from bintrack.deployment_model import Region


@dataclass(frozen=True)
class LinearSegment:
    """``p(t) = (x0, y0) + (vx, vy)·(t − t0)`` for t0 ≤ t ≤ t1."""

    t0: float
    t1: float
    x0: float
    y0: float
    vx: float
    vy: float

    @property
    def duration(self) -> float:
        return self.t1 - self.t0

    def position(self, t: np.ndarray) -> np.ndarray:
        tau = np.asarray(t, dtype=float) - self.t0
        return np.stack([self.x0 + self.vx * tau, self.y0 + self.vy * tau], axis=-1)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        shape = np.shape(t)
        return np.broadcast_to(np.array([self.vx, self.vy]), shape + (2,)).copy()

    def end(self) -> tuple[float, float]:
        return (self.x0 + self.vx * self.duration, self.y0 + self.vy * self.duration)

    def bbox(self) -> tuple[float, float, float, float]:
        x1, y1 = self.end()
        return min(self.x0, x1), min(self.y0, y1), max(self.x0, x1), max(self.y0, y1)

    def circle_times(self, centre, radius: float) -> np.ndarray:
        p0, v = (self.x0, self.y0), (self.vx, self.vy)
        return self.t0 + geometry.segment_circle_times(p0, v, self.duration, centre, radius)

    def ray_times(self, origin, angle: float, length: float) -> np.ndarray:
        p0, v = (self.x0, self.y0), (self.vx, self.vy)
        return self.t0 + geometry.segment_ray_times(p0, v, self.duration, origin, angle, length)

    def line_times(self, a: float, b: float) -> np.ndarray:
        p0, v = (self.x0, self.y0), (self.vx, self.vy)
        return self.t0 + geometry.segment_line_times(p0, v, self.duration, a, b)

    def interior_times(self, tolerance: float) -> np.ndarray:
        """Times inside the segment needed for linear interpolation: none, it is straight."""
        return np.empty(0)


@dataclass(frozen=True)
class ArcSegment:
    """``p(t) = (cx, cy) + radius·(cos φ, sin φ)``, φ = phi0 + omega·(t − t0), for t0 ≤ t ≤ t1.

    ``omega`` is the signed angular speed (rad/s, > 0 counter-clockwise)."""

    t0: float
    t1: float
    cx: float
    cy: float
    radius: float
    phi0: float
    omega: float

    @property
    def duration(self) -> float:
        return self.t1 - self.t0

    def _phi(self, t) -> np.ndarray:
        return self.phi0 + self.omega * (np.asarray(t, dtype=float) - self.t0)

    def position(self, t: np.ndarray) -> np.ndarray:
        phi = self._phi(t)
        return np.stack([self.cx + self.radius * np.cos(phi), self.cy + self.radius * np.sin(phi)], axis=-1)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        phi = self._phi(t)
        speed = self.omega * self.radius
        return np.stack([-speed * np.sin(phi), speed * np.cos(phi)], axis=-1)

    def end(self) -> tuple[float, float]:
        x, y = self.position(self.t1)
        return float(x), float(y)

    def bbox(self) -> tuple[float, float, float, float]:
        return self.cx - self.radius, self.cy - self.radius, self.cx + self.radius, self.cy + self.radius

    def _args(self):
        return (self.cx, self.cy), self.radius, self.phi0, self.omega, self.duration

    def circle_times(self, centre, radius: float) -> np.ndarray:
        return self.t0 + geometry.arc_circle_times(*self._args(), centre, radius)

    def ray_times(self, origin, angle: float, length: float) -> np.ndarray:
        return self.t0 + geometry.arc_ray_times(*self._args(), origin, angle, length)

    def line_times(self, a: float, b: float) -> np.ndarray:
        return self.t0 + geometry.arc_line_times(*self._args(), a, b)

    def interior_times(self, tolerance: float) -> np.ndarray:
        """Times at which chords deviate from the arc by at most ``tolerance`` units (sagitta)."""
        if self.omega == 0.0 or self.radius <= tolerance:
            return np.empty(0)
        step = 2.0 * math.acos(1.0 - tolerance / self.radius) / abs(self.omega)
        count = int(math.ceil(self.duration / step))
        return self.t0 + self.duration * np.arange(1, count) / count


Segment = Union[LinearSegment, ArcSegment]


def _near(bbox: tuple[float, float, float, float], centre, radius: float) -> bool:
    """Whether a disk of ``radius`` about ``centre`` reaches the bounding box."""
    dx = max(bbox[0] - centre[0], 0.0, centre[0] - bbox[2])
    dy = max(bbox[1] - centre[1], 0.0, centre[1] - bbox[3])
    return dx * dx + dy * dy <= radius * radius


@dataclass(frozen=True)
class Trajectory:
    """One target's path: contiguous segments from ``t_entry`` to ``t_exit`` (s).

    ``target`` is its id in truth.csv. Outside [t_entry, t_exit] the target does not exist:
    :meth:`position` and :meth:`velocity` give NaN there. At a vertex the velocity is that of
    the segment that starts there (right-continuous)."""

    target: str
    segments: tuple[Segment, ...]

    def __post_init__(self):
        if not self.segments:
            raise ValueError("a trajectory needs at least one segment")
        for before, after in zip(self.segments, self.segments[1:]):
            if after.t0 != before.t1:
                raise ValueError(f"segments are not contiguous in time at t={before.t1}")

    @property
    def t_entry(self) -> float:
        return self.segments[0].t0

    @property
    def t_exit(self) -> float:
        return self.segments[-1].t1

    @property
    def vertex_times(self) -> np.ndarray:
        """Entry time, every segment boundary and exit time, s."""
        return np.array([s.t0 for s in self.segments] + [self.t_exit])

    def alive(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return (t >= self.t_entry) & (t <= self.t_exit)

    def _evaluate(self, t, what: str) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        flat = np.atleast_1d(t)
        out = np.full(flat.shape + (2,), np.nan)
        index = np.searchsorted([s.t0 for s in self.segments], flat, side="right") - 1
        index = np.clip(index, 0, len(self.segments) - 1)
        live = self.alive(flat)
        for k in np.unique(index[live]):
            mask = live & (index == k)
            out[mask] = getattr(self.segments[k], what)(flat[mask])
        return out.reshape(t.shape + (2,))

    def position(self, t) -> np.ndarray:
        """Position(s) at time(s) ``t``: shape ``np.shape(t) + (2,)``, units."""
        return self._evaluate(t, "position")

    def velocity(self, t) -> np.ndarray:
        """Velocity at time(s) ``t``: shape ``np.shape(t) + (2,)``, units/s."""
        return self._evaluate(t, "velocity")

    def bbox(self) -> tuple[float, float, float, float]:
        boxes = np.array([s.bbox() for s in self.segments])
        return boxes[:, 0].min(), boxes[:, 1].min(), boxes[:, 2].max(), boxes[:, 3].max()

    def circle_times(self, centre, radius: float) -> np.ndarray:
        """Sorted times (s) at which the target is at distance ``radius`` from ``centre``."""
        parts = [s.circle_times(centre, radius) for s in self.segments if _near(s.bbox(), centre, radius)]
        return np.sort(np.concatenate(parts)) if parts else np.empty(0)

    def ray_times(self, origin, angle: float, length: float) -> np.ndarray:
        """Sorted times (s) at which the target crosses the ray from ``origin`` at ``angle`` (rad)
        within ``length`` of the origin."""
        parts = [s.ray_times(origin, angle, length) for s in self.segments if _near(s.bbox(), origin, length)]
        return np.sort(np.concatenate(parts)) if parts else np.empty(0)

    def line_times(self, a: float, b: float) -> np.ndarray:
        """Sorted times (s) at which the target meets the line a·x + b·y = 1."""
        return np.sort(np.concatenate([s.line_times(a, b) for s in self.segments]))

    def truth_times(self, tolerance: float = 1e-3, step: float | None = None) -> np.ndarray:
        """Times (s) at which sampling the path makes linear interpolation exact to ``tolerance``
        units: every vertex, enough points along arcs, and with ``step`` also a regular grid."""
        needed = np.concatenate([self.vertex_times] + [s.interior_times(tolerance) for s in self.segments])
        needed = np.unique(needed)
        if step is None:
            return needed
        grid = np.arange(math.ceil(self.t_entry / step), math.floor(self.t_exit / step) + 1) * step
        gap = np.min(np.abs(grid[:, None] - needed[None, :]), axis=1) if grid.size else grid
        return np.unique(np.concatenate([needed, grid[gap > 1e-6]]))


# --------------------------------------------------------------------------- builders


def polyline(target: str, t0: float, points, speeds) -> Trajectory:
    """Piecewise-linear path through ``points`` (units) starting at ``t0`` (s); ``speeds``
    (units/s) is one speed or one per piece."""
    pts = np.asarray(points, dtype=float)
    speeds = np.broadcast_to(np.asarray(speeds, dtype=float), (len(pts) - 1,))
    segments = []
    t = float(t0)
    for (x0, y0), (x1, y1), speed in zip(pts[:-1], pts[1:], speeds):
        length = math.hypot(x1 - x0, y1 - y0)
        if length == 0.0:
            continue
        if speed <= 0:
            raise ValueError("speeds must be positive")
        dt = length / speed
        segments.append(LinearSegment(t, t + dt, float(x0), float(y0), (x1 - x0) / dt, (y1 - y0) / dt))
        t += dt
    return Trajectory(target, tuple(segments))


def circle(target: str, t0: float, centre, radius: float, phi0: float, speed: float, duration: float,
           clockwise: bool = False) -> Trajectory:
    """Circular path about ``centre`` starting at angle ``phi0`` (rad) at ``speed`` (units/s)."""
    omega = (-1.0 if clockwise else 1.0) * speed / radius
    return Trajectory(target, (ArcSegment(t0, t0 + duration, float(centre[0]), float(centre[1]), radius, phi0, omega),))


def random_linear(rng: np.random.Generator, box: Region, speed: float, duration: float,
                  t0: float = 0.0, target: str = "0") -> Trajectory:
    """Straight path of length speed·duration inside ``box`` in a uniformly random direction,
    its start uniform among the starts that keep it inside (paper 001 §5.2 'linear')."""
    length = speed * duration
    if length > min(box.width, box.height):
        raise ValueError(f"a straight path of {length:g} units does not fit in a {box.width:g}×{box.height:g} square")
    heading = rng.uniform(0.0, geometry.TWO_PI)
    dx, dy = length * math.cos(heading), length * math.sin(heading)
    x0 = rng.uniform(box.xmin + max(0.0, -dx), box.xmax - max(0.0, dx))
    y0 = rng.uniform(box.ymin + max(0.0, -dy), box.ymax - max(0.0, dy))
    return polyline(target, t0, [(x0, y0), (x0 + dx, y0 + dy)], speed)


def random_circular(rng: np.random.Generator, box: Region, speed: float, duration: float | None = None,
                    t0: float = 0.0, target: str = "0") -> Trajectory:
    """Circle of radius U[0.25, 0.45]·side inside ``box``, random start angle and sense;
    ``duration`` defaults to one revolution (paper 001 §5.2 'circular')."""
    side = min(box.width, box.height)
    radius = rng.uniform(0.25, 0.45) * side
    cx = rng.uniform(box.xmin + radius, box.xmax - radius)
    cy = rng.uniform(box.ymin + radius, box.ymax - radius)
    phi0 = rng.uniform(0.0, geometry.TWO_PI)
    clockwise = bool(rng.integers(2))
    if duration is None:
        duration = geometry.TWO_PI * radius / speed
    return circle(target, t0, (cx, cy), radius, phi0, speed, duration, clockwise)


def random_turns(rng: np.random.Generator, box: Region, speed: float, duration: float,
                 piece_length: tuple[float, float], max_turn: float = math.pi / 2,
                 t0: float = 0.0, target: str = "0") -> Trajectory:
    """Piecewise-linear path with random turns (paper 001 §5.2): pieces of length
    U[piece_length] (units), turns U[−max_turn, max_turn] (rad), inside ``box``, of total
    length speed·duration. A piece that would leave the box is redrawn; after 50 tries
    it heads for the box centre instead."""
    cx, cy = (box.xmin + box.xmax) / 2, (box.ymin + box.ymax) / 2
    x = rng.uniform(cx - box.width / 4, cx + box.width / 4)
    y = rng.uniform(cy - box.height / 4, cy + box.height / 4)
    heading = rng.uniform(0.0, geometry.TWO_PI)
    points = [(x, y)]
    remaining = speed * duration
    first = True
    while remaining > 0:
        for _ in range(50):
            turn = 0.0 if first else rng.uniform(-max_turn, max_turn)
            length = min(rng.uniform(*piece_length), remaining)
            h = heading + turn
            nx, ny = x + length * math.cos(h), y + length * math.sin(h)
            if box.xmin <= nx <= box.xmax and box.ymin <= ny <= box.ymax:
                break
        else:
            h = math.atan2(cy - y, cx - x)
            room = geometry.box_exit_distance((x, y), (math.cos(h), math.sin(h)), box.xmin, box.ymin, box.xmax, box.ymax)
            length = min(length, room)
            nx, ny = x + length * math.cos(h), y + length * math.sin(h)
        first = False
        heading, x, y = h, nx, ny
        points.append((x, y))
        remaining -= length
    return polyline(target, t0, points, speed)


def speed_changes(rng: np.random.Generator, box: Region, base_speed: float, changes: int = 4,
                  multiples: tuple[int, ...] = (1, 2, 3), t0: float = 0.0, target: str = "0") -> Trajectory:
    """Straight path across ``box`` (length = the box's shorter side) whose speed changes
    suddenly ``changes`` times to a random multiple of ``base_speed`` (paper 001 §5.4)."""
    side = min(box.width, box.height)
    line = random_linear(rng, box, 1.0, side, t0, target)
    (x0, y0), (x1, y1) = line.position(line.t_entry), line.position(line.t_exit)
    weights = rng.uniform(1.0, 2.0, changes + 1)
    cuts = np.concatenate([[0.0], np.cumsum(weights) / weights.sum()])
    points = [(x0 + f * (x1 - x0), y0 + f * (y1 - y0)) for f in cuts]
    factors = [int(rng.choice(multiples))]
    for _ in range(changes):
        factors.append(int(rng.choice([m for m in multiples if m != factors[-1]])))
    return polyline(target, t0, points, base_speed * np.array(factors, dtype=float))


def random_walk(rng: np.random.Generator, box: Region, speed: float, sigma: float, dt: float,
                duration: float, t0: float = 0.0, target: str = "0") -> Trajectory:
    """Markov motion of paper 002: x_{k+1} = x_k + v_k·dt, v_{k+1} = v_k + N(0, σ²I) (σ in
    units/s), from a start near the centre of ``box`` at ``speed`` in a random direction.
    A step that would leave the box has the offending velocity components reflected."""
    cx, cy = (box.xmin + box.xmax) / 2, (box.ymin + box.ymax) / 2
    x = np.array([rng.uniform(cx - box.width / 8, cx + box.width / 8),
                  rng.uniform(cy - box.height / 8, cy + box.height / 8)])
    heading = rng.uniform(0.0, geometry.TWO_PI)
    v = speed * np.array([math.cos(heading), math.sin(heading)])
    lo, hi = np.array([box.xmin, box.ymin]), np.array([box.xmax, box.ymax])
    steps = int(math.ceil(duration / dt - 1e-9))
    segments = []
    for k in range(steps):
        start = t0 + k * dt
        end = min(t0 + (k + 1) * dt, t0 + duration)
        nxt = x + v * (end - start)
        v = np.where((nxt < lo) | (nxt > hi), -v, v)
        segments.append(LinearSegment(start, end, float(x[0]), float(x[1]), float(v[0]), float(v[1])))
        x = x + v * (end - start)
        v = v + rng.normal(0.0, sigma, 2)
    return Trajectory(target, tuple(segments))


def walk_across(rng: np.random.Generator, box: Region, speed: float, t0: float, target: str) -> Trajectory:
    """A straight walk from a random point of a random side of ``box`` to a random point of the
    opposite side (both in the middle 70 % of the side), at ``speed`` units/s from ``t0`` s."""
    side = int(rng.integers(4))
    f_in, f_out = rng.uniform(0.15, 0.85, 2)
    x_in, x_out = box.xmin + f_in * box.width, box.xmin + f_out * box.width
    y_in, y_out = box.ymin + f_in * box.height, box.ymin + f_out * box.height
    start, end = [((box.xmin, y_in), (box.xmax, y_out)), ((box.xmax, y_in), (box.xmin, y_out)),
                  ((x_in, box.ymin), (x_out, box.ymax)), ((x_in, box.ymax), (x_out, box.ymin))][side]
    return polyline(target, t0, [start, end], speed)


def _border_points(box: Region, centre, distance: float) -> np.ndarray:
    """Points of the border of ``box`` at ``distance`` from ``centre``."""
    corners = [(box.xmin, box.ymin), (box.xmax, box.ymin), (box.xmax, box.ymax), (box.xmin, box.ymax)]
    points = []
    for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1]):
        for tau in geometry.segment_circle_times((x0, y0), (x1 - x0, y1 - y0), 1.0, centre, distance):
            points.append((x0 + tau * (x1 - x0), y0 + tau * (y1 - y0)))
    return np.array(points).reshape(-1, 2)


def crossing_walks(rng: np.random.Generator, box: Region, entries: tuple[float, float],
                   targets: tuple[str, str], speeds: tuple[float, float] = (1.0, 1.5),
                   min_angle: float = math.pi / 4) -> tuple[Trajectory, Trajectory]:
    """Two straight walks that enter the border of ``box`` at times ``entries`` (s) and cross
    each other near the middle of the box at the same instant, at an angle between
    ``min_angle`` and π − ``min_angle`` (rad); speeds within ``speeds`` (units/s).

    The crossing time is drawn where both walkers can reach the crossing point from the border
    at an allowed speed; each entry point is then on the border at the distance walked."""
    centre = np.array([(box.xmin + box.xmax) / 2, (box.ymin + box.ymax) / 2])
    centre += rng.uniform(-0.1, 0.1, 2) * np.array([box.width, box.height])
    near = min(centre[0] - box.xmin, box.xmax - centre[0], centre[1] - box.ymin, box.ymax - centre[1])
    far = max(math.hypot(x - centre[0], y - centre[1])
              for x in (box.xmin, box.xmax) for y in (box.ymin, box.ymax))
    slow, fast = speeds
    earliest = max(t + near / fast for t in entries)
    latest = min(t + far / slow for t in entries)
    if earliest > latest:
        raise ValueError("the entry times are too far apart for the walkers to meet")
    t_cross = earliest + rng.uniform(0.25, 0.5) * (latest - earliest)
    walks = []
    first_heading = None
    for t0, target in zip(entries, targets):
        walked = t_cross - t0
        speed = rng.uniform(max(slow, near / walked), min(fast, far / walked))
        starts = _border_points(box, centre, speed * walked)
        headings = np.arctan2(centre[1] - starts[:, 1], centre[0] - starts[:, 0])
        if first_heading is None:
            choice = int(rng.integers(len(starts)))
        else:
            between = np.abs(geometry.normalize_angle(headings - first_heading + math.pi) - math.pi)
            allowed = np.flatnonzero((between >= min_angle) & (between <= math.pi - min_angle))
            choice = int(rng.choice(allowed)) if allowed.size else int(np.argmin(np.abs(between - math.pi / 2)))
        heading = headings[choice]
        first_heading = heading if first_heading is None else first_heading
        direction = (math.cos(heading), math.sin(heading))
        ahead = geometry.box_exit_distance(centre, direction, box.xmin, box.ymin, box.xmax, box.ymax)
        end = centre + ahead * np.array(direction)
        walks.append(polyline(target, t0, [starts[choice], end], speed))
    return walks[0], walks[1]


def curve_walk(rng: np.random.Generator, box: Region, course: Trajectory, step: float = 1.0,
               spread: float = 0.35, reversion: float = 5.0) -> Trajectory:
    """The walk ``course`` (a straight walk across ``box``) bent: same entry point, entry time and
    speed, but its heading is a mean-reverting random walk around the course's heading (an
    Ornstein–Uhlenbeck process of stationary spread ``spread`` rad and time constant
    ``reversion`` s, changed every ``step`` s). It ends where it first leaves ``box``, which
    may be on a side other than the course's."""
    start, end = course.position(course.t_entry), course.position(course.t_exit)
    speed = float(np.hypot(*course.velocity(course.t_entry)))
    heading = math.atan2(end[1] - start[1], end[0] - start[0])
    keep = math.exp(-step / reversion)
    kick = spread * math.sqrt(1.0 - keep * keep)
    x, y = float(start[0]), float(start[1])
    deviation = 0.0
    points = [(x, y)]
    for _ in range(100_000):
        h = heading + deviation
        direction = (math.cos(h), math.sin(h))
        room = geometry.box_exit_distance((x, y), direction, box.xmin, box.ymin, box.xmax, box.ymax)
        length = max(0.0, min(speed * step, room))
        x, y = x + length * direction[0], y + length * direction[1]
        points.append((x, y))
        if length < speed * step:
            break
        deviation = keep * deviation + kick * rng.standard_normal()
    return polyline(course.target, course.t_entry, points, speed)


def beside(rng: np.random.Generator, leader: Trajectory, target: str, offset: tuple[float, float],
           lag: float = 1.0) -> Trajectory:
    """A person walking beside ``leader`` (straight or piecewise linear): the leader's path moved
    sideways by U[offset] units (to a random side, perpendicular to the leader's first heading)
    and U[0, lag] s later."""
    vx, vy = leader.velocity(leader.t_entry)
    h = math.atan2(vy, vx)
    d = rng.uniform(*offset) * (1.0 if rng.integers(2) else -1.0)
    dx, dy, dt = -d * math.sin(h), d * math.cos(h), rng.uniform(0.0, lag)
    return Trajectory(target, tuple(LinearSegment(s.t0 + dt, s.t1 + dt, s.x0 + dx, s.y0 + dy, s.vx, s.vy)
                                    for s in _linear(leader)))


def with_stop(rng: np.random.Generator, walk: Trajectory, pause: tuple[float, float]) -> Trajectory:
    """``walk`` with a stop of U[pause] s at a time U[0.3, 0.7] of the way through it; the rest of
    the walk is delayed by the stop."""
    t_stop = walk.t_entry + rng.uniform(0.3, 0.7) * (walk.t_exit - walk.t_entry)
    wait = rng.uniform(*pause)
    segments: list[LinearSegment] = []
    for s in _linear(walk):
        if s.t1 <= t_stop:
            segments.append(s)
        elif s.t0 >= t_stop:
            segments.append(LinearSegment(s.t0 + wait, s.t1 + wait, s.x0, s.y0, s.vx, s.vy))
        else:
            x, y = s.x0 + s.vx * (t_stop - s.t0), s.y0 + s.vy * (t_stop - s.t0)
            segments += [LinearSegment(s.t0, t_stop, s.x0, s.y0, s.vx, s.vy),
                         LinearSegment(t_stop, t_stop + wait, x, y, 0.0, 0.0),
                         LinearSegment(t_stop + wait, s.t1 + wait, x, y, s.vx, s.vy)]
    return Trajectory(walk.target, tuple(segments))


def _linear(walk: Trajectory) -> tuple[LinearSegment, ...]:
    if not all(isinstance(s, LinearSegment) for s in walk.segments):
        raise ValueError("only piecewise-linear walks can be moved or stopped")
    return walk.segments
