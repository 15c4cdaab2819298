"""The MQTT bridge's pure parts: sensor table, payload readers, the core's time, order, retained
state and faults, broker options, and Zigbee2MQTT playback (no broker, no Zenoh)."""

from __future__ import annotations

import asyncio
import json
import os
import pickle
from collections import deque
from pathlib import Path

import pytest

import bintrack.live.replay_gate as replay_gate
from bintrack.formats import Event, open_dataset
from bintrack.keys import Keys, parse_key
from bintrack.live.replay_gate import ReplayGate
from bintrack.mqtt.bridge_core import BridgeCore, End, Fault, FaultLines, Retained, Sample
from bintrack.mqtt.broker_options import BrokerConfigError, broker_options, parse_broker_url
from bintrack.mqtt.payload_reader import PayloadError, PayloadReader
from bintrack.mqtt.sensor_table import PayloadSpec, TableError, load_table, parse_instant, table_text
from bintrack.mqtt.zigbee_playback import check_zigbee, iso_time, zigbee_messages

from support import REPO

DARPA3 = REPO / "datasets" / "darpa-grid-3"
EPOCH = "2026-01-01T00:00:00Z"
E_US = parse_instant(EPOCH)

TABLE = """
name = "hall"
units = "m"
epoch = "2026-01-01T00:00:00Z"
region = { xmin = 0, ymin = 0, xmax = 10, ymax = 10 }

[[sensors]]
id = "pir1"
topic = "zigbee2mqtt/hall_pir_1"
payload = { format = "zigbee2mqtt" }
kind = "disk"
x = 1.0
y = 2.0
range = 4.0

[[sensors]]
id = "pir2"
topic = "home/pir2/state"
payload = { format = "on-off" }
clock_offset = 0.25
kind = "disk"
x = 5.0
y = 2.0
range = 4.0

[[sensors]]
id = "door"
topic = "zigbee2mqtt/door"
payload = { format = "zigbee2mqtt", field = "contact", invert = true }
kind = "disk"
x = 9.0
y = 9.0
range = 1.0
"""


@pytest.fixture
def table(tmp_path):
    path = tmp_path / "table.toml"
    path.write_text(TABLE)
    return load_table(path)


def z2m(occupancy: bool, t: float | None = None, **extra) -> bytes:
    body = {"occupancy": occupancy, "battery": 90, **extra}
    if t is not None:
        body["last_seen"] = iso_time(E_US + round(t * 1e6))
    return json.dumps(body).encode()


# -- sensor table --------------------------------------------------------------------------


def test_a_table_gives_the_deployment_and_its_topics(table):
    deployment = table.deployment()
    assert [s.id for s in deployment.sensors] == ["pir1", "pir2", "door"]
    assert deployment.sensors[1].clock_offset == 0.0  # the bridge applies the table's offsets itself
    assert set(table.by_topic()) == {"zigbee2mqtt/hall_pir_1", "home/pir2/state", "zigbee2mqtt/door"}
    assert table.epoch_us == E_US


@pytest.mark.parametrize("change, words", [
    (('topic = "home/pir2/state"', 'topic = "zigbee2mqtt/hall_pir_1"'), "given to both"),
    (('topic = "home/pir2/state"', 'topic = "home/+/state"'), "wildcards"),
    (('format = "on-off"', 'format = "json"'), "field path"),
    (('format = "on-off"', 'format = "xml"'), "payload.format"),
    (('units = "m"', 'units = "furlong"'), "units"),
    (('epoch = "2026-01-01T00:00:00Z"', 'epoch = "soon"'), "ISO 8601"),
    (('range = 1.0', 'range = -1.0'), "range"),
    (('[[sensors]]\nid = "door"', '[[sensors]\nid = "door"'), "not TOML"),
])
def test_a_bad_table_is_one_line_naming_the_file(tmp_path, change, words):
    path = tmp_path / "bad.toml"
    path.write_text(TABLE.replace(*change, 1))
    with pytest.raises(TableError) as caught:
        load_table(path)
    assert str(caught.value).startswith(str(path)) and words in str(caught.value) and "\n" not in str(caught.value)


def test_the_table_written_for_a_dataset_gives_its_deployment(tmp_path):
    dataset = open_dataset(DARPA3)
    path = tmp_path / "t.toml"
    path.write_text(table_text(dataset.deployment, EPOCH))
    table = load_table(path)
    assert table.deployment() == dataset.deployment
    assert table.by_topic()["zigbee2mqtt/n007"].id == "n007"
    assert table.subscriptions() == ["zigbee2mqtt/+"]


