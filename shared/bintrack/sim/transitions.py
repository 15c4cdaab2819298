"""Exact transition times of event-driven sensors (papers 000, 001) and beam crossings (paper 003).

A sensor's status can change only when some target crosses one of its curves: the sensing
circle, a sector boundary ray (within the radius), or when a target appears or disappears.
The candidate times are the union over targets of those analytic crossing times; the status
is constant between consecutive candidates, so evaluating it once between each pair gives
the exact transitions. With several targets a disk reports 1 if any target is inside and a
sector reports the sector of the lowest-numbered target inside.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bintrack.formats import Event, idle_value
from bintrack.deployment_model import DiskSensor, LineSensor, SectorSensor
from bintrack.sensing import DiskModel, LineModel, SectorModel, model_for
from bintrack.sim.trajectories import Trajectory


def inside_intervals(trajectory: Trajectory, centre, radius: float,
                     t_lo: float | None = None, t_hi: float | None = None) -> list[tuple[float, float]]:
    """Maximal time intervals (s) within [t_lo, t_hi] (default: the target's life) during
    which the target is closer than ``radius`` (units) to ``centre``."""
    lo = trajectory.t_entry if t_lo is None else t_lo
    hi = trajectory.t_exit if t_hi is None else t_hi
    crossings = trajectory.circle_times(centre, radius)
    times = np.unique(np.concatenate([[lo, hi], crossings[(crossings > lo) & (crossings < hi)]]))
    if len(times) < 2:
        return []
    mids = (times[:-1] + times[1:]) / 2
    position = trajectory.position(mids)
    inside = np.hypot(position[:, 0] - centre[0], position[:, 1] - centre[1]) < radius
    intervals: list[tuple[float, float]] = []
    for k in np.flatnonzero(inside):
        start, end = float(times[k]), float(times[k + 1])
        if intervals and intervals[-1][1] == start:
            intervals[-1] = (intervals[-1][0], end)
        else:
            intervals.append((start, end))
    return intervals


class _Visits:
    """A target's visits to a sensor's disk with the radius that applies during each."""

    def __init__(self, intervals: list[tuple[float, float]], radii: list[float]):
        self.start = np.array([a for a, _ in intervals])
        self.end = np.array([b for _, b in intervals])
        self.radius = np.array(radii, dtype=float)

    def radius_at(self, t: np.ndarray) -> np.ndarray:
        """The detection radius at times ``t`` (0 outside every visit)."""
        if self.start.size == 0:
            return np.zeros_like(t)
        k = np.clip(np.searchsorted(self.start, t, side="right") - 1, 0, None)
        during = (t >= self.start[k]) & (t <= self.end[k])
        return np.where(during, self.radius[k], 0.0)


def exact_transitions(sensor: DiskSensor | SectorSensor, trajectories: Sequence[Trajectory],
                      rng: np.random.Generator | None = None) -> list[Event]:
    """Every change of an event-driven disk or sector sensor's status, at its exact time (s).

    Ideal model: the status follows the sensing circle. Imperfect model (``range_in`` and
    ``detection_law`` set): for each visit of a target to the outer disk an effective radius r
    is drawn (survival function P_detect, paper 001 eq. 25/26) and the target counts as
    inside exactly while its distance is below r; ``rng`` is then required."""
    model = model_for(sensor)
    if not isinstance(model, DiskModel):
        raise TypeError(f"sensor {sensor.id!r} is not a disk or sector sensor")
    centre = model.centre
    visits: list[_Visits] = []
    candidates = []
    for trajectory in trajectories:
        outer = inside_intervals(trajectory, centre, model.range)
        radii = []
        for start, end in outer:
            candidates.extend([start, end])
            if model.imperfect:
                if rng is None:
                    raise ValueError("the imperfect sensing model needs a random generator")
                r = model.effective_radius(rng)
                crossings = trajectory.circle_times(centre, r)
                candidates.extend(crossings[(crossings > start) & (crossings < end)])
            else:
                r = model.range
            radii.append(r)
        visits.append(_Visits(outer, radii))
        if isinstance(model, SectorModel) and model.sectors > 1 and outer:
            for angle in model.boundary_angles():
                candidates.extend(trajectory.ray_times(centre, angle, model.range))
    if not candidates:
        return []
    times = np.unique(np.asarray(candidates, dtype=float))
    status = _status(model, trajectories, visits, (times[:-1] + times[1:]) / 2)
    idle = idle_value(sensor)
    # the status is idle before the first candidate and after the last (no target inside)
    status = np.concatenate([status, [idle]])
    events = []
    previous = idle
    for t, value in zip(times, status):
        if value != previous:
            events.append(Event(float(t), sensor.id, int(value)))
            previous = value
    return events


def _status(model: DiskModel, trajectories: Sequence[Trajectory], visits: list[_Visits],
            t: np.ndarray) -> np.ndarray:
    sector = isinstance(model, SectorModel)
    value = np.full(t.shape, -1 if sector else 0)
    for trajectory, visit in zip(trajectories, visits):
        position = trajectory.position(t)
        with np.errstate(invalid="ignore"):
            inside = trajectory.alive(t) & (model.distance(position) < visit.radius_at(t))
        if sector:
            free = inside & (value == -1)
            value[free] = model.sector_of(position[free])
        else:
            value[inside] = 1
    return value


def beam_crossings(sensor: LineSensor, trajectories: Sequence[Trajectory]) -> list[Event]:
    """Times (s) at which any target meets the beam a·x + b·y = 1 of a line sensor (value 1)."""
    model = model_for(sensor)
    if not isinstance(model, LineModel):
        raise TypeError(f"sensor {sensor.id!r} is not a line sensor")
    times = np.sort(np.concatenate([tr.line_times(model.a, model.b) for tr in trajectories] or [np.empty(0)]))
    return [Event(float(t), sensor.id, 1) for t in times]
