"""The root of every bus message: the schema version, event time in seconds, and the strict,
frozen pydantic model every payload and its parts are built on (DESIGN §3–4).

Each message carries ``version`` (the schema version) and event time ``t`` in seconds where
it has one.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

SCHEMA_VERSION = 1

Seconds = Annotated[float, Field(description="event time, s")]


class FrozenModel(BaseModel):
    """A model that refuses unknown fields and non-finite floats, and cannot change once made."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class Message(FrozenModel):
    """A payload on the bus (or a file's content that is also one, the deployment)."""

    version: Literal[1] = Field(SCHEMA_VERSION, description="schema version of bintrack messages")
