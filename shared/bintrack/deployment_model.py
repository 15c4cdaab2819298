"""The deployment (DESIGN §6): ``deployment.json``, and the payload of the ``deployment``
queryable: the sensors with their kinds and clocks, the region, named regions and calibration.

Sensors ignore fields beyond the format, so that files with extra metadata still load.
"""

from __future__ import annotations

import re
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from bintrack.message_base import Message

DEPLOYMENT_FORMAT = "bintrack.deployment/1"

# A sensor id is one chunk of a Zenoh key expression and one CSV cell.
SENSOR_ID_PATTERN = r"^[^/*$?#,\s\"']+$"
_SENSOR_ID_RE = re.compile(SENSOR_ID_PATTERN)

def check_sensor_id(value: str) -> str:
    """Return ``value`` if it can be a sensor id (a key-expression chunk and a CSV cell)."""
    if not _SENSOR_ID_RE.match(value):
        raise ValueError(
            f"sensor id {value!r} must be non-empty without '/', '*', '$', '?', '#', ',', quotes or spaces"
        )
    return value


class _SensorBase(BaseModel):
    # Fields beyond the format are ignored so that files with extra metadata still load.
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)

    id: str = Field(description="unique sensor id")
    clock_offset: float = Field(
        0.0, description="offset of the node's local clock, s (local = (1 + skew)·t + offset)"
    )
    clock_skew: float = Field(0.0, gt=-0.5, lt=0.5, description="relative rate error of the node's clock")

    @field_validator("id")
    @classmethod
    def _valid_id(cls, value: str) -> str:
        return check_sensor_id(value)


class _RangeSensor(_SensorBase):
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    range: float = Field(gt=0, description="sensing range R (R_out in the imperfect model), deployment units")
    range_in: float | None = Field(
        None, gt=0, description="imperfect model: always detected within range_in, deployment units"
    )
    detection_law: Literal["linear", "exponential"] | None = Field(
        None, description="imperfect model between range_in and range: paper 001 eq. 25 or eq. 26"
    )
    pd: float | None = Field(None, ge=0, le=1, description="detection probability per sample")
    pfa: float | None = Field(None, ge=0, le=1, description="false-alarm probability per sample")
    period: float | None = Field(None, gt=0, description="sampling period, s; absent = event-driven")
    hold: float | None = Field(
        None, ge=0, description="real PIR: s the output stays on after the last trigger (absent: the papers' "
        "presence disk, no hold)")
    still: float | None = Field(
        None, ge=0, le=1, description="real PIR, which sees motion: pd of a person standing still as a fraction of pd "
        "(absent: 1, a presence sensor)")

    @model_validator(mode="after")
    def _inner_within_outer(self):
        if self.range_in is not None and self.range_in > self.range:
            raise ValueError(f"range_in {self.range_in} exceeds range {self.range}")
        return self

    @property
    def inner_range(self) -> float:
        """R_in: the radius within which the sensor always detects (R for the ideal model)."""
        return self.range if self.range_in is None else self.range_in


class DiskSensor(_RangeSensor):
    kind: Literal["disk"] = "disk"


class SectorSensor(_RangeSensor):
    kind: Literal["sector"] = "sector"
    sectors: int = Field(ge=1, description="number of equal sectors s")
    offset: float = Field(
        0.0, description="angle of sector 0's first boundary from +x, rad; sectors numbered clockwise"
    )


class MotionSensor(_SensorBase):
    kind: Literal["motion"] = "motion"
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    period: float = Field(gt=0, description="reporting period, s")


class LineSensor(_SensorBase):
    kind: Literal["line"] = "line"
    x: float | None = Field(None, description="sensor position if known, deployment units")
    y: float | None = Field(None, description="sensor position if known, deployment units")
    a: float | None = Field(None, description="beam a·x + b·y = 1, if known, 1/units")
    b: float | None = Field(None, description="beam a·x + b·y = 1, if known, 1/units")

    @model_validator(mode="after")
    def _pairs(self):
        if (self.x is None) != (self.y is None):
            raise ValueError("x and y must be given together")
        if (self.a is None) != (self.b is None):
            raise ValueError("a and b must be given together")
        return self


Sensor = Annotated[
    Union[DiskSensor, SectorSensor, MotionSensor, LineSensor], Field(discriminator="kind")
]


class Region(BaseModel):
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)
    xmin: float
    ymin: float
    xmax: float
    ymax: float

    @model_validator(mode="after")
    def _ordered(self):
        if not (self.xmin < self.xmax and self.ymin < self.ymax):
            raise ValueError("region needs xmin < xmax and ymin < ymax")
        return self

    @property
    def width(self) -> float:
        return self.xmax - self.xmin

    @property
    def height(self) -> float:
        return self.ymax - self.ymin


Point = tuple[float, float]


