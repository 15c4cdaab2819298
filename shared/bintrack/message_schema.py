"""The JSON Schema of every message, which ``bintrack schema`` prints for programs in other
languages."""

from __future__ import annotations

import json

from bintrack.bus_payloads import (
    Clock,
    EndOfStream,
    LineObjectEstimate,
    LocalEstimate,
    PositionReports,
    RawSample,
    SensorState,
    TrackSet,
    Transition,
    TruthSample,
    VelocityEstimate,
)
from bintrack.deployment_model import Deployment
from bintrack.message_base import SCHEMA_VERSION, Message

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