def test_subscriptions_are_the_filters_and_the_topics_they_miss(table):
    assert table.subscriptions() == ["zigbee2mqtt/hall_pir_1", "home/pir2/state", "zigbee2mqtt/door"]
    wider = table.model_copy(update={"subscribe": ["zigbee2mqtt/+", "home/#"]})
    assert wider.subscriptions() == ["zigbee2mqtt/+", "home/#"]
    assert table.model_copy(update={"subscribe": ["home/+"]}).subscriptions() == [
        "home/+", "zigbee2mqtt/hall_pir_1", "home/pir2/state", "zigbee2mqtt/door"]


# -- payloads ------------------------------------------------------------------------------


@pytest.mark.parametrize("spec, payload, expected", [
    (PayloadSpec(), b'{"occupancy": true, "linkquality": 80}', (1, None)),
    (PayloadSpec(), b'{"presence": false}', (0, None)),
    (PayloadSpec(), b'{"occupancy": true, "last_seen": 1767225600123}', (1, E_US + 123_000)),
    (PayloadSpec(), b'{"occupancy": false, "last_seen": "2026-01-01T00:00:01.5Z"}', (0, E_US + 1_500_000)),
    (PayloadSpec(field="contact", invert=True), b'{"contact": false}', (1, None)),
    (PayloadSpec(format="on-off"), b"ON", (1, None)),
    (PayloadSpec(format="on-off"), b" off\n", (0, None)),
    (PayloadSpec(format="one-zero"), b"1", (1, None)),
    (PayloadSpec(format="json", field="state.motion", time_field="ts"), b'{"state": {"motion": "ON"}, "ts": 5}', (1, 5000)),
    (PayloadSpec(format="json", field="v"), b'{"v": 0}', (0, None)),
])
def test_each_payload_format_reads(spec, payload, expected):
    assert PayloadReader(spec).read(payload) == expected


@pytest.mark.parametrize("spec, payload, words", [
    (PayloadSpec(), b"{not json", "not JSON"),
    (PayloadSpec(), b"[1, 2]", "JSON object"),
    (PayloadSpec(), b'{"battery": 50}', "none of occupancy"),
    (PayloadSpec(), b'{"occupancy": "maybe"}', "not a binary status"),
    (PayloadSpec(), b'{"occupancy": true, "last_seen": "yesterday"}', "not ISO 8601"),
    (PayloadSpec(), b"\xff\xfe", "not UTF-8"),
    (PayloadSpec(format="on-off"), b"1", "expected ON/OFF"),
    (PayloadSpec(format="one-zero"), b"", "(empty)"),
    (PayloadSpec(format="json", field="a.b"), b'{"a": {}}', "no field 'a.b'"),
])
def test_a_malformed_payload_says_why_in_one_line(spec, payload, words):
    with pytest.raises(PayloadError) as caught:
        PayloadReader(spec).read(payload)
    assert words in str(caught.value) and "\n" not in str(caught.value)


# -- the core ------------------------------------------------------------------------------


def test_payload_times_are_exact_to_the_microsecond(table):
    core = BridgeCore(table, clock="payload")
    for t in (0.048651, 12.5, 89.946300, 1234.000001):
        sample = core.receive("zigbee2mqtt/hall_pir_1", z2m(True, t), retained=False, received_us=0)
        assert sample == Sample(t, "pir1", 1)
        core.receive("zigbee2mqtt/hall_pir_1", z2m(False, t + 0.1), retained=False, received_us=0)


def test_receipt_time_and_clock_offset_without_a_payload_time(table):
    core = BridgeCore(table)
    sample = core.receive("home/pir2/state", b"ON", retained=False, received_us=E_US + 10_000_000)
    assert sample == Sample(10.0 - 0.25, "pir2", 1)


