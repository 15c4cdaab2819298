"""Decoding and encoding a hot message: pydantic beside msgspec, in one run.

A ``Transition`` (the payload of every ``sensor/<id>/transition``) as msgpack bytes, decoded
and validated by pydantic (``msgpack.unpackb`` + ``validate_python``, what ``decode`` does for
the other messages) and by the msgspec view (``decode_view``), and encoded from the model's
field dict (``encode``) and from the msgspec Struct. Best of 5 × 100 000 calls, µs per call.

Run: ``nice -n 10 .venv/bin/python benchmarks/codec.py``
"""

from __future__ import annotations

import timeit

import msgpack
import msgspec

from bintrack.bus_payloads import Transition
from bintrack.message_codec import VIEWS, decode, decode_view, encode

CALLS, REPEAT = 100_000, 5


def best(call) -> float:
    return min(timeit.repeat(call, number=CALLS, repeat=REPEAT)) / CALLS * 1e6


def main() -> None:
    message = Transition(t=123.456789, sensor="n123", value=1, previous=0, seq=17, source="host-1234", source_seq=1234)
    payload = encode(message)
    view = decode_view(Transition, payload)
    encoder = msgspec.msgpack.Encoder()
    assert isinstance(view, VIEWS[Transition])
    rows = [
        ("decode + validate, pydantic (decode)", best(lambda: decode(Transition, payload))),
        ("decode + validate, msgspec view (decode_view)", best(lambda: decode_view(Transition, payload))),
        ("encode, pydantic model's field dict + msgpack (encode)", best(lambda: encode(message))),
        ("encode, pydantic model_dump + msgpack (the former encode)",
         best(lambda: msgpack.packb(message.model_dump(mode="json", by_alias=True), use_bin_type=True))),
        ("encode, msgspec Struct", best(lambda: encoder.encode(view))),
    ]
    width = max(len(name) for name, _ in rows)
    print(f"{'Transition, ' + str(len(payload)) + ' bytes':<{width}}  µs/call")
    for name, value in rows:
        print(f"{name:<{width}}  {value:7.2f}")
    print(f"ratio decode pydantic / msgspec: {rows[0][1] / rows[1][1]:.1f}")


if __name__ == "__main__":
    main()
