"""`bintrack export RECORDING --foxglove OUT.mcap`: JSON channels with JSON Schemas, and a
foxglove.SceneUpdate channel, read back with the mcap reader and validated with jsonschema."""

from __future__ import annotations

import json

import jsonschema
from mcap.reader import make_reader

from bintrack.formats import read_deployment
from bintrack.bus_payloads import Clock, PositionReport, PositionReports, Track, TrackSet, Transition, TruthSample
from bintrack.message_codec import encode
from bintrack.live.recording import RecordingWriter, open_recording
from support import DATASETS, bintrack

DARPA3 = DATASETS / "darpa-grid-3"


def make_recording(path):
    deployment = read_deployment(DARPA3 / "deployment.json")
    messages = [
        ("sensor/n001/transition", Transition(t=1.0, sensor="n001", value=1, previous=0, seq=1)),
        ("clock", Clock(t=1.5)),
        ("fusion/reports", PositionReports(t=1.5, reports=[PositionReport(x=5.0, y=1.0, cov=((4.0, 1.0), (1.0, 2.0)))])),
        ("tracks", TrackSet(t=1.5, tracker="mcmcda", tracks=[Track(track=7, x=5.0, y=1.0, vx=1.0, vy=0.5),
                                                             Track(track=8, x=20.0, y=30.0)])),
        ("truth", TruthSample(t=1.6, target="1", x=5.2, y=0.9)),
        ("sensor/n001/transition", Transition(t=2.0, sensor="n001", value=0, previous=1, seq=2)),
    ]
    with RecordingWriter(path, deployment, "darpa-grid") as writer:
        for suffix, message in messages:
            writer.write(f"bintrack/darpa-grid/{suffix}", message.t, encode(message))
    return messages


def test_every_message_is_json_with_its_schema_and_the_scene_validates(tmp_path):
    source, out = tmp_path / "run.mcap", tmp_path / "foxglove.mcap"
    messages = make_recording(source)
    result = bintrack("export", str(source), "--foxglove", str(out))
    assert result.returncode == 0, result.stderr
    assert "written to" in result.stderr
    seen, scenes = [], []
    with open(out, "rb") as handle:
        for schema, channel, message in make_reader(handle).iter_messages(log_time_order=True):
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            payload = json.loads(message.data)
            jsonschema.validate(payload, json.loads(schema.data))
            if channel.topic == "/scene":
                assert schema.name == "foxglove.SceneUpdate"
                scenes.append(payload)
            else:
                assert schema.name.startswith("bintrack.")
                seen.append((channel.topic, message.log_time, payload))
    # The same messages, keys and event times as the recording, now as JSON.
    assert [(topic, t) for topic, t, _ in seen] == [(f"bintrack/darpa-grid/{s}", round(m.t * 1e9)) for s, m in messages]
    assert [payload for _, _, payload in seen] == [json.loads(m.model_dump_json(by_alias=True)) for _, m in messages]
    # The scene: the sensors' ranges, the detecting sensor lit then deleted, tracks with ids and arrows.
    entities = {e["id"]: e for update in scenes for e in update["entities"]}
    assert len(entities["sensors"]["cylinders"]) == 144
    assert entities["sensor/n001"]["cylinders"][0]["pose"]["position"]["x"] == 4.88
    assert scenes[-1]["deletions"] == [{"timestamp": {"sec": 2, "nsec": 0}, "type": 0, "id": "sensor/n001"}]
    assert [t["text"] for t in entities["tracks"]["texts"]] == ["7", "8"]
    assert len(entities["tracks"]["arrows"]) == 1 and entities["tracks"]["arrows"][0]["shaft_length"] > 0
    (ellipse,) = entities["reports"]["spheres"]
    assert ellipse["size"]["x"] > ellipse["size"]["y"] > 0
    assert entities["truth"]["spheres"][0]["pose"]["position"] == {"x": 5.2, "y": 0.9, "z": 0.0}
    assert open_recording(out).deployment == open_recording(source).deployment


def test_foxglove_export_options_are_checked_with_one_line(tmp_path):
    source = tmp_path / "run.mcap"
    make_recording(source)
    for args, words in ((["--foxglove", str(tmp_path / "x.csv")], "must end in .mcap"),
                        (["--foxglove", str(tmp_path / "x.mcap"), "--what", "tracks"], "without --what"),
                        ([], "give --what and --out"),
                        (["--foxglove", str(source)], "must not overwrite")):
        result = bintrack("export", str(source), *args)
        assert result.returncode == 2 and words in result.stderr and result.stderr.count("\n") == 1, result.stderr
