"""Every payload on the bus (DESIGN §3–4) as a pydantic v2 model, and their msgpack codec.

Each message carries ``version`` (the schema version) and event time ``t`` in seconds where
it has one. Encoding is msgpack of the model's fields by name; decoding validates and raises
:class:`MessageError`, the single error type a service has to catch for a bad payload.
"""

from __future__ import annotations

import json
import re
from functools import lru_cache
from typing import Annotated, Any, Literal, TypeVar, Union

import msgpack
import msgspec
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

SCHEMA_VERSION = 1
DEPLOYMENT_FORMAT = "bintrack.deployment/1"

# A sensor id is one chunk of a Zenoh key expression and one CSV cell.
SENSOR_ID_PATTERN = r"^[^/*$?#,\s\"']+$"
_SENSOR_ID_RE = re.compile(SENSOR_ID_PATTERN)

Seconds = Annotated[float, Field(description="event time, s")]


class MessageError(ValueError):
    """A payload that does not decode or does not validate; ``reason`` says why, in one line."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class Message(_Model):
    version: Literal[1] = Field(SCHEMA_VERSION, description="schema version of bintrack messages")


# --------------------------------------------------------------------------- deployment


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


class RegionArea(BaseModel):
    """One named region of a deployment served by its own base station: a rectangle
    (``xmin``, ``ymin``, ``xmax``, ``ymax``) or a ``polygon`` ([[x, y], …], deployment units)."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)
    name: str = Field(pattern=REGION_NAME_PATTERN, description="region name, a key-expression chunk")
    xmin: float | None = None
    ymin: float | None = None
    xmax: float | None = None
    ymax: float | None = None
    polygon: list[Point] | None = Field(None, description="vertices in order, deployment units")

    @model_validator(mode="after")
    def _one_shape(self):
        corners = (self.xmin, self.ymin, self.xmax, self.ymax)
        if self.polygon is not None:
            if any(c is not None for c in corners):
                raise ValueError(f"region {self.name!r}: give a rectangle or a polygon, not both")
            if len(self.polygon) < 3:
                raise ValueError(f"region {self.name!r}: a polygon needs at least 3 vertices")
        elif any(c is None for c in corners):
            raise ValueError(f"region {self.name!r}: needs xmin, ymin, xmax, ymax or a polygon")
        elif not (self.xmin < self.xmax and self.ymin < self.ymax):
            raise ValueError(f"region {self.name!r} needs xmin < xmax and ymin < ymax")
        return self

    def vertices(self) -> list[Point]:
        """The outline, deployment units (a rectangle's four corners counter-clockwise)."""
        if self.polygon is not None:
            return [tuple(p) for p in self.polygon]
        return [(self.xmin, self.ymin), (self.xmax, self.ymin), (self.xmax, self.ymax), (self.xmin, self.ymax)]


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
        return self

    def by_id(self) -> dict[str, DiskSensor | SectorSensor | MotionSensor | LineSensor]:
        """The sensors keyed by id."""
        return {s.id: s for s in self.sensors}


# --------------------------------------------------------------------------- bus payloads


class RawSample(Message):
    """One sample of one sensor as the hardware (or replay) reports it."""

    t: Seconds
    sensor: str = Field(description="sensor id")
    value: int = Field(description="disk 0/1; sector 0..s-1 or -1; motion +1/-1; line 1")


class Transition(Message):
    """A change of a sensor's status (papers 000, 001): sent only when the status changes."""

    t: Seconds
    sensor: str = Field(description="sensor id")
    value: int = Field(description="new status")
    previous: int = Field(description="status before the change")
    seq: int = Field(ge=1, description="per-sensor sequence number, 1 for the first transition")
    source: str | None = Field(None, description="id of the sensor-agent instance that published it")
    source_seq: int | None = Field(None, ge=1, description="that instance's count of transitions, 1 for its first")


class SensorState(Message):
    """Reply of a sensor's ``state`` queryable: its current status and last ``seq``, and the
    recent transitions after the ``since`` seq the query asked for (to repair a gap)."""

    t: Seconds
    sensor: str
    value: int
    seq: int = Field(ge=0, description="seq of the last transition, 0 if none yet")
    missed: list[Transition] = Field(default_factory=list, description="transitions after the asked seq, oldest first")


class LocalEstimate(Message):
    """A node's estimate of the target at one of its transitions (peer agents, single target)."""

    t: Seconds
    node: str = Field(description="id of the estimating node")
    tracker: str = Field(description="tracker name")
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    vx: float | None = Field(None, description="velocity, units/s")
    vy: float | None = Field(None, description="velocity, units/s")
    arc: float | None = Field(None, ge=0, description="central angle of the final arc, rad (arc/sector trackers)")
    weight: float | None = Field(None, ge=0, description="trajectory-fit weight (paper 001 eq. 2 or 4)")