REGION_NAME_PATTERN = r"^[A-Za-z0-9_.-]+$"


class Area(BaseModel):
    """An area of the floor: a rectangle (``xmin``, ``ymin``, ``xmax``, ``ymax``) or a
    ``polygon`` ([[x, y], …]), deployment units."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)
    xmin: float | None = None
    ymin: float | None = None
    xmax: float | None = None
    ymax: float | None = None
    polygon: list[Point] | None = Field(None, description="vertices in order, deployment units")

    def _label(self) -> str:
        return "area"

    @model_validator(mode="after")
    def _one_shape(self):
        corners = (self.xmin, self.ymin, self.xmax, self.ymax)
        if self.polygon is not None:
            if any(c is not None for c in corners):
                raise ValueError(f"{self._label()}: give a rectangle or a polygon, not both")
            if len(self.polygon) < 3:
                raise ValueError(f"{self._label()}: a polygon needs at least 3 vertices")
        elif any(c is None for c in corners):
            raise ValueError(f"{self._label()}: needs xmin, ymin, xmax, ymax or a polygon")
        elif not (self.xmin < self.xmax and self.ymin < self.ymax):
            raise ValueError(f"{self._label()} needs xmin < xmax and ymin < ymax")
        return self

    def vertices(self) -> list[Point]:
        """The outline, deployment units (a rectangle's four corners counter-clockwise)."""
        if self.polygon is not None:
            return [tuple(p) for p in self.polygon]
        return [(self.xmin, self.ymin), (self.xmax, self.ymin), (self.xmax, self.ymax), (self.xmin, self.ymax)]


class _Named(BaseModel):
    name: str = Field(pattern=REGION_NAME_PATTERN, description="region name, a key-expression chunk")


class RegionArea(Area, _Named):  # _Named last, so that ``name`` is a region's first field, as it always was
    """One named region of a deployment served by its own base station: a rectangle
    (``xmin``, ``ymin``, ``xmax``, ``ymax``) or a ``polygon`` ([[x, y], …], deployment units)."""

    def _label(self) -> str:
        return f"region {self.name!r}"


class FloorPlan(BaseModel):
    """What the room's plan tells a tracker: where nobody can stand (furniture, pillars) and
    where people come in and leave (doors), deployment units."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)
    obstacles: list[Area] = Field(default_factory=list, description="areas of the floor nobody can stand on")
    doors: list[Point] = Field(default_factory=list, description="where people come in and leave, [x, y] each")


class CalibrationPass(BaseModel):
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True, populate_by_name=True)
    pass_: int = Field(alias="pass", ge=1, description="pass number, from 1 in time order")
    t_entry: float = Field(description="entry time, s")
    entry: Point = Field(description="entry point, deployment units")
    t_exit: float = Field(description="exit time, s")
    exit: Point = Field(description="exit point, deployment units")


class Calibration(BaseModel):
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)
    passes: list[CalibrationPass] = Field(default_factory=list)


METRES_PER_UNIT = {"m": 1.0, "ft": 0.3048, "unit": 1.0}
"""length of one deployment unit in metres; an abstract ``unit`` is taken as a metre"""


class Deployment(Message):
    """``deployment.json`` of DESIGN §6, and the payload of the ``deployment`` queryable."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)

    format: Literal["bintrack.deployment/1"] = DEPLOYMENT_FORMAT
    name: str = Field(description="deployment (network) name; the <net> of the key expressions")
    units: Literal["m", "ft", "unit"] = Field(description="length unit of every position and range")
    region: Region
    sensors: list[Sensor]
    calibration: Calibration | None = None
    regions: list[RegionArea] | None = Field(
        None, description="named regions, each served by a base station of its own; absent = one region")
    floor_plan: FloorPlan | None = Field(
        None, description="obstacles nobody stands on and doors people use; absent = an open field entered anywhere")

    @property
    def metres_per_unit(self) -> float:
        """Metres in one of ``units`` (1 for the abstract ``unit``): converts physical defaults,
        such as a walking person's speed, into the deployment's units."""
        return METRES_PER_UNIT[self.units]

    @model_validator(mode="after")
    def _unique_ids(self):
        seen: set[str] = set()
        for sensor in self.sensors:
            if sensor.id in seen:
                raise ValueError(f"duplicate sensor id {sensor.id!r}")
            seen.add(sensor.id)
        names = [r.name for r in self.regions or ()]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate region name in {names}")
        r = self.region
        for x, y in self.floor_plan.doors if self.floor_plan else ():
            if not (r.xmin <= x <= r.xmax and r.ymin <= y <= r.ymax):
                raise ValueError(f"door ({x:g}, {y:g}) lies outside the region")
        return self

    def by_id(self) -> dict[str, DiskSensor | SectorSensor | MotionSensor | LineSensor]:
        """The sensors keyed by id."""
        return {s.id: s for s in self.sensors}
