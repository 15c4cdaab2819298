"""Sensing models: what a binary sensor reports for a target's state.

Each model is built from the pydantic sensor of :mod:`bintrack.deployment_model` with
:func:`model_for` and works on arrays: ``positions`` of shape (..., 2) in deployment units,
``velocities`` of shape (..., 2) in units/s. Values follow DESIGN §6: disk 1/0, sector
0..s−1 or −1, motion +1/−1, line 1 (the beam was crossed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bintrack.geometry import TWO_PI, normalize_angle
from bintrack.deployment_model import DiskSensor, LineSensor, MotionSensor, SectorSensor

# Paper 001 §5.2: the exponential law falls to 0.01 % at R_out.
EXPONENTIAL_FLOOR = 1e-4
# Paper 001 §5.2 (after Mechitov et al.): R_in = 0.9 · R_out by default.
DEFAULT_INNER_FRACTION = 0.9


def exponential_alpha(range_in: float, range_out: float) -> float:
    """α of paper 001 eq. 26: e^{−α(R_out − R_in)} = 0.01 %, so α = ln(1e-4)/(R_in − R_out), 1/units."""
    return math.log(EXPONENTIAL_FLOOR) / (range_in - range_out)


def detection_probability(distance, range_in: float, range_out: float, law: str | None):
    """P_detect(d) of paper 001: 1 within R_in, 0 beyond R_out, and between them eq. 25
    (``law="linear"``: (R_out − d)/(R_out − R_in)) or eq. 26 (``"exponential"``: e^{−α(d − R_in)}).
    With ``law=None`` or R_in = R_out the ideal model: 1 for d < R_out, else 0. Distances in units."""
    d = np.asarray(distance, dtype=float)
    if law is None or range_in >= range_out:
        return (d < range_out).astype(float)
    if law == "linear":
        ring = (range_out - d) / (range_out - range_in)
    elif law == "exponential":
        ring = np.exp(-exponential_alpha(range_in, range_out) * (d - range_in))
    else:
        raise ValueError(f"unknown detection law {law!r}")
    return np.where(d <= range_in, 1.0, np.where(d < range_out, ring, 0.0))


def draw_effective_radius(rng: np.random.Generator, range_in: float, range_out: float, law: str | None) -> float:
    """A radius r (units) with survival P(r > d) = P_detect(d) of eq. 25/26.

    Reporting 1 exactly while d < r detects a target at distance d with probability
    P_detect(d) without flickering: linear law → r ~ U[R_in, R_out]; exponential law →
    r = R_in + Exp(α), capped at R_out (the 0.01 % tail lands on R_out)."""
    if law is None or range_in >= range_out:
        return range_out
    if law == "linear":
        return float(rng.uniform(range_in, range_out))
    if law == "exponential":
        return float(min(range_in + rng.exponential(1.0 / exponential_alpha(range_in, range_out)), range_out))
    raise ValueError(f"unknown detection law {law!r}")


def _distance(centre: tuple[float, float], positions) -> np.ndarray:
    p = np.asarray(positions, dtype=float)
    return np.hypot(p[..., 0] - centre[0], p[..., 1] - centre[1])


@dataclass(frozen=True)
class DiskModel:
    """Omni-directional presence sensor (papers 001, 004): 1 while the target is in range."""

    x: float
    y: float
    range: float
    range_in: float
    law: str | None

    @classmethod
    def from_sensor(cls, sensor: DiskSensor | SectorSensor) -> "DiskModel":
        return cls(sensor.x, sensor.y, sensor.range, sensor.inner_range, sensor.detection_law)

    @property
    def centre(self) -> tuple[float, float]:
        return (self.x, self.y)

    @property
    def imperfect(self) -> bool:
        return self.law is not None and self.range_in < self.range

    def distance(self, positions) -> np.ndarray:
        """Distance (units) from the sensor to each position."""
        return _distance(self.centre, positions)

    def status(self, positions, radius: float | np.ndarray | None = None) -> np.ndarray:
        """Ideal report: 1 where the distance is below ``radius`` (default: the range), else 0."""
        limit = self.range if radius is None else radius
        return (self.distance(positions) < limit).astype(int)

    def detect_probability(self, positions) -> np.ndarray:
        """P_detect at each position: eq. 25/26 between R_in and R_out for the imperfect model."""
        return detection_probability(self.distance(positions), self.range_in, self.range, self.law)

    def effective_radius(self, rng: np.random.Generator) -> float:
        """One draw of the radius within which a visit is detected (see :func:`draw_effective_radius`)."""
        return draw_effective_radius(rng, self.range_in, self.range, self.law)


@dataclass(frozen=True)
class SectorModel(DiskModel):
    """Directional sensor of paper 000: which of s equal sectors holds the target, −1 if absent.

    Sectors are numbered 0..s−1 clockwise from the boundary at angle ``offset`` (rad from +x):
    sector k covers the angles (offset − (k+1)·2π/s, offset − k·2π/s]."""

    sectors: int = 1
    offset: float = 0.0

    @classmethod
    def from_sensor(cls, sensor: SectorSensor) -> "SectorModel":
        return cls(sensor.x, sensor.y, sensor.range, sensor.inner_range, sensor.detection_law,
                   sensor.sectors, sensor.offset)

    @property
    def width(self) -> float:
        """Central angle of one sector, rad."""
        return TWO_PI / self.sectors

    def boundary_angles(self) -> np.ndarray:
        """Angles (rad, in [0, 2π)) of the s sector boundaries: offset − k·2π/s."""
        return normalize_angle(self.offset - self.width * np.arange(self.sectors))

    def sector_interval(self, k: int) -> tuple[float, float]:
        """Sector k as (start, start + 2π/s): the counter-clockwise angle range it covers, rad."""
        start = normalize_angle(self.offset - (k + 1) * self.width)
        return start, start + self.width

    def sector_of(self, positions) -> np.ndarray:
        """Sector index of each position regardless of range (the sensor's own position: 0)."""
        p = np.asarray(positions, dtype=float)
        bearing = np.arctan2(p[..., 1] - self.y, p[..., 0] - self.x)
        clockwise = normalize_angle(self.offset - bearing)
        return np.minimum(np.floor_divide(clockwise, self.width).astype(int), self.sectors - 1)

    def status(self, positions, radius: float | np.ndarray | None = None) -> np.ndarray:
        """Ideal report: the sector holding the target when within ``radius`` (default range), else −1."""
        inside = super().status(positions, radius).astype(bool)
        return np.where(inside, self.sector_of(positions), -1)


@dataclass(frozen=True)
class MotionModel:
    """Closer/farther sensor of paper 002: +1 when the distance to the target is decreasing,
    i.e. (s − x)·v > 0, and −1 otherwise (DESIGN §8.5)."""

    x: float
    y: float

    @classmethod
    def from_sensor(cls, sensor: MotionSensor) -> "MotionModel":
        return cls(sensor.x, sensor.y)

    def status(self, positions, velocities) -> np.ndarray:
        p = np.asarray(positions, dtype=float)
        v = np.asarray(velocities, dtype=float)
        closing = (self.x - p[..., 0]) * v[..., 0] + (self.y - p[..., 1]) * v[..., 1]
        return np.where(closing > 0.0, 1, -1)


@dataclass(frozen=True)
class LineModel:
    """Laser beam of paper 003: the line a·x + b·y = 1; reports 1 when a target crosses it."""

    a: float
    b: float

    @classmethod
    def from_sensor(cls, sensor: LineSensor) -> "LineModel":
        if sensor.a is None or sensor.b is None:
            raise ValueError(f"line sensor {sensor.id!r} has no beam (a, b) to simulate")
        return cls(sensor.a, sensor.b)

    def side(self, positions) -> np.ndarray:
        """a·x + b·y − 1 at each position: its sign says which side of the beam the point is on."""
        p = np.asarray(positions, dtype=float)
        return self.a * p[..., 0] + self.b * p[..., 1] - 1.0

    def crossed(self, start, end) -> np.ndarray:
        """Whether the straight moves from ``start`` to ``end`` cross (or touch) the beam."""
        return self.side(start) * self.side(end) <= 0.0


SensorModel = DiskModel | SectorModel | MotionModel | LineModel


def model_for(sensor: DiskSensor | SectorSensor | MotionSensor | LineSensor) -> SensorModel:
    """The sensing model of a deployment sensor."""
    if isinstance(sensor, SectorSensor):
        return SectorModel.from_sensor(sensor)
    if isinstance(sensor, DiskSensor):
        return DiskModel.from_sensor(sensor)
    if isinstance(sensor, MotionSensor):
        return MotionModel.from_sensor(sensor)
    if isinstance(sensor, LineSensor):
        return LineModel.from_sensor(sensor)
    raise TypeError(f"no sensing model for {type(sensor).__name__}")


def reports_presence(sensor, value: int) -> bool:
    """Whether ``value`` says ``sensor`` saw a target: disk 1, sector 0..s−1, line 1.
    Closer/farther (motion) sensors report every period and never count as detecting."""
    if isinstance(sensor, SectorSensor):
        return value >= 0
    if isinstance(sensor, (DiskSensor, LineSensor)):
        return value == 1
    return False