class PositionReport(_Model):
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    cov: tuple[tuple[float, float], tuple[float, float]] = Field(
        description="2×2 position covariance, units²"
    )
    weight: float = Field(1.0, ge=0, description="the report's evidence: its cluster's summed cell likelihood "
                          "(clustering fusion) or its gain, nats of eq. 4 (fitted fusion); 0 for a shared copy")
    shared: bool = Field(False, description="a copy of another report, for a second target that a track "
                         "expects there but whose detections are unresolved from that report's")


class PositionReports(Message):
    """One scan of fused position reports (paper 004 §III)."""

    t: Seconds
    reports: list[PositionReport]


class Track(_Model):
    track: int = Field(ge=0, description="track identity, persistent across scans")
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    vx: float | None = Field(None, description="velocity, units/s")
    vy: float | None = Field(None, description="velocity, units/s")
    region: str | None = Field(None, description="merged picture: the region whose base station tracks it")
    stale: bool = Field(False, description="merged picture: its region's base station is gone; the last "
                        "position it gave, not updated")


class TrackSet(Message):
    """The tracks at one scan; also what the ``tracks`` queryable returns."""

    t: Seconds
    tracker: str
    tracks: list[Track]


class LineObjectEstimate(Message):
    """One object's straight pass through a line-sensor region (paper 003)."""

    object: int = Field(ge=1, description="pass number, from 1 in time order")
    t_first: Seconds
    t_last: Seconds
    entry_x: float
    entry_y: float
    exit_x: float
    exit_y: float
    vx: float = Field(description="velocity, units/s")
    vy: float = Field(description="velocity, units/s")
    entry_sd: float | None = Field(default=None, ge=0, description="standard deviation of the entry point, units "
                                   "(√ trace of its covariance; None if unknown)")
    exit_sd: float | None = Field(default=None, ge=0, description="standard deviation of the exit point, units "
                                  "(√ trace of its covariance; None if unknown)")


class VelocityEstimate(Message):
    """Velocity (and optionally position) from closer/farther sensors (paper 002)."""

    t: Seconds
    method: str = Field(description="velocity-plane, svm, ppr or motion-rw")
    vx: float = Field(description="units/s")
    vy: float = Field(description="units/s")
    x: float | None = None
    y: float | None = None


class TruthSample(Message):
    """One row of a dataset's truth.csv, replayed in event time beside the events (optional
    ``truth`` key): where target ``target`` really was at ``t``."""

    t: Seconds
    target: str = Field(description="target id as in truth.csv")
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")


class Clock(Message):
    """Event time advances even when no sensor reports. Also a service's progress report."""

    t: Seconds
    sent: int | None = Field(None, ge=0, description="in a sensor agent's progress report: transitions it has sent so far")
    released: float | None = Field(None, description="in a tracker service's progress report: its watermark, s — "
                                   "every output of an event time before it has been published")


class EndOfStream(Message):
    """The replay has ended: flush and emit final results."""

    t: Seconds


MESSAGE_TYPES: tuple[type[Message], ...] = (
    RawSample,
    Transition,
    SensorState,
    LocalEstimate,
    PositionReports,
    TrackSet,
    LineObjectEstimate,
    VelocityEstimate,
    TruthSample,
    Clock,
    EndOfStream,
    Deployment,
)

M = TypeVar("M", bound=BaseModel)


# --------------------------------------------------------------------------- hot path
# The messages every sample of a run carries (raw samples, transitions, clock ticks, progress)
# are decoded and validated by msgspec into read-only Structs with the models' fields, some
# twenty times faster than pydantic. The pydantic models stay the definition (``bintrack
# schema`` prints theirs; a test holds the Structs to them): a payload msgspec refuses, or
# one with a non-finite float, goes through pydantic, which gives the error (or accepts it).


