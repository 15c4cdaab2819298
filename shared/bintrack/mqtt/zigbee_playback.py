"""A dataset as Zigbee2MQTT devices would report it: the MQTT messages, pure (no I/O).

Each event of a binary (disk) sensor becomes a JSON state on ``<base>/<sensor id>``:
``{"occupancy": true, "last_seen": "<ISO 8601, µs>", "linkquality": 120}`` (Zigbee2MQTT's
payload of an occupancy sensor with ``last_seen`` on), the time being ``epoch`` + the event's
time. The stream ends with a message on :data:`END_TOPIC` whose ``last_seen`` is the last event's.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from datetime import datetime, timedelta, timezone

from bintrack.formats import Event
from bintrack.deployment_model import Deployment, DiskSensor

BASE_TOPIC = "zigbee2mqtt"
END_TOPIC = "bintrack/end"
UNIX_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


def iso_time(unix_us: int) -> str:
    """Unix time in integer µs as ISO 8601 UTC text with µs (``2026-01-01T10:00:00.048651Z``)."""
    return (UNIX_EPOCH + timedelta(microseconds=unix_us)).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def check_zigbee(deployment: Deployment) -> None:
    """Raise ValueError unless every sensor is binary (disk), as a Zigbee occupancy sensor is."""
    other = [s.id for s in deployment.sensors if not isinstance(s, DiskSensor)]
    if other:
        raise ValueError(f"only binary (disk) sensors play as Zigbee2MQTT occupancy sensors; "
                         f"{len(other)} are not, e.g. {other[0]}")


def zigbee_messages(events: Iterable[Event], epoch_us: int, base: str = BASE_TOPIC) -> Iterator[tuple[float, str, bytes]]:
    """(event time s, topic, payload) of each event in order, then of the end of stream."""
    last = None
    for event in events:
        stamp = epoch_us + round(event.t * 1_000_000)
        body = {"occupancy": bool(event.value), "last_seen": iso_time(stamp), "linkquality": 120}
        last = event.t
        yield event.t, f"{base}/{event.sensor}", json.dumps(body).encode()
    if last is not None:
        yield last, END_TOPIC, json.dumps({"last_seen": iso_time(epoch_us + round(last * 1_000_000))}).encode()
