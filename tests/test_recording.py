"""Recordings: the MCAP writer and reader, the recorder service on a real Zenoh router (bad
payloads, SIGTERM, a crash), and ``bintrack export``."""

from __future__ import annotations

import json
import signal

import msgpack
import pytest
from mcap.reader import make_reader

from bintrack.cli import main as cli
from bintrack.keys import Keys
from bintrack.formats import FormatError, ObjectRow, TrackRow, read_objects, read_tracks
from bintrack.bus_payloads import (
    Clock, EndOfStream, LineObjectEstimate, LocalEstimate, RawSample, Track, TrackSet, VelocityEstimate,
)
from bintrack.deployment_model import Deployment, DiskSensor, Region
from bintrack.message_codec import encode
from bintrack.message_schema import json_schema
from bintrack.live.recording import RecordingWriter, log_time_ns, open_recording, replay_items, shift_payload

from support import HUNG, FakeBus


def output(process) -> str:
    """What a service process has logged so far (also after it exited)."""
    return process.log_path.read_text()


DEPLOYMENT = Deployment(name="rec", units="m", region=Region(xmin=0, ymin=0, xmax=10, ymax=10),
                        sensors=[DiskSensor(id=f"n{i}", x=float(i), y=1.0, range=2.0) for i in range(4)])


def write(path, records, net="rec"):
    with RecordingWriter(path, DEPLOYMENT, net) as writer:
        for key, message in records:
            writer.write(key, message.t, encode(message))
    return path


KEYS = Keys("rec")


def raw(t, sensor="n0", value=1):
    return KEYS.raw(sensor), RawSample(t=t, sensor=sensor, value=value)


# --------------------------------------------------------------------------- files


def test_round_trip_in_log_time_order_ties_in_recorded_order(tmp_path):
    records = [raw(0.2, "n1"), ("bintrack/rec/clock", Clock(t=0.0)), raw(0.1, "n0"), raw(0.1, "n2"), raw(0.1, "n3")]
    recording = open_recording(write(tmp_path / "a.mcap", records))
    assert recording.complete and recording.net == "rec" and recording.deployment == DEPLOYMENT
    assert recording.message_count == 5
    got = [(r.key, r.t, r.payload) for r in recording.records()]
    expected = [records[i] for i in (1, 2, 3, 4, 0)]
    assert got == [(k, m.t, encode(m)) for k, m in expected]
    assert [r.key for r in recording.records(lambda key: key.endswith("n3"))] == ["bintrack/rec/raw/n3"]


def test_standard_mcap_layout(tmp_path):
    """Per-key channels with msgpack payloads and the messages' JSON Schemas, as Foxglove reads them."""
    path = write(tmp_path / "a.mcap", [raw(0.1), raw(0.2, "n1"), ("bintrack/rec/clock", Clock(t=0.5))])
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == {"bintrack/rec/raw/n0", "bintrack/rec/raw/n1", "bintrack/rec/clock"}
        assert {c.message_encoding for c in channels.values()} == {"msgpack"}
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {"bintrack.RawSample", "bintrack.Clock"}
        assert schemas["bintrack.RawSample"].encoding == "jsonschema"
        assert json.loads(schemas["bintrack.RawSample"].data) == json_schema()["messages"]["RawSample"]
        assert [m.name for m in reader.iter_metadata()] == ["bintrack.recording"]
        [attachment] = reader.iter_attachments()
        assert attachment.name == "bintrack.deployment" and attachment.media_type == "application/json"
        assert [m.log_time for _, _, m in reader.iter_messages()] == [100_000_000, 200_000_000, 500_000_000]


def test_truncated_recording_keeps_a_readable_prefix(tmp_path):
    path = tmp_path / "a.mcap"
    with RecordingWriter(path, DEPLOYMENT, "rec", chunk_size=1024) as writer:
        for i in range(400):
            key, message = raw(i / 100, f"n{i % 4}")
            writer.write(key, message.t, encode(message))
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    recording = open_recording(cut)
    assert not recording.complete
    records = list(recording.records())
    assert 100 < len(records) < 400
    assert [r.t for r in records] == [i / 100 for i in range(len(records))]


@pytest.mark.parametrize("content, message", [
    (None, "not found"),
    (b"", "empty file"),
    (b"PK\x03\x04 a zip file", "not an MCAP recording"),
    (b"\x89MCAP0\r\n\x01garbage", "corrupt or truncated recording"),
])
def test_bad_recordings_raise_one_line(tmp_path, content, message):
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(FormatError, match=message) as info:
        open_recording(path)
    assert "\n" not in str(info.value)