def test_samples_out_of_order_within_the_lateness_come_out_sorted_before_their_tick(table):
    core = BridgeCore(table, period=0.5, lateness=1.0, clock="payload")
    for topic, t in (("zigbee2mqtt/hall_pir_1", 0.30), ("zigbee2mqtt/door", 0.10), ("zigbee2mqtt/hall_pir_1", 0.2)):
        body = z2m(True, t) if "pir" in topic else json.dumps({"contact": False, "last_seen": iso_time(E_US + round(t * 1e6))}).encode()
        assert isinstance(core.receive(topic, body, retained=False, received_us=0), Sample)
    assert core.next_tick(0) is None  # the watermark (0.30 − 1.0) reaches no tick yet
    core.receive("zigbee2mqtt/hall_pir_1", z2m(False, 1.6), retained=False, received_us=0)
    assert core.next_tick(0) == (0.0, [])
    tick, samples = core.next_tick(0)
    assert tick == 0.5 and [(s.t, s.sensor) for s in samples] == [(0.1, "door"), (0.2, "pir1"), (0.3, "pir1")]
    assert core.next_tick(0) is None
    late = core.receive("zigbee2mqtt/hall_pir_1", z2m(True, 0.4), retained=False, received_us=0)
    assert isinstance(late, Fault) and late.kind == "late" and core.faults["late"] == 1


def test_the_wall_clock_moves_event_time_when_nothing_comes(table):
    core = BridgeCore(table, period=0.5, lateness=1.0, clock="wall")
    assert core.next_tick(E_US + 3_200_000) == (2.0, [])
    assert core.next_tick(E_US + 3_200_000) is None
    assert core.next_tick(E_US + 3_600_000) == (2.5, [])


def test_a_redelivery_is_a_duplicate_not_a_second_sample(table):
    core = BridgeCore(table, clock="payload", lateness=0.0)
    assert isinstance(core.receive("zigbee2mqtt/hall_pir_1", z2m(True, 1.0), retained=False, received_us=0), Sample)
    again = core.receive("zigbee2mqtt/hall_pir_1", z2m(True, 1.0), retained=False, received_us=0)
    assert again.kind == "duplicate"
    core.receive("zigbee2mqtt/hall_pir_1", z2m(False, 3.0), retained=False, received_us=0)
    while core.next_tick(0):
        pass
    assert core.receive("zigbee2mqtt/hall_pir_1", z2m(True, 1.0), retained=False, received_us=0).kind == "duplicate"
    assert core.released == 1 and core.faults == {"duplicate": 2}


def test_retained_messages_give_the_state_at_start_and_are_never_published(table):
    core = BridgeCore(table, clock="payload", lateness=0.0)
    got = core.receive("zigbee2mqtt/hall_pir_1", z2m(True, -3600.0), retained=True, received_us=0)
    assert got == Retained("pir1", 1) and core.initial == {"pir1": 1}
    core.receive("zigbee2mqtt/door", b'{"contact": true}', retained=True, received_us=0)
    assert core.initial == {"pir1": 1, "door": 0}
    assert len(core.buffer) == 0 and core.next_tick(0) is None and core.latest is None


def test_unknown_topics_malformed_payloads_bad_values_and_floods_are_counted_faults(table):
    core = BridgeCore(table, clock="payload", max_rate=5.0)
    assert core.receive("zigbee2mqtt/kitchen", z2m(True, 1.0), retained=False, received_us=0).kind == "unknown topic"
    assert core.receive("home/pir2/state", b"MAYBE", retained=False, received_us=0).kind == "malformed payload"
    outcomes = [core.receive("zigbee2mqtt/hall_pir_1", z2m(i % 2 == 0, 1.0 + i / 1000), retained=False, received_us=0)
                for i in range(20)]
    taken = [o for o in outcomes if isinstance(o, Sample)]
    assert len(taken) == 5 and all(o.kind == "flood" for o in outcomes[5:])
    later = core.receive("zigbee2mqtt/hall_pir_1", z2m(True, 2.5), retained=False, received_us=0)
    assert isinstance(later, Sample)  # the bucket refills with event time
    assert core.faults == {"unknown topic": 1, "malformed payload": 1, "flood": 15}
    assert core.summary().startswith("23 messages: 0 samples published") and "'flood': 15" in core.summary()


def test_a_retained_state_after_the_first_tick_gets_a_counted_line(table):
    core, lines = BridgeCore(table, clock="payload", lateness=0.0), FaultLines(limit=1)
    first = core.receive("zigbee2mqtt/hall_pir_1", z2m(True), retained=True, received_us=0)
    assert lines.describe(first, core) is None  # the state at start: in the summary
    core.receive("zigbee2mqtt/door", b'{"contact": true, "last_seen": 5000}', retained=False, received_us=0)
    core.next_tick(0)
    again = core.receive("zigbee2mqtt/hall_pir_1", z2m(False), retained=True, received_us=0)
    assert lines.describe(again, core) == "retained state #2 on pir1: 0, taken as the sensor's state, not as a detection"
    assert "only counted" in lines.describe(again, core) and lines.describe(again, core) is None
    assert core.initial == {"pir1": 0} and core.released == 0


