"""foxglove.SceneUpdate messages of bintrack messages: what Foxglove's 3D panel draws.

Pure (dicts in the JSON form of the schema vendored in ``foxglove_scene_update.json``, from the
npm package ``@foxglove/schemas`` 2.1.0; no I/O). Used by the export of a recording
(:mod:`bintrack.live.foxglove_export`), by the recorder's Foxglove channels and by the live
bridge (``bintrack up --foxglove``), so all three draw the same scene. Frame ``map``, the
deployment's units as metres, timestamps in event time:

* ``sensors``: each disk or sector sensor's range as a flat grey cylinder (first message);
* ``sensor/<id>``: a yellow disk while the sensor detects (deleted when it stops);
* ``tracks``: each track of the latest scan as a sphere with its id as text and its velocity
  as an arrow (the displacement over 2 s), in the map page's track colours;
* ``reports``: each fused report's 95 % covariance ellipse as a flattened grey sphere;
* ``truth``: where each target really is, when replay publishes truth.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from bintrack.bus_payloads import PositionReports, TrackSet, Transition, TruthSample
from bintrack.deployment_model import Deployment, DiskSensor, SectorSensor
from bintrack.message_base import Message

SCENE_TOPIC = "/scene"
FRAME = "map"
SCENE_SCHEMA = Path(__file__).resolve().parent / "foxglove_scene_update.json"
ARROW_S = 2.0
ELLIPSE_K = math.sqrt(5.991464547107979)   # 95 % of a 2-D Gaussian: chi-square(2) quantile
# the map page's track colours (view/static/map.js): no layer uses them
TRACK_HEX = ["#1e88e5", "#d81b60", "#00897b", "#8e24aa", "#e64a19", "#3949ab", "#6d4c41", "#0097a7"]
PALETTE = [tuple(int(h[i:i + 2], 16) / 255 for i in (1, 3, 5)) for h in TRACK_HEX]


def _time(t: float) -> dict[str, int]:
    ns = max(0, round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _colour(r: float, g: float, b: float, a: float) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


def _pose(x: float, y: float, yaw: float = 0.0) -> dict[str, Any]:
    return {"position": {"x": x, "y": y, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}}


def _entity(t: float, entity_id: str, **primitives) -> dict[str, Any]:
    empty = {name: [] for name in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")}
    return {"timestamp": _time(t), "frame_id": FRAME, "id": entity_id, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False, "metadata": [], **empty, **primitives}


def _update(entities: list[dict] = (), deletions: list[dict] = ()) -> dict[str, Any]:
    return {"deletions": list(deletions), "entities": list(entities)}


class SceneBuilder:
    """foxglove.SceneUpdate messages, as dicts, of a network's messages in order."""

    def __init__(self, deployment: Deployment):
        self.sensors = deployment.by_id()
        self.started = False
        self.truth: dict[str, tuple[float, float]] = {}

    def updates(self, t: float, message: Message) -> list[dict[str, Any]]:
        """The SceneUpdates that ``message`` (at event time ``t``, s) brings; often none."""
        out = []
        if not self.started:
            self.started = True
            out.append(_update([_entity(t, "sensors", cylinders=[
                {"pose": _pose(s.x, s.y), "size": {"x": 2 * s.range, "y": 2 * s.range, "z": 0.02},
                 "bottom_scale": 1.0, "top_scale": 1.0, "color": _colour(0.56, 0.64, 0.68, 0.12)}
                for s in self.sensors.values() if isinstance(s, (DiskSensor, SectorSensor))])]))
        if isinstance(message, Transition):
            sensor = self.sensors.get(message.sensor)
            if isinstance(sensor, (DiskSensor, SectorSensor)):
                entity_id = f"sensor/{sensor.id}"
                idle = -1 if isinstance(sensor, SectorSensor) else 0
                if message.value == idle:
                    out.append(_update(deletions=[{"timestamp": _time(t), "type": 0, "id": entity_id}]))
                else:
                    out.append(_update([_entity(t, entity_id, cylinders=[
                        {"pose": _pose(sensor.x, sensor.y), "size": {"x": 2 * sensor.range, "y": 2 * sensor.range,
                                                                     "z": 0.03},
                         "bottom_scale": 1.0, "top_scale": 1.0, "color": _colour(0.99, 0.85, 0.21, 0.3)}])]))
        elif isinstance(message, TrackSet):
            spheres, texts, arrows = [], [], []
            for track in message.tracks:
                r, g, b = PALETTE[track.track % len(PALETTE)]
                spheres.append({"pose": _pose(track.x, track.y), "size": {"x": 1.0, "y": 1.0, "z": 1.0},
                                "color": _colour(r, g, b, 1.0)})
                texts.append({"pose": _pose(track.x + 0.8, track.y + 0.8), "billboard": True, "font_size": 14.0,
                              "scale_invariant": True, "color": _colour(r, g, b, 1.0), "text": str(track.track)})
                if track.vx is not None and track.vy is not None and math.hypot(track.vx, track.vy) > 0:
                    length = math.hypot(track.vx, track.vy) * ARROW_S
                    arrows.append({"pose": _pose(track.x, track.y, math.atan2(track.vy, track.vx)),
                                   "shaft_length": 0.7 * length, "shaft_diameter": 0.15, "head_length": 0.3 * length,
                                   "head_diameter": 0.4, "color": _colour(r, g, b, 1.0)})
            out.append(_update([_entity(t, "tracks", spheres=spheres, texts=texts, arrows=arrows)]))
        elif isinstance(message, PositionReports):
            spheres = []
            for report in message.reports:
                (cxx, cxy), (_, cyy) = report.cov
                half = (cxx + cyy) / 2
                disc = math.sqrt(max(0.0, ((cxx - cyy) / 2) ** 2 + cxy * cxy))
                major, minor = max(0.0, half + disc), max(0.0, half - disc)
                yaw = 0.5 * math.atan2(2 * cxy, cxx - cyy)
                spheres.append({"pose": _pose(report.x, report.y, yaw),
                                "size": {"x": 2 * ELLIPSE_K * math.sqrt(major), "y": 2 * ELLIPSE_K * math.sqrt(minor),
                                         "z": 0.05},
                                "color": _colour(0.56, 0.64, 0.68, 0.25)})
            out.append(_update([_entity(t, "reports", spheres=spheres)]))
        elif isinstance(message, TruthSample):
            self.truth[message.target] = (message.x, message.y)
            out.append(_update([_entity(t, "truth", spheres=[
                {"pose": _pose(x, y), "size": {"x": 0.6, "y": 0.6, "z": 0.6}, "color": _colour(1.0, 1.0, 1.0, 0.9)}
                for x, y in self.truth.values()])]))
        return out
