"""The sensor table: which MQTT topic is which sensor, where it is, and how to read its payload.

A TOML (or JSON) file with the deployment's name, units and region, and one ``[[sensors]]``
entry per sensor: the fields of a sensor in ``deployment.json`` (id, kind, x, y, range, …)
plus ``topic``, ``payload`` (how to read it, :class:`PayloadSpec`) and ``clock_offset`` (s,
what the sensor's clock is ahead of event time). ``epoch`` says which wall-clock instant is
event time 0 (default the Unix epoch: event time = Unix time, s).
"""

from __future__ import annotations

import json
import tomllib
from datetime import datetime, timezone
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from bintrack.deployment_model import Deployment, Region
from bintrack.message_codec import first_error

PAYLOAD_FORMATS = ("zigbee2mqtt", "on-off", "one-zero", "json")
ZIGBEE_FIELDS = ("occupancy", "presence", "contact")
TABLE_ONLY = ("topic", "payload", "clock_offset")  # fields of a table row that are not the deployment's


class TableError(ValueError):
    """A sensor table that does not load; ``str()`` is one line naming the file and the field."""


class PayloadSpec(BaseModel):
    """How to read a sensor's payload into 1 (detecting) or 0.

    ``zigbee2mqtt``: JSON whose ``field`` (default: the first of occupancy, presence, contact
    present) is a boolean, and whose ``time_field`` (default ``last_seen``) is the time, ISO 8601
    or epoch milliseconds, if there. ``on-off``: ``ON``/``OFF`` (Home Assistant, Tasmota).
    ``one-zero``: ``1``/``0``. ``json``: the value at the dotted ``field`` path (boolean, 0/1 or
    ON/OFF), time at ``time_field`` if given. ``invert`` swaps 1 and 0 (a door contact: closed
    is ``contact: true``, and an open door is the detection).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["zigbee2mqtt", "on-off", "one-zero", "json"] = "zigbee2mqtt"
    field: str | None = None
    time_field: str | None = None
    invert: bool = False

    @model_validator(mode="after")
    def _field_for_json(self):
        if self.format == "json" and not self.field:
            raise ValueError("payload format json needs a field path (field = \"a.b.c\")")
        if self.format in ("on-off", "one-zero") and (self.field or self.time_field):
            raise ValueError(f"payload format {self.format} is a plain word: it has no field or time_field")
        return self

    @property
    def time_path(self) -> str | None:
        return self.time_field or ("last_seen" if self.format == "zigbee2mqtt" else None)


class TableSensor(BaseModel):
    """One row: ``topic``, ``payload``, ``clock_offset`` (s) and the deployment's sensor fields."""

    model_config = ConfigDict(extra="allow", frozen=True)

    id: str
    topic: str
    payload: PayloadSpec = PayloadSpec()
    clock_offset: float = Field(0.0, allow_inf_nan=False,
                                description="the sensor's clock minus event time, s (subtracted from its timestamps)")

    @field_validator("topic")
    @classmethod
    def _concrete(cls, topic: str) -> str:
        if not topic or "+" in topic or "#" in topic:
            raise ValueError(f"topic {topic!r} must be a concrete topic (no wildcards)")
        return topic


