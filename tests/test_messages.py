import json

import msgpack
import pytest

from bintrack.cli import main as cli
from bintrack.bus_payloads import Clock, LocalEstimate, PositionReport, PositionReports, Track, TrackSet, Transition
from bintrack.deployment_model import Deployment
from bintrack.message_codec import MessageError, decode, encode
from bintrack.message_schema import MESSAGE_TYPES

SAMPLES = [
    Transition(t=1.5, sensor="n1", value=1, previous=0, seq=3),
    LocalEstimate(t=2.0, node="n1", tracker="arc", x=1.0, y=2.0, vx=0.1, vy=None, arc=0.2, weight=31.4),
    PositionReports(t=3.0, reports=[PositionReport(x=1, y=2, cov=((1, 0), (0, 1)), weight=2.0)]),
    TrackSet(t=4.0, tracker="mcmcda", tracks=[Track(track=7, x=1, y=2, vx=0.5, vy=-0.5)]),
    Clock(t=5.0),
    Deployment(name="net", units="m", region=dict(xmin=0, ymin=0, xmax=10, ymax=10),
               sensors=[dict(id="a", kind="disk", x=1, y=1, range=2),
                        dict(id="b", kind="sector", x=2, y=2, range=2, sectors=4, offset=0.3),
                        dict(id="c", kind="motion", x=3, y=3, period=1),
                        dict(id="d", kind="line")],
               calibration={"passes": [{"pass": 1, "t_entry": 0, "entry": [0, 0], "t_exit": 2, "exit": [10, 0]}]}),
]


@pytest.mark.parametrize("message", SAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(message):
    assert decode(type(message), encode(message)) == message


def test_payload_is_a_msgpack_map_with_field_names_and_version():
    payload = msgpack.unpackb(encode(SAMPLES[0]))
    assert payload == {"version": 1, "t": 1.5, "sensor": "n1", "value": 1, "previous": 0, "seq": 3,
                       "source": None, "source_seq": None}


@pytest.mark.parametrize(
    "payload, reason",
    [
        (b"\xc1garbage", "not msgpack"),
        (msgpack.packb([1, 2, 3]), "expected a map"),
        (msgpack.packb({"version": 1, "t": 1.0, "sensor": "a", "value": 1, "previous": 0}), "seq: Field required"),
        (msgpack.packb({"version": 1, "t": float("nan"), "sensor": "a", "value": 1, "previous": 0, "seq": 1}), "t:"),
        (msgpack.packb({"version": 2, "t": 1.0, "sensor": "a", "value": 1, "previous": 0, "seq": 1}), "version"),
        (msgpack.packb({"version": 1, "t": 1.0, "sensor": "a/b", "value": 1, "previous": 0, "seq": 1, "x": 1}), "x"),
    ],
)
def test_bad_payloads_raise_one_typed_error(payload, reason):
    with pytest.raises(MessageError) as info:
        decode(Transition, payload)
    assert reason in str(info.value)
    assert "\n" not in str(info.value)


def test_deployment_rejects_duplicate_ids_and_bad_ranges():
    base = dict(name="n", units="m", region=dict(xmin=0, ymin=0, xmax=1, ymax=1))
    with pytest.raises(ValueError, match="duplicate"):
        Deployment(**base, sensors=[dict(id="a", kind="line"), dict(id="a", kind="line")])
    with pytest.raises(ValueError, match="range_in"):
        Deployment(**base, sensors=[dict(id="a", kind="disk", x=0, y=0, range=1, range_in=2)])
    with pytest.raises(ValueError, match="sensor id"):
        Deployment(**base, sensors=[dict(id="a b", kind="line")])


def test_schema_command_prints_json_schema_of_every_message(capsys):
    assert cli.main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert set(schema["messages"]) == {cls.__name__ for cls in MESSAGE_TYPES}
    transition = schema["messages"]["Transition"]
    assert set(transition["required"]) >= {"t", "sensor", "value", "previous", "seq"}
    assert "s" in transition["properties"]["t"]["description"]


def test_the_hot_path_views_have_the_models_fields_and_refuse_what_they_refuse():
    """The msgspec views of the hot messages (decode_view) mirror the pydantic models, which
    stay the definition: same fields and defaults; a bad payload gets pydantic's reason."""
    import math

    import msgpack
    import msgspec

    from bintrack.bus_payloads import Clock, RawSample, Transition
    from bintrack.message_codec import VIEWS, MessageError, decode_view, encode

    for cls, view in VIEWS.items():
        fields = {f.name: f.default for f in msgspec.structs.fields(view)}
        assert set(fields) == set(cls.model_fields), cls
        for name, info in cls.model_fields.items():
            if not info.is_required():
                assert fields[name] == info.default, (cls, name)
    tr = Transition(t=1.5, sensor="a", value=1, previous=0, seq=3, source="x", source_seq=4)
    assert msgspec.structs.asdict(decode_view(Transition, encode(tr))) == tr.model_dump()
    assert decode_view(Clock, encode(Clock(t=2.0, sent=5))).sent == 5
    for payload, reason in ((msgpack.packb({"t": math.nan, "sensor": "a", "value": 1}), "t: Input should be a finite number"),
                            (msgpack.packb({"temperature": 21.5}), "t: Field required"),
                            (msgpack.packb({"t": 1.0, "sensor": "a", "value": 1, "x": 2}), "x: Extra inputs are not permitted"),
                            (b"\xc1", "not msgpack")):
        with pytest.raises(MessageError, match=reason):
            decode_view(RawSample, payload)
    with pytest.raises(MessageError, match="seq: Input should be greater than or equal to 1"):
        decode_view(Transition, msgpack.packb({**tr.model_dump(), "seq": 0}))


def test_a_raw_sample_encoded_without_its_model_has_the_models_bytes():
    from bintrack.bus_payloads import RawSample
    from bintrack.message_codec import encode, encode_raw_sample

    for t, sensor, value in ((1, "a", 1), (2.5, "n17", -1), (0.0, "s", 0)):
        assert encode_raw_sample(t, sensor, value) == encode(RawSample(t=t, sensor=sensor, value=value))


def test_a_transition_encoded_without_its_model_has_the_models_bytes():
    from bintrack.bus_payloads import Transition
    from bintrack.message_codec import encode, encode_transition
    from bintrack.live.sensor_hosting import TRANSITION_FIELDS, Sent

    assert TRANSITION_FIELDS == ("version", *Sent._fields)  # the sensor agent's checkpoint layout
    for fields in ((1.5, "a", 1, 0, 1, "agent-1", 7), (20.25, "n17", 0, 1, 12, None, None)):
        assert encode_transition(*fields) == encode(Transition(**dict(zip(Sent._fields, fields))))
    sent = Sent(3.0, "a", 1, 0, 2, "agent-1", 9)
    assert encode_transition(*sent) == encode(sent.message())
