"""``bintrack export RECORDING --foxglove OUT.mcap``: a copy of a recording that Foxglove opens.

Foxglove does not decode msgpack channels, so a bintrack recording shows there as channels
without messages. This writes every recorded message again, on the same topic (its key) and at
the same log time (event time), JSON-encoded (``message_encoding="json"``) with its JSON
Schema (``bintrack.<Message>``, the pydantic schema), so the Raw Messages and Plot panels read
it; plus one channel ``/scene`` of ``foxglove.SceneUpdate`` messages for the 3D panel
(:mod:`bintrack.live.foxglove_scene`).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from mcap.writer import Writer

from bintrack import __version__
from bintrack.formats import deployment_text
from bintrack.live.foxglove_scene import SCENE_SCHEMA, SCENE_TOPIC, SceneBuilder
from bintrack.live.recording import (DEPLOYMENT_ATTACHMENT, KIND_TYPES, RECORDING_FORMAT, RECORDING_METADATA, Recording,
                                     open_recording)

log = logging.getLogger("bintrack")


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
        builder = SceneBuilder(recording.deployment)
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


def foxglove_path(path: Path | str) -> Path:
    """Where ``--foxglove`` writes Foxglove's copy of the recording ``path``: FILE.foxglove.mcap."""
    return Path(path).with_suffix(".foxglove.mcap")


def write_foxglove_copy(path: Path | str) -> None:
    """Foxglove's copy of the finished recording ``path`` beside it."""
    copy = foxglove_path(path)
    export_foxglove(open_recording(path), copy)
    log.info("recorder: Foxglove's copy in %s", copy)