def test_fault_lines_are_one_each_with_the_count_then_only_counted():
    lines = FaultLines(limit=2)
    fault = Fault("malformed payload", "a/b", "not JSON")
    assert lines.line(fault, 1) == "malformed payload #1 on a/b: not JSON"
    assert lines.line(fault, 2) == "malformed payload #2 on a/b: not JSON"
    assert "further ones are only counted" in lines.line(fault, 3)
    assert lines.line(fault, 4) is None
    assert lines.line(Fault("late", "a/b", "x"), 1) == "late #1 on a/b: x"


def test_the_end_releases_every_tick_up_to_the_final_one(table):
    core = BridgeCore(table, period=0.5, lateness=5.0, clock="payload")
    for t in (0.2, 1.7, 2.1):
        core.receive("zigbee2mqtt/hall_pir_1", z2m(t != 1.7, t), retained=False, received_us=0)
    final, t_end = core.end()
    assert (final, t_end) == (2.5, 2.1)
    ticks = []
    while (due := core.next_tick(0)) is not None:
        ticks.append((due[0], [s.t for s in due[1]]))
    assert ticks == [(0.0, []), (0.5, [0.2]), (1.0, []), (1.5, []), (2.0, [1.7]), (2.5, [2.1])]


def test_a_snapshot_restores_the_same_core(table):
    core = BridgeCore(table, clock="payload", lateness=0.5)
    for i, t in enumerate((0.2, 0.9, 1.4)):
        core.receive("zigbee2mqtt/hall_pir_1", z2m(i % 2 == 0, t), retained=False, received_us=0, seq=i + 1)
    core.next_tick(0)
    copy = BridgeCore(table, clock="payload", lateness=0.5)
    copy.restore(pickle.loads(pickle.dumps(core.snapshot())))
    assert copy.journal_seq == 3
    assert copy.receive("zigbee2mqtt/hall_pir_1", z2m(False, 0.9), retained=False, received_us=0).kind == "duplicate"
    assert [core.next_tick(0) for _ in range(3)] == [copy.next_tick(0) for _ in range(3)]


def test_a_snapshot_taken_after_the_end_keeps_it(table):
    """A bridge killed while it sent its last ticks had taken the end topic's message (the
    broker will not send it again): the restored core keeps the final tick, and ending it again
    gives the same one, not one more tick past the last."""
    core = BridgeCore(table, clock="payload", lateness=0.5)
    for i, t in enumerate((0.2, 0.9, 1.4)):
        core.receive("zigbee2mqtt/hall_pir_1", z2m(i % 2 == 0, t), retained=False, received_us=0, seq=i + 1)
    final, _ = core.end()
    core.next_tick(0)
    copy = BridgeCore(table, clock="payload", lateness=0.5)
    copy.restore(pickle.loads(pickle.dumps(core.snapshot())))
    assert copy.final_tick == final == 1.5
    while (due := copy.next_tick(0)) is not None:
        last = due[0]
    assert last == final and copy.end()[0] == final


def test_a_snapshot_taken_between_the_end_message_and_the_final_ticks_keeps_the_end(table):
    """The end topic's message taken (and acknowledged to the broker), then a checkpoint at a
    tick before the bridge set its final tick, then SIGKILL: the restored core knows the stream
    ended, so its successor sends the last ticks and the end (it used to wait for ever)."""
    core = BridgeCore(table, clock="payload", lateness=0.5, end_topic="bintrack/end")
    for i, t in enumerate((0.2, 0.9, 1.4)):
        core.receive("zigbee2mqtt/hall_pir_1", z2m(i % 2 == 0, t), retained=False, received_us=0, seq=i + 1)
    assert isinstance(core.receive("bintrack/end", b"", retained=False, received_us=0, seq=4), End)
    core.next_tick(0)
    copy = BridgeCore(table, clock="payload", lateness=0.5, end_topic="bintrack/end")
    copy.restore(pickle.loads(pickle.dumps(core.snapshot())))
    assert copy.ended and copy.final_tick is None and copy.journal_seq == 4
    assert copy.end()[0] == core.end()[0] == 1.5
    old = core.snapshot()
    del old["ended"]  # a checkpoint written before the core kept it: the final tick says it
    copy.restore(old)
    assert copy.ended