class _RawSampleView(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    t: float
    sensor: str
    value: int
    version: Literal[1] = SCHEMA_VERSION


class _TransitionView(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    t: float
    sensor: str
    value: int
    previous: int
    seq: Annotated[int, msgspec.Meta(ge=1)]
    version: Literal[1] = SCHEMA_VERSION
    source: str | None = None
    source_seq: Annotated[int, msgspec.Meta(ge=1)] | None = None


class _ClockView(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    t: float
    version: Literal[1] = SCHEMA_VERSION
    sent: Annotated[int, msgspec.Meta(ge=0)] | None = None
    released: float | None = None


class _EndOfStreamView(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    t: float
    version: Literal[1] = SCHEMA_VERSION


VIEWS: dict[type[Message], type[msgspec.Struct]] = {
    RawSample: _RawSampleView, Transition: _TransitionView, Clock: _ClockView, EndOfStream: _EndOfStreamView,
}
_VIEW_DECODERS = {cls: msgspec.msgpack.Decoder(view) for cls, view in VIEWS.items()}


def decode_view(cls: type[Message], payload: bytes | bytearray | memoryview):
    """Decode and validate ``payload`` as ``cls`` (RawSample, Transition, Clock or EndOfStream)
    into a read-only Struct with the same fields, or as the pydantic model for any other
    ``cls``; raises :class:`MessageError` with pydantic's reason on any fault."""
    decoder = _VIEW_DECODERS.get(cls)
    if decoder is not None:
        try:
            view = decoder.decode(payload)
        except (msgspec.ValidationError, msgspec.DecodeError):
            pass  # pydantic says why (or accepts what msgspec's stricter types refused)
        else:
            # x − x is 0 for a finite float, nan for ±inf and nan; t is the float field of all
            # four, Clock also has ``released``
            t = view.t
            if t - t == 0.0 and (cls is not Clock or view.released is None or view.released - view.released == 0.0):
                return view
    return decode(cls, payload)


# Messages of scalar fields only, without aliases: their field dict is what model_dump(mode="json")
# gives (same keys, same order, same values), so the hot path packs it directly.
_FLAT = frozenset({RawSample, Transition, Clock, EndOfStream, LocalEstimate, TruthSample})


def encode(message: BaseModel) -> bytes:
    """msgpack bytes of ``message`` with field names as keys (aliases where a field has one)."""
    if type(message) in _FLAT:
        return msgpack.packb(message.__dict__, use_bin_type=True)
    return msgpack.packb(message.model_dump(mode="json", by_alias=True), use_bin_type=True)


def encode_raw_sample(t: float, sensor: str, value: int) -> bytes:
    """``encode(RawSample(t=t, sensor=sensor, value=value))`` without building the model, for
    fields already validated (a dataset's rows, checked when it was opened)."""
    return msgpack.packb({"version": SCHEMA_VERSION, "t": float(t), "sensor": sensor, "value": int(value)},
                         use_bin_type=True)


def encode_transition(t: float, sensor: str, value: int, previous: int, seq: int, source: str | None = None,
                      source_seq: int | None = None) -> bytes:
    """``encode(Transition(...))`` of these fields without building the model, for fields valid
    by construction (a sensor agent's, from a validated sample)."""
    return msgpack.packb({"version": SCHEMA_VERSION, "t": t, "sensor": sensor, "value": value, "previous": previous,
                          "seq": seq, "source": source, "source_seq": source_seq}, use_bin_type=True)


RESENT = msgpack.packb({"resent": True})
"""The attachment of a raw sample that a restarted replay sends again (a kill may have caught
it in the dead instance's send path): a receiver keeps it only if it is newer than the last
sample it has of that sensor."""


@lru_cache(maxsize=64)  # the attachments on raw keys are few (none, or a replay's one or two)
def is_resent(attachment: bytes) -> bool:
    """Whether a sample's attachment (bytes) marks it as sent again (:data:`RESENT`)."""
    try:
        body = msgpack.unpackb(attachment)
    except Exception:  # msgpack raises several unrelated types
        return False
    return isinstance(body, dict) and body.get("resent") is True


def decode(cls: type[M], payload: bytes | bytearray | memoryview) -> M:
    """Decode and validate ``payload`` as ``cls``; raises :class:`MessageError` on any fault."""
    try:
        obj: Any = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types
        raise MessageError(f"not msgpack: {type(exc).__name__}: {exc}") from None
    if not isinstance(obj, dict):
        raise MessageError(f"expected a map for {cls.__name__}, got {type(obj).__name__}")
    try:
        return cls.__pydantic_validator__.validate_python(obj)
    except ValidationError as exc:
        raise MessageError(f"invalid {cls.__name__}: {first_error(exc)}") from None


def first_error(exc: ValidationError) -> str:
    """One line for the first error of a pydantic ValidationError: ``field.path: message``."""
    err = exc.errors()[0]
    return f"{location_text(err['loc'])}: {err['msg']}"


def location_text(loc: tuple) -> str:
    """``('sensors', 3, 'disk', 'range')`` → ``sensors[3].range`` (discriminator tags dropped)."""
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        elif part in ("disk", "sector", "motion", "line"):
            continue
        else:
            text += ("." if text else "") + str(part)
    return text or "(top level)"


def json_schema() -> dict:
    """JSON Schema of every message, keyed by message name."""
    schemas = {cls.__name__: cls.model_json_schema(by_alias=True) for cls in MESSAGE_TYPES}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "bintrack messages",
        "description": f"msgpack maps with these fields; schema version {SCHEMA_VERSION}",
        "version": SCHEMA_VERSION,
        "messages": schemas,
    }


def json_schema_text() -> str:
    return json.dumps(json_schema(), indent=2, sort_keys=True)

