"""Bus messages as the compact JSON items the map page draws.

Every item is a dict with ``k`` (its kind) and, where the message has one, ``t`` (event
time, s). Positions and velocities are in the deployment's units (units/s), rounded to
``DIGITS`` decimals; nothing is converted. Pure functions, no I/O.
"""

from __future__ import annotations

from typing import Any

from bintrack.bus_payloads import (
    Clock, EndOfStream, LineObjectEstimate, LocalEstimate, PositionReports, TrackSet, Transition, TruthSample,
    VelocityEstimate,
)
from bintrack.deployment_model import Deployment, DiskSensor, LineSensor, MotionSensor, SectorSensor
from bintrack.message_base import Message

DIGITS = 4

Item = dict[str, Any]

# key kinds (keys.parse_key) a page draws
DRAWN_KINDS = frozenset({"transition", "tracks", "fusion_reports", "estimate", "laser_objects",
                         "motion_velocity", "truth", "clock", "eos"})


def _r(value: float | None) -> float | None:
    return None if value is None else round(float(value), DIGITS)


def sensor_item(sensor) -> Item:
    """One sensor of the deployment: ``id``, ``kind``, position ``x``, ``y`` (None for a line
    sensor of unknown position), range ``r``, sectors ``s`` and ``o`` (offset, rad), beam
    ``a``, ``b`` (a·x + b·y = 1)."""
    item: Item = {"id": sensor.id, "kind": sensor.kind, "x": _r(getattr(sensor, "x", None)),
                  "y": _r(getattr(sensor, "y", None))}
    if isinstance(sensor, (DiskSensor, SectorSensor)):
        item["r"] = _r(sensor.range)
    if isinstance(sensor, SectorSensor):
        item["s"], item["o"] = sensor.sectors, _r(sensor.offset)
    if isinstance(sensor, LineSensor) and sensor.a is not None:
        item["a"], item["b"] = sensor.a, sensor.b
    if isinstance(sensor, MotionSensor):
        item["period"] = sensor.period
    return item


def deployment_item(deployment: Deployment) -> Item:
    """The deployment: name, units, region ``[xmin, ymin, xmax, ymax]``, every sensor and, where
    the deployment has a floor plan, its obstacles' outlines and its doors (``plan``)."""
    region = deployment.region
    item = {"k": "deployment", "name": deployment.name, "units": deployment.units,
            "region": [region.xmin, region.ymin, region.xmax, region.ymax],
            "sensors": [sensor_item(s) for s in deployment.sensors]}
    plan = deployment.floor_plan
    if plan is not None:
        item["plan"] = {"obstacles": [[list(p) for p in area.vertices()] for area in plan.obstacles],
                        "doors": [list(p) for p in plan.doors]}
    return item


def message_item(message: Message) -> Item | None:
    """The item of one bus message, or None for a message the page does not draw."""
    if isinstance(message, Transition):
        return {"k": "sensor", "t": message.t, "id": message.sensor, "v": message.value}
    if isinstance(message, TrackSet):
        return {"k": "tracks", "t": message.t, "tracker": message.tracker,
                "tracks": [[tr.track, _r(tr.x), _r(tr.y), _r(tr.vx), _r(tr.vy)] for tr in message.tracks]}
    if isinstance(message, PositionReports):
        return {"k": "reports", "t": message.t,
                "reports": [[_r(p.x), _r(p.y), _r(p.cov[0][0]), _r(p.cov[0][1]), _r(p.cov[1][1]), int(p.shared)]
                            for p in message.reports]}
    if isinstance(message, LocalEstimate):
        return {"k": "estimate", "t": message.t, "node": message.node, "tracker": message.tracker,
                "x": _r(message.x), "y": _r(message.y), "vx": _r(message.vx), "vy": _r(message.vy)}
    if isinstance(message, LineObjectEstimate):
        return {"k": "object", "t": message.t_last, "n": message.object, "t0": message.t_first,
                "entry": [_r(message.entry_x), _r(message.entry_y)], "exit": [_r(message.exit_x), _r(message.exit_y)],
                "v": [_r(message.vx), _r(message.vy)], "rev": message.revision or 0}
    if isinstance(message, VelocityEstimate):
        position = None if message.x is None or message.y is None else [_r(message.x), _r(message.y)]
        return {"k": "velocity", "t": message.t, "method": message.method, "v": [_r(message.vx), _r(message.vy)],
                "p": position}
    if isinstance(message, TruthSample):
        return {"k": "truth", "t": message.t, "id": message.target, "x": _r(message.x), "y": _r(message.y)}
    if isinstance(message, Clock):
        return {"k": "clock", "t": message.t}
    if isinstance(message, EndOfStream):
        return {"k": "eos", "t": message.t}
    return None
