"""Read a binary sensor's MQTT payload: its status (1 detecting, 0 idle) and its own time, if any.

The formats of :class:`bintrack.mqtt.sensor_table.PayloadSpec`: Zigbee2MQTT's JSON
(``{"occupancy": true, "last_seen": "2026-01-01T10:00:00.123Z", ...}``), the ``ON``/``OFF`` of
Home Assistant and Tasmota, ``1``/``0``, and a JSON field path.
"""

from __future__ import annotations

import json
import math

from bintrack.mqtt.sensor_table import ZIGBEE_FIELDS, PayloadSpec, parse_instant

WORDS = {"on": 1, "off": 0, "true": 1, "false": 0, "1": 1, "0": 0, "open": 1, "closed": 0}


class PayloadError(ValueError):
    """A payload the sensor's reader cannot read; ``str()`` says why in one line."""


class PayloadReader:
    """Reads one sensor's payloads the way its table row says."""

    def __init__(self, spec: PayloadSpec):
        self.spec = spec
        self._path = tuple(spec.field.split(".")) if spec.field else None
        self._time = tuple(spec.time_path.split(".")) if spec.time_path else None

    def read(self, payload: bytes) -> tuple[int, int | None]:
        """(status 1/0, the payload's own time as Unix time in integer µs, or None)."""
        spec = self.spec
        if spec.format in ("on-off", "one-zero"):
            word = _text(payload).strip().lower()
            allowed = ("on", "off") if spec.format == "on-off" else ("1", "0")
            if word not in allowed:
                raise PayloadError(f"expected {'/'.join(a.upper() for a in allowed)}, got {_shown(payload)}")
            return WORDS[word] ^ spec.invert, None
        try:
            body = json.loads(_text(payload))
        except json.JSONDecodeError as exc:
            raise PayloadError(f"not JSON ({exc.msg} at character {exc.pos}): {_shown(payload)}") from None
        if not isinstance(body, dict):
            raise PayloadError(f"expected a JSON object, got {_shown(payload)}")
        if self._path is not None:
            value = _at(body, self._path)
            if value is _MISSING:
                raise PayloadError(f"no field {spec.field!r} in {_shown(payload)}")
        else:
            present = [name for name in ZIGBEE_FIELDS if name in body]
            if not present:
                raise PayloadError(f"none of {', '.join(ZIGBEE_FIELDS)} in {_shown(payload)}")
            value = body[present[0]]
        status = _status(value, spec.field or present[0])
        when = None
        if self._time is not None:
            stamp = _at(body, self._time)
            if stamp is not _MISSING and stamp is not None:
                when = _instant(stamp, spec.time_path)
        return status ^ spec.invert, when


_MISSING = object()


def _at(body: dict, path: tuple[str, ...]):
    for part in path:
        if not isinstance(body, dict) or part not in body:
            return _MISSING
        body = body[part]
    return body


def _status(value, name: str) -> int:
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int) and value in (0, 1):
        return value
    if isinstance(value, str) and value.strip().lower() in WORDS:
        return WORDS[value.strip().lower()]
    raise PayloadError(f"field {name!r} is {json.dumps(value)[:40]}, not a binary status")


def _instant(stamp, name: str) -> int:
    """A timestamp field: ISO 8601 text, or a number of epoch milliseconds (Zigbee2MQTT's
    ``last_seen: epoch``); Unix time in integer µs."""
    if isinstance(stamp, bool) or not isinstance(stamp, (int, float, str)):
        raise PayloadError(f"time field {name!r} is {json.dumps(stamp)[:40]}, not a time")
    if isinstance(stamp, str):
        try:
            return parse_instant(stamp)
        except ValueError:
            raise PayloadError(f"time field {name!r} is {stamp[:40]!r}, not ISO 8601") from None
    if not math.isfinite(stamp):
        raise PayloadError(f"time field {name!r} is not finite")
    return round(stamp * 1000)


def _text(payload: bytes) -> str:
    try:
        return payload.decode()
    except UnicodeDecodeError:
        raise PayloadError(f"not UTF-8 text: {_shown(payload)}") from None


def _shown(payload: bytes, limit: int = 60) -> str:
    """The payload as a short printable excerpt, for a log line."""
    text = repr(bytes(payload[:limit]))[2:-1]
    return text + ("…" if len(payload) > limit else "") if payload else "(empty)"
