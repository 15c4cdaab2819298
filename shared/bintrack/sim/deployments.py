"""Sensor layouts: uniform random nodes (papers 000, 001, 002), a jittered grid with dead nodes
(paper 004 §V), and laser/light-sensor pairs across a track (paper 003 §6–7.1).

Positions are rounded (to 1e-3 units, 1e-2 for the grid and the track) so that the written
deployment is exactly what was simulated. Ids are zero-padded so they sort in node order.
"""

from __future__ import annotations

import math

import numpy as np

from bintrack.deployment_model import DiskSensor, LineSensor, MotionSensor, Region, SectorSensor


def _ids(prefix: str, count: int) -> list[str]:
    width = len(str(max(count - 1, 0)))
    return [f"{prefix}{k:0{width}d}" for k in range(count)]


def uniform_positions(rng: np.random.Generator, count: int, region: Region) -> np.ndarray:
    """``count`` positions uniform over ``region`` (units, rounded to 1e-3), shape (count, 2)."""
    x = rng.uniform(region.xmin, region.xmax, count)
    y = rng.uniform(region.ymin, region.ymax, count)
    return np.round(np.stack([x, y], axis=1), 3)


def disks_at(positions: np.ndarray, sensing_range: float, prefix: str = "n", **fields) -> list[DiskSensor]:
    """Disk sensors at ``positions`` with range ``sensing_range`` (units) and the optional
    :class:`DiskSensor` fields (``range_in``, ``detection_law``, ``pd``, ``pfa``, ``period``)."""
    fields = {k: v for k, v in fields.items() if v is not None}
    return [DiskSensor(id=i, x=float(x), y=float(y), range=sensing_range, **fields)
            for i, (x, y) in zip(_ids(prefix, len(positions)), positions)]


def sectors_at(positions: np.ndarray, offsets: np.ndarray, sensing_range: float, sectors: int,
               prefix: str = "n", **fields) -> list[SectorSensor]:
    """Sector sensors (paper 000) at ``positions`` with sector-0 boundary angles ``offsets`` (rad)."""
    fields = {k: v for k, v in fields.items() if v is not None}
    return [SectorSensor(id=i, x=float(x), y=float(y), range=sensing_range, sectors=sectors,
                         offset=float(o), **fields)
            for i, (x, y), o in zip(_ids(prefix, len(positions)), positions, offsets)]


def random_offsets(rng: np.random.Generator, count: int) -> np.ndarray:
    """Sector-0 boundary angles uniform in [0, 2π) rad, rounded to 1e-6 (paper 000 §II)."""
    return np.round(rng.uniform(0.0, 2.0 * math.pi, count), 6)


def grid_positions(rng: np.random.Generator, rows: int, cols: int, spacing: float, jitter: float,
                   origin: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """A rows×cols grid at ``spacing`` (units), row-major from ``origin``, each node moved by
    U[−jitter, jitter] in x and y; rounded to 1e-2 units."""
    r, c = np.divmod(np.arange(rows * cols), cols)
    x = origin[0] + c * spacing + rng.uniform(-jitter, jitter, rows * cols)
    y = origin[1] + r * spacing + rng.uniform(-jitter, jitter, rows * cols)
    return np.round(np.stack([x, y], axis=1), 2)


def dead_nodes(rng: np.random.Generator, ids: list[str], count: int) -> frozenset[str]:
    """``count`` ids drawn without replacement: nodes listed in the deployment that never report."""
    return frozenset(ids[k] for k in rng.choice(len(ids), size=count, replace=False))


def motion_at(positions: np.ndarray, period: float, prefix: str = "m") -> list[MotionSensor]:
    """Closer/farther sensors (paper 002) at ``positions`` reporting every ``period`` s."""
    return [MotionSensor(id=i, x=float(x), y=float(y), period=period)
            for i, (x, y) in zip(_ids(prefix, len(positions)), positions)]


def beam(x_sensor: float, y_sensor: float, x_laser: float, y_laser: float) -> tuple[float, float]:
    """(a, b) of the line a·x + b·y = 1 through a light sensor and its laser (paper 003 eq. 1)."""
    det = x_sensor * y_laser - x_laser * y_sensor
    if det == 0.0:
        raise ValueError("a beam through the origin has no form a·x + b·y = 1")
    return (y_laser - y_sensor) / det, (x_sensor - x_laser) / det


def laser_track(rng: np.random.Generator, length: float, width: float, count: int = 6,
                angles: tuple[float, float] = (55.0, 70.0), offset: float | None = None) -> list[LineSensor]:
    """``count`` laser/light-sensor pairs across a track [0, length] × [0, width] (paper 003 §7.1).

    Light sensors stand along y = 0, spread along the track with jitter, lasers along
    y = width. The first half of the beams lean right and the rest left, each at an acute angle
    to the x axis drawn in its own stratum of ``angles`` (degrees), so no two are parallel and
    every beam spans the track from side to side. Light sensors stand within ±``offset`` units of
    evenly spaced places (default ±2 % of the length). Ids L1..Lcount; x, y is the light sensor;
    a, b the true beam (for simulation; not published)."""
    lo, hi = math.radians(angles[0]), math.radians(angles[1])
    right = (count + 1) // 2
    margin = width / math.tan(lo)
    slots = np.linspace(0.1 * length, 0.9 * length, count)
    sensors = []
    for k in range(count):
        group, rank, size = (0, k, right) if k < right else (1, k - right, count - right)
        theta = lo + (rank + rng.uniform(0.2, 0.8)) * (hi - lo) / size
        run = width / math.tan(theta)
        xs = slots[k] + (rng.uniform(-0.02, 0.02) * length if offset is None else rng.uniform(-offset, offset))
        xs = min(max(xs, 0.02 * length), length - margin) if group == 0 else min(max(xs, margin), 0.98 * length)
        xs = round(xs, 2)
        xl = round(xs + run if group == 0 else xs - run, 2)
        a, b = beam(xs, 0.0, xl, width)
        sensors.append(LineSensor(id=f"L{k + 1}", x=xs, y=0.0, a=a, b=b))
    return sensors