def test_an_mcap_file_that_is_not_a_recording(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "other.mcap"
    with open(path, "wb") as handle:
        writer = Writer(handle)
        writer.start()
        writer.finish()
    with pytest.raises(FormatError, match="bintrack.deployment: missing attachment"):
        open_recording(path)


def test_times_payload_shift_and_replay_items(tmp_path):
    with pytest.raises(ValueError, match="cannot be an MCAP log time"):
        log_time_ns(-0.5)
    payload = encode(LineObjectEstimate(object=1, t_first=1.0, t_last=2.0, entry_x=0, entry_y=0, exit_x=1, exit_y=1,
                                        vx=1, vy=1))
    assert shift_payload(payload, 0.0) is payload
    shifted = msgpack.unpackb(shift_payload(payload, 10.0))
    assert (shifted["t_first"], shifted["t_last"], shifted["vx"]) == (11.0, 12.0, 1)
    recording = open_recording(write(tmp_path / "a.mcap", [
        ("bintrack/rec/clock", Clock(t=0.0)), raw(0.1), ("bintrack/rec/control/eos", EndOfStream(t=0.1)),
        ("bintrack/rec/control/done/basestation/x", EndOfStream(t=0.1)), raw(0.2, "n1")]))
    items = list(replay_items(recording, keep=lambda key: key.endswith("n1")))
    assert [(t, r and r.key) for t, r in items] == [(0.0, None), (0.2, "bintrack/rec/raw/n1")]


# --------------------------------------------------------------------------- the recorder, live


@pytest.fixture
def bus(zenoh_router):
    handle = FakeBus(zenoh_router, DEPLOYMENT)
    yield handle
    handle.close()


def test_bad_payloads_are_counted_not_recorded_and_the_recorder_goes_on(tmp_path, zenoh_router, services, bus):
    out = tmp_path / "bad.mcap"
    recorder = services("recorder", "--out", str(out), "--net", "rec", endpoint=zenoh_router)
    bus.wait_for("recorder")
    bus.put(KEYS.raw("n0"), b"\xc1\xff garbage")
    bus.put(KEYS.raw("n1"), msgpack.packb({"version": 1, "temperature": 20}))
    bus.put(KEYS.raw("n2"), msgpack.packb({"version": 1, "t": float("nan"), "sensor": "n2", "value": 1}))
    bus.put(KEYS.raw("n2"), msgpack.packb({"version": 1, "t": float("nan"), "sensor": "n2", "value": 1}))
    bus.put(f"{KEYS.prefix}/no/such/key", encode(Clock(t=1.0)))
    bus.put(KEYS.raw("n3"), RawSample(t=1.0, sensor="n3", value=1))
    bus.tick(1.5, "recorder")
    assert recorder.proc.poll() is None
    bus.put(KEYS.eos(), EndOfStream(t=1.0))
    assert recorder.wait(HUNG) == 0
    log = output(recorder)
    assert "5 bad payloads" in log, log
    for sender in ("raw/n0", "raw/n1", "raw/n2", "no/such/key"):
        assert log.count(f"dropped a bad payload from bintrack/rec/{sender}") == 1, log  # once per sender
    assert [(r.key, r.t) for r in open_recording(out).records()] == [
        ("bintrack/rec/raw/n3", 1.0), ("bintrack/rec/control/eos", 1.0), ("bintrack/rec/clock", 1.5)]


def test_recorder_waits_for_upstream_done_before_finalising(tmp_path, zenoh_router, services, bus):
    out = tmp_path / "up.mcap"
    recorder = services("recorder", "--out", str(out), "--net", "rec", endpoint=zenoh_router)
    token = bus.session.liveliness().declare_token(KEYS.alive("basestation", "b1"))
    try:
        bus.wait_for("recorder")
        bus.put(KEYS.eos(), EndOfStream(t=2.0))
        bus.put(KEYS.tracks(), TrackSet(t=2.0, tracker="mcmcda", tracks=[Track(track=1, x=1.0, y=2.0)]))
        # Not finalised: ticks after the end of stream are still recorded and acknowledged. The
        # end of stream wakes the recorder's main loop (which would finalise) in three turns of
        # its asyncio loop; each tick, sent once the one before is acknowledged, is handled
        # after one more of those turns had its go, so the last of these five comes after the
        # main loop's check, and a finalised recorder would leave it unanswered.
        for t in (2.5, 3.0, 3.5, 4.0, 4.5):
            bus.tick(t, "recorder", recorder)
        assert recorder.proc.poll() is None, "finalised before the base station was done"
        bus.put(KEYS.done("basestation", "b1"), EndOfStream(t=2.0))
        assert recorder.wait(HUNG) == 0, output(recorder)
    finally:
        token.undeclare()
    # in log-time (event-time) order: the done at t=2 before the ticks after it
    assert [r.kind for r in open_recording(out).records()] == ["eos", "tracks", "done"] + ["clock"] * 5


@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
def test_a_stopped_recorder_leaves_a_readable_file(tmp_path, zenoh_router, services, bus, how):
    out = tmp_path / "stopped.mcap"
    recorder = services("recorder", "--out", str(out), "--net", "rec", endpoint=zenoh_router)
    bus.wait_for("recorder")
    for i in range(50):
        bus.put(KEYS.raw(f"n{i % 4}"), RawSample(t=i / 10, sensor=f"n{i % 4}", value=i % 2))
    bus.tick(5.0, "recorder")
    recorder.proc.send_signal(getattr(signal, how))
    code = recorder.wait(HUNG)
    recording = open_recording(out)
    assert recording.deployment == DEPLOYMENT
    if how == "SIGTERM":
        assert code == 0 and recording.complete
        assert len(list(recording.records())) == 51
    else:  # a crash: whatever chunks were finished, here none (the open chunk was in memory)
        assert not recording.complete
        assert [r.t for r in recording.records()] == [i / 10 for i in range(len(list(recording.records())))]


def test_export_of_hand_published_results(tmp_path, zenoh_router, services, bus, capsys):
    out = tmp_path / "results.mcap"
    recorder = services("recorder", "--out", str(out), "--net", "rec", endpoint=zenoh_router)
    bus.wait_for("recorder")
    # published out of order: exports are sorted whatever the arrival order
    bus.put(KEYS.tracks(), TrackSet(t=2.0, tracker="mcmcda", tracks=[Track(track=2, x=5.0, y=1.0),
                                                                Track(track=1, x=3.0, y=4.0, vx=0.5, vy=-0.5)]))
    bus.put(KEYS.tracks(), TrackSet(t=1.0, tracker="mcmcda", tracks=[Track(track=1, x=2.0, y=4.0)]))
    bus.put(KEYS.estimate("n2"), LocalEstimate(t=1.5, node="n2", tracker="arc", x=2.5, y=1.0, vx=1.0, vy=0.0))
    bus.put(KEYS.estimate("n1"), LocalEstimate(t=0.5, node="n1", tracker="arc", x=1.5, y=1.2))
    obj = dict(t_first=0.0, t_last=3.0, entry_x=0.0, entry_y=1.0, exit_x=10.0, exit_y=2.0, vy=0.1)
    bus.put(KEYS.laser_objects(), LineObjectEstimate(object=1, vx=3.0, **obj))
    bus.put(KEYS.laser_objects(), LineObjectEstimate(object=1, vx=3.5, **obj))  # refined later: the last one counts
    bus.put(KEYS.motion_velocity(), VelocityEstimate(t=1.0, method="motion-rw", vx=1.0, vy=2.0, x=3.0, y=4.0))
    bus.put(KEYS.eos(), EndOfStream(t=3.0))
    assert recorder.wait(HUNG) == 0, output(recorder)

    def export(what: str) -> str:
        target = tmp_path / f"{what}.csv"
        assert cli.main(["export", str(out), "--what", what, "--out", str(target)]) == 0
        return target

    assert read_tracks(export("tracks")) == [TrackRow(1.0, 1, 2.0, 4.0), TrackRow(2.0, 1, 3.0, 4.0, 0.5, -0.5),
                                             TrackRow(2.0, 2, 5.0, 1.0)]
    assert read_tracks(export("estimates")) == [TrackRow(0.5, 0, 1.5, 1.2), TrackRow(1.5, 0, 2.5, 1.0, 1.0, 0.0)]
    assert read_tracks(export("velocity")) == [TrackRow(1.0, 0, 3.0, 4.0, 1.0, 2.0)]
    assert read_objects(export("objects")) == [ObjectRow(1, 0.0, 3.0, 0.0, 1.0, 10.0, 2.0, 3.5, 0.1)]
    assert "1 objects rows written" in capsys.readouterr().err


@pytest.mark.parametrize("content", [None, b"\x89MCAP0\r\n\x00\x01\x02"])
def test_export_of_a_missing_or_corrupt_recording(tmp_path, capsys, content):
    path = tmp_path / "broken.mcap"
    if content is not None:
        path.write_bytes(content)
    assert cli.main(["export", str(path), "--what", "tracks", "--out", str(tmp_path / "t.csv")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(path) in err, err
    assert not (tmp_path / "t.csv").exists()


def test_recorder_rejects_an_unusable_out(tmp_path, zenoh_router, services):
    recorder = services("recorder", "--out", str(tmp_path / "nowhere" / "x.mcap"), endpoint=zenoh_router)
    assert recorder.wait(HUNG) == 2
    assert "does not exist" in output(recorder)