def test_the_bridge_paces_at_replays_gate_and_says_an_overdue_tick_again(monkeypatch):
    """The bridge's flow control is replay's gate with the bridge as the source: it waits for
    the awaited services, then for the tick --max-ahead back, saying the last tick again every
    SAY_AGAIN s while it is overdue (a consumer that lost it acknowledges a later one)."""
    monkeypatch.setattr(replay_gate, "SAY_AGAIN", 0.02)
    keys = Keys("net")

    async def scenario():
        said = []
        gate = ReplayGate(["sensor_agent", "basestation*2"], lambda: False, asyncio.Event(), source="mqtt_bridge")
        gate.tick_again = lambda: said.append(gate.last_tick)
        sent = deque([0.0, 0.5], maxlen=2)
        for service, instance in [("sensor_agent", "a"), ("basestation", "b1"), ("mqtt_bridge", "me")]:
            gate.on_presence(parse_key(keys.alive(service, instance)), True)
        assert gate.missing() == ["basestation*2"]
        waiting = asyncio.create_task(gate.window_open(sent))
        await asyncio.sleep(0.05)
        assert not waiting.done() and said == []  # a service short: no tick is owed yet
        gate.on_presence(parse_key(keys.alive("basestation", "b2")), True)  # the bridge itself is no consumer
        gate.last_tick = 0.5
        while not said:  # the tick two back is owed by the three consumers: said again meanwhile
            await asyncio.sleep(0.01)
        for service, instance in [("sensor_agent", "a"), ("basestation", "b1")]:
            gate.reported(service, instance, 0.0)
        assert not waiting.done()
        gate.reported("basestation", "b2", 0.5)
        assert await asyncio.wait_for(waiting, 5)
        assert set(said) == {0.5}

    asyncio.run(asyncio.wait_for(scenario(), 10))


# -- broker options ------------------------------------------------------------------------


def test_broker_urls():
    assert parse_broker_url("mqtt://127.0.0.1:1884") == ("127.0.0.1", 1884, False)
    assert parse_broker_url("mqtts://broker.local") == ("broker.local", 8883, True)
    for bad in ("tcp://h:1", "mqtt://", "mqtt://h:1/x"):
        with pytest.raises(BrokerConfigError):
            parse_broker_url(bad)
    with pytest.raises(BrokerConfigError) as caught:
        parse_broker_url("mqtt://user:hunter2@h:1883")
    assert "hunter2" not in str(caught.value)


def test_secrets_come_from_the_config_file_and_never_show(tmp_path):
    secret = tmp_path / "secret"
    secret.write_text("hunter2\n")
    (tmp_path / "ca.pem").write_text("x")
    config = tmp_path / "mqtt.toml"
    config.write_text('[broker]\nusername = "bintrack"\npassword_file = "secret"\nca = "ca.pem"\n')
    options = broker_options("mqtt://h:8883", config)
    assert (options.username, options.password, options.tls) == ("bintrack", "hunter2", True)
    assert "hunter2" not in repr(options) and "hunter2" not in options.url
    config.write_text('[broker]\npassword = "hunter2"\n')
    os.chmod(config, 0o644)
    with pytest.raises(BrokerConfigError, match="chmod 600"):
        broker_options("mqtt://h", config)
    os.chmod(config, 0o600)
    assert broker_options("mqtt://h", config).password == "hunter2"
    config.write_text('[broker]\npasword = "x"\n')
    with pytest.raises(BrokerConfigError, match="unknown key"):
        broker_options("mqtt://h", config)


# -- playback ------------------------------------------------------------------------------


def test_zigbee_playback_reads_back_to_the_same_events(table):
    events = [Event(0.048651, "pir1", 1), Event(2.5, "pir1", 0), Event(3.000001, "pir1", 1)]
    messages = list(zigbee_messages(events, E_US, base="zigbee2mqtt"))
    assert messages[-1][1] == "bintrack/end" and len(messages) == 4
    reader = PayloadReader(PayloadSpec())
    for event, (t, topic, payload) in zip(events, messages):
        value, stamp = reader.read(payload)
        assert topic == "zigbee2mqtt/pir1" and value == event.value
        assert (stamp - E_US) / 1_000_000 == event.t