class SensorTable(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    units: Literal["m", "ft", "unit"]
    region: Region
    epoch: str | float = Field(0.0, description="the instant of event time 0: ISO 8601, or Unix time in s")
    subscribe: list[str] = Field(default_factory=list, description="topic filters to subscribe to besides the "
                                 "sensors' topics (e.g. zigbee2mqtt/+): a message on one no sensor has is counted")
    sensors: list[TableSensor]

    @model_validator(mode="after")
    def _unique_topics(self):
        seen: dict[str, str] = {}
        for sensor in self.sensors:
            if sensor.topic in seen:
                raise ValueError(f"topic {sensor.topic!r} is given to both {seen[sensor.topic]} and {sensor.id}")
            seen[sensor.topic] = sensor.id
        parse_instant(self.epoch)
        return self

    @property
    def epoch_us(self) -> int:
        """Event time 0 as Unix time, integer microseconds."""
        return parse_instant(self.epoch)

    def deployment(self) -> Deployment:
        """The deployment the bridge serves: the rows without their MQTT fields (their clock
        offsets are applied by the bridge, so event times on the bus are already corrected)."""
        sensors = [{k: v for k, v in row.model_dump().items() if k not in TABLE_ONLY} for row in self.sensors]
        return Deployment(name=self.name, units=self.units, region=self.region, sensors=sensors)

    def by_topic(self) -> dict[str, TableSensor]:
        return {row.topic: row for row in self.sensors}

    def subscriptions(self) -> list[str]:
        """The topic filters to subscribe to: ``subscribe`` and each sensor topic none of them covers."""
        return [*self.subscribe, *(row.topic for row in self.sensors
                                   if not any(topic_matches(f, row.topic) for f in self.subscribe))]


def topic_matches(topic_filter: str, topic: str) -> bool:
    """Whether the MQTT ``topic_filter`` (with ``+`` and ``#``) matches the concrete ``topic``."""
    parts, levels = topic_filter.split("/"), topic.split("/")
    for i, part in enumerate(parts):
        if part == "#":
            return True
        if i >= len(levels) or (part != "+" and part != levels[i]):
            return False
    return len(parts) == len(levels)


def parse_instant(value: str | float | int) -> int:
    """An instant (ISO 8601 text, naive = UTC; or Unix time in s) as Unix time in integer µs."""
    if isinstance(value, (int, float)):
        return round(value * 1_000_000)
    try:
        instant = datetime.fromisoformat(value.strip())
    except (ValueError, AttributeError):
        raise ValueError(f"not an ISO 8601 time: {value!r}") from None
    if instant.tzinfo is None:
        instant = instant.replace(tzinfo=timezone.utc)
    return (instant - datetime(1970, 1, 1, tzinfo=timezone.utc)) // _MICROSECOND


_MICROSECOND = datetime(1970, 1, 1, 0, 0, 0, 1) - datetime(1970, 1, 1)


def load_table(path: str | Path) -> SensorTable:
    """Read and check a sensor table (``.toml``, else JSON); raises :class:`TableError`."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise TableError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text) if path.suffix != ".json" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise TableError(f"{path}: not {'JSON' if path.suffix == '.json' else 'TOML'}: {exc}") from None
    try:
        table = SensorTable.model_validate(data)
        table.deployment()
    except ValidationError as exc:
        raise TableError(f"{path}: {first_error(exc)}") from None
    except ValueError as exc:
        raise TableError(f"{path}: {exc}") from None
    return table


def table_text(deployment: Deployment, epoch: str, base: str = "zigbee2mqtt") -> str:
    """A sensor table (TOML) for ``deployment`` whose sensors are Zigbee2MQTT occupancy sensors
    named by their ids (topic ``<base>/<id>``), event time 0 at ``epoch`` (ISO 8601)."""
    lines = [f"name = {json.dumps(deployment.name)}", f"units = {json.dumps(deployment.units)}",
             f"epoch = {json.dumps(epoch)}", f"subscribe = [{json.dumps(base + '/+')}]", "", "[region]"]
    lines += [f"{k} = {v!r}" for k, v in deployment.region.model_dump().items()]
    for sensor in deployment.sensors:
        fields = {k: v for k, v in sensor.model_dump(exclude_none=True).items()
                  if not (k in ("clock_offset", "clock_skew") and v == 0)}
        lines += ["", "[[sensors]]", f"id = {json.dumps(fields.pop('id'))}", f"topic = {json.dumps(f'{base}/{sensor.id}')}",
                  'payload = { format = "zigbee2mqtt", field = "occupancy" }']
        lines += [f"{k} = {json.dumps(v)}" for k, v in fields.items()]
    return "\n".join(lines) + "\n"
