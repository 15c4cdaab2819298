"""The msgpack codec of the bus messages: encoding is msgpack of the model's fields by name;
decoding validates and raises :class:`MessageError`, the single error type a service has to
catch for a bad payload. The hot messages decode through msgspec (below)."""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated, Any, Literal, TypeVar

import msgpack
import msgspec
from pydantic import BaseModel, ValidationError

from bintrack.bus_payloads import Clock, EndOfStream, LocalEstimate, RawSample, Transition, TruthSample
from bintrack.errors import BintrackError
from bintrack.message_base import SCHEMA_VERSION, Message


class MessageError(BintrackError, ValueError):
    """A payload that does not decode or does not validate; ``reason`` says why, in one line."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


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
    sent_to: dict[str, Annotated[int, msgspec.Meta(ge=0)]] | None = None


class _EndOfStreamView(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    t: float
    version: Literal[1] = SCHEMA_VERSION
    awaited: list[str] | None = None


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


# Messages of plain fields (scalars, or a list or dict of them), without aliases: their field
# dict is what model_dump(mode="json") gives (same keys, order and values), so the hot path
# packs it directly.
_FLAT = frozenset({RawSample, Transition, Clock, EndOfStream, LocalEstimate, TruthSample})


def encode(message: BaseModel) -> bytes:
    """msgpack bytes of ``message`` with field names as keys (aliases where a field has one)."""
    if type(message) in _FLAT:
        fields = message.__dict__
        later = getattr(message, "added_later", None)
        if later is not None and fields[later] is None:  # absent: the bytes as before it was added
            fields = {name: value for name, value in fields.items() if name != later}
        return msgpack.packb(fields, use_bin_type=True)
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
