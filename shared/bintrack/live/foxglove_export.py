"""``bintrack export RECORDING --foxglove OUT.mcap``: a copy of a recording that Foxglove opens.

Foxglove does not decode msgpack channels, so a bintrack recording shows there as channels
without messages. This writes every recorded message again, on the same topic (its key) and at
the same log time (event time), JSON-encoded (``message_encoding="json"``) with its JSON
Schema (``bintrack.<Message>``, the pydantic schema), so the Raw Messages and Plot panels read
it; plus one channel ``/scene`` of ``foxglove.SceneUpdate`` messages (schema vendored from the
npm package ``@foxglove/schemas`` 2.1.0) for the 3D panel, in frame ``map`` with the
deployment's units as metres:

* ``sensors``: each disk or sector sensor's range as a flat grey cylinder (first message time);
* ``sensor/<id>``: an orange disk while the sensor detects (deleted when it stops);
* ``tracks``: each track of the latest scan as a sphere with its id as text and its velocity
  as an arrow (the displacement over 2 s);
* ``reports``: each fused report's 95 % covariance ellipse as a flattened sphere;
* ``truth``: where each target really is, when the recording holds replayed truth.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from mcap.writer import Writer

from bintrack import __version__
from bintrack.formats import deployment_text
from bintrack.messages import DiskSensor, Message, PositionReports, SectorSensor, TrackSet, Transition, TruthSample
from bintrack.live.recording import DEPLOYMENT_ATTACHMENT, KIND_TYPES, RECORDING_FORMAT, RECORDING_METADATA, Recording

SCENE_TOPIC = "/scene"
FRAME = "map"
SCENE_SCHEMA = Path(__file__).resolve().parent / "foxglove_scene_update.json"
ARROW_S = 2.0
ELLIPSE_K = math.sqrt(5.991464547107979)   # 95 % of a 2-D Gaussian: chi-square(2) quantile
PALETTE = [(0.90, 0.22, 0.21), (0.12, 0.53, 0.90), (0.26, 0.63, 0.28), (0.98, 0.55, 0.0), (0.56, 0.14, 0.67),
           (0.0, 0.54, 0.48), (0.43, 0.30, 0.25), (0.85, 0.11, 0.38), (0.22, 0.29, 0.67), (0.49, 0.70, 0.26)]


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
    """foxglove.SceneUpdate messages of a recording's messages (pure: dicts out, no I/O)."""

    def __init__(self, recording: Recording):
        self.sensors = recording.deployment.by_id()
        self.started = False
        self.truth: dict[str, tuple[float, float]] = {}

    def updates(self, t: float, message: Message) -> list[dict[str, Any]]:
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
                         "bottom_scale": 1.0, "top_scale": 1.0, "color": _colour(1.0, 0.6, 0.0, 0.3)}])]))
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
                                "color": _colour(0.67, 0.28, 0.74, 0.25)})
            out.append(_update([_entity(t, "reports", spheres=spheres)]))
        elif isinstance(message, TruthSample):
            self.truth[message.target] = (message.x, message.y)
            out.append(_update([_entity(t, "truth", spheres=[
                {"pose": _pose(x, y), "size": {"x": 0.6, "y": 0.6, "z": 0.6}, "color": _colour(1.0, 1.0, 1.0, 0.9)}
                for x, y in self.truth.values()])]))
        return out


def export_foxglove(recording: Recording, out: Path | str) -> dict[str, int]:
    """Write ``out`` from ``recording``; returns messages written per topic kind (and ``scene``).
    FormatError for a recorded payload that does not decode."""
    counts: dict[str, int] = {}
    with open(out, "wb") as handle:
        writer = Writer(handle)
        writer.start(profile="", library=f"bintrack {__version__}")
        writer.add_metadata(RECORDING_METADATA, {"format": RECORDING_FORMAT, "net": recording.net,
                                                 "encoding": "json"})
        writer.add_attachment(create_time=0, log_time=0, name=DEPLOYMENT_ATTACHMENT, media_type="application/json",
                              data=deployment_text(recording.deployment).encode())
        scene_schema = writer.register_schema(name="foxglove.SceneUpdate", encoding="jsonschema",
                                              data=SCENE_SCHEMA.read_bytes())
        scene = writer.register_channel(topic=SCENE_TOPIC, message_encoding="json", schema_id=scene_schema)
        schemas: dict[type, int] = {}
        channels: dict[str, int] = {}
        builder = SceneBuilder(recording)
        kinds = set(KIND_TYPES) - {"progress", "done", "eos"}
        for record, message in recording.messages(kinds):
            cls = type(message)
            if cls not in schemas:
                schema = json.dumps(cls.model_json_schema(by_alias=True), sort_keys=True).encode()
                schemas[cls] = writer.register_schema(name=f"bintrack.{cls.__name__}", encoding="jsonschema", data=schema)
            if record.key not in channels:
                channels[record.key] = writer.register_channel(topic=record.key, message_encoding="json",
                                                               schema_id=schemas[cls])
            log_time = round(record.t * 1e9)
            writer.add_message(channel_id=channels[record.key], log_time=log_time, publish_time=record.received_ns,
                               data=message.model_dump_json(by_alias=True).encode())
            counts[record.kind] = counts.get(record.kind, 0) + 1
            for update in builder.updates(record.t, message):
                writer.add_message(channel_id=scene, log_time=log_time, publish_time=record.received_ns,
                                   data=json.dumps(update, separators=(",", ":")).encode())
                counts["scene"] = counts.get("scene", 0) + 1
        writer.finish()
    return counts