def test_only_binary_sensors_play_as_zigbee_devices():
    check_zigbee(open_dataset(DARPA3).deployment)
    with pytest.raises(ValueError, match="binary"):
        check_zigbee(open_dataset(REPO / "datasets" / "laser-testbed").deployment)


# -- compose -------------------------------------------------------------------------------


def test_the_mqtt_compose_file_runs_the_bridge_on_its_shipped_table_and_the_official_broker():
    import yaml

    from bintrack.services.mqtt_bridge import build_parser

    compose = yaml.safe_load((REPO / "docker-compose.mqtt.yml").read_text())["services"]
    assert compose["mosquitto"]["image"].startswith("eclipse-mosquitto:")
    config = compose["mosquitto"]["volumes"][0].split(":")[0]
    assert "max_queued_messages 0" in (REPO / config).read_text()
    module, *argv = compose["mqtt_bridge"]["command"]
    assert module == "bintrack.services.mqtt_bridge"
    args = build_parser().parse_args(argv)
    assert args.broker == "mqtt://mosquitto:1883" and args.state_dir
    shipped = REPO / "deploy" / "mqtt" / Path(args.sensor_table).name
    table = load_table(shipped)
    assert table.deployment() == open_dataset(DARPA3).deployment
    assert shipped.read_text() == table_text(open_dataset(DARPA3).deployment, iso_time(0))  # as simulate writes it
    played = compose["devices"]["command"]
    assert played[:2] == ["bintrack.cli", "simulate"] and played[played.index("--publish") + 1] == args.broker


def test_the_readme_sensor_table_and_broker_config_load(tmp_path):
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Real sensors on MQTT"):]
    short = tmp_path / "readme.toml"
    short.write_text(section.split("```toml\n")[1].split("```", 1)[0])
    assert [s.id for s in load_table(short).sensors] == ["hall"]
    text = (REPO / "docs" / "mqtt.md").read_text()
    blocks = [b.split("```", 1)[0] for b in text.split("```toml\n")[1:3]]
    table = tmp_path / "office.toml"
    table.write_text(blocks[0])
    loaded = load_table(table)
    assert [s.id for s in loaded.sensors] == ["hall", "door", "kitchen"] and loaded.epoch_us == 0
    assert loaded.subscriptions() == ["zigbee2mqtt/+", "tasmota/kitchen_pir/POWER"]
    secret = tmp_path / "secret"
    secret.write_text("s3cret")
    (tmp_path / "ca.pem").write_text("x")
    config = tmp_path / "mqtt.toml"
    config.write_text(blocks[1].replace("/run/secrets/mqtt", str(secret)))
    options = broker_options("mqtt://h:1883", config)
    assert options.password == "s3cret" and options.tls and options.client_id == "bintrack-office"


# -- bad options: one line, exit 2 -----------------------------------------------------------


@pytest.mark.parametrize("extra, words", [
    ([], "needs --sensor-table FILE"),
    (["--sensor-table", "TABLE", "--exit-at-end"], "needs --end-topic TOPIC"),
    (["--sensor-table", "/nonexistent.toml"], "cannot read"),
    (["--sensor-table", "TABLE", str(DARPA3)], "not both"),
    (["--sensor-table", "TABLE", "--mqtt-config", "/nonexistent.toml"], "cannot read"),
])
def test_up_with_a_broker_rejects_bad_options_in_one_line(extra, words, tmp_path, capsys):
    from bintrack.cli import main as cli

    path = tmp_path / "t.toml"
    path.write_text(TABLE)
    args = ["up", "--source", "mqtt://127.0.0.1:1", *[str(path) if a == "TABLE" else a for a in extra]]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err


def test_up_refuses_a_broker_url_with_a_secret_without_showing_it(tmp_path, capsys):
    from bintrack.cli import main as cli

    path = tmp_path / "t.toml"
    path.write_text(TABLE)
    assert cli.main(["up", "--source", "mqtt://me:hunter2@127.0.0.1:1883", "--sensor-table", str(path)]) == 2
    err = capsys.readouterr().err
    assert "config file" in err and "hunter2" not in err


def test_the_bridge_service_exits_2_with_one_line_for_a_bad_table(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "t.toml"
    path.write_text(TABLE.replace('units = "m"', 'units = "parsec"'))
    done = subprocess.run([sys.executable, "-m", "bintrack.services.mqtt_bridge", "mqtt://127.0.0.1:1", "--sensor-table",
                           str(path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1 and "units" in done.stderr
