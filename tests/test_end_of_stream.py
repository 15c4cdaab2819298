"""The end of stream when services die around it: replay says it again to a service that comes
back after it and ends once every awaited service has reported done; a service downstream waits
for an upstream service that is gone at the end (and gives up, saying so, after a grace); a
finished service reports done again when the end is said again; the recorder records each once.
The live runs (services SIGKILLed after the end went out) are in tests/test_fault_pairs.py."""

from __future__ import annotations

import asyncio
import logging

import pytest

import bintrack.live.end_of_stream as end_of_stream
import bintrack.live.replay_gate as replay_gate
from bintrack.bus_payloads import EndOfStream as EndOfStreamMessage
from bintrack.keys import Keys, parse_key
from bintrack.live.end_of_stream import EndOfStream, UpstreamDone
from bintrack.live.disk_full import DiskFull
from bintrack.live.record_filter import RecordFilter
from bintrack.live.recording_end import RecordingEnd
from bintrack.live.recording_sink import RecordingSink
from bintrack.live.replay_gate import ReplayGate
from bintrack.live.track_ledger import TrackRefill
from bintrack.message_codec import encode

KEYS = Keys("net")


def alive(service: str, instance: str):
    return parse_key(KEYS.alive(service, instance))


def test_upstream_done_waits_for_a_service_gone_or_awaited_until_given_up():
    upstream = UpstreamDone(["basestation"])
    assert upstream.complete  # never seen: nothing to wait for
    upstream.on_presence(alive("basestation", "b"), True)
    upstream.on_presence(alive("basestation", "b"), False)
    assert upstream.gone() == ["basestation"] and not upstream.complete  # killed: its restart owes done
    upstream.give_up(["basestation"])
    assert upstream.complete
    upstream.on_presence(alive("basestation", "b"), True)
    assert not upstream.complete  # back: it owes its done again
    upstream.on_done("basestation", "b", 9.0)
    assert upstream.complete

    restarted = UpstreamDone(["basestation", "peer_agent"])
    restarted.expect(["basestation", "recorder"])  # replay's end names what it awaits
    assert restarted.gone() == ["basestation"] and not restarted.complete


def run(coroutine):
    return asyncio.run(asyncio.wait_for(coroutine, 10))


def test_a_finished_service_reports_done_again_when_the_end_is_said_again():
    reported = []

    async def scenario():
        end = EndOfStream("basestation", ["sensor_agent"], lambda t: None, reported.append)
        end.on_eos(5.0)
        end.on_eos(5.0)
        end.on_eos(6.0)  # not this run's end: ignored
        assert reported == [5.0, 5.0]

    run(scenario())


def test_the_end_waits_for_an_upstream_service_named_by_replay_and_gives_up_after_the_grace(monkeypatch, caplog):
    monkeypatch.setattr(end_of_stream, "END_GRACE", 0.05)
    finished, reported = [], []

    async def scenario():
        end = EndOfStream("recorder", ["basestation"], finished.append, reported.append)
        end.on_eos(5.0, ["basestation", "recorder"])  # restarted after the end: never saw the base station
        assert finished == []
        end.on_presence(alive("basestation", "b"), True)
        end.on_done("basestation", "b", 5.0)
        assert finished == reported == [5.0]

        late = EndOfStream("recorder", ["basestation"], finished.append, reported.append)
        late.on_eos(7.0, ["basestation"])
        assert finished == [5.0]
        while finished[-1] != 7.0:  # the grace passes
            await asyncio.sleep(0.01)

    with caplog.at_level(logging.WARNING, "bintrack"):
        run(scenario())
    assert "recorder: end of stream at t=7 s while basestation has no live instance; waiting up to 0.05 s" in caplog.text
    assert "recorder: basestation did not come back within 0.05 s of the end of stream; finishing" in caplog.text


def test_the_recorder_waits_for_an_upstream_service_gone_at_the_end_and_gives_up_after_the_grace(monkeypatch, caplog):
    monkeypatch.setattr(end_of_stream, "END_GRACE", 0.05)
    reported = []

    def unexpected(key, reason):
        pytest.fail(f"{key}: {reason}")

    async def scenario():
        stopping = asyncio.Event()
        sink = RecordingSink(RecordFilter(unexpected), DiskFull("stop", lambda status: pytest.fail("gave up")),
                             unexpected, lambda t: None, lambda part: None)
        refill = TrackRefill(KEYS.tracks(), lambda selector, timeout: [], lambda *a: False, unexpected, lambda: False)
        end = RecordingEnd(["basestation"], sink, refill, reported.append, True, stopping)
        end.on_presence(alive("basestation", "b"), True)
        end.on_presence(alive("basestation", "b"), False)  # killed just before the end
        end.on_eos(5.0)
        await asyncio.wait_for(end.run(), 5)  # the same wait as every other service's, not its 5 s poll

    with caplog.at_level(logging.WARNING, "bintrack"):
        run(scenario())
    assert reported == [5.0]
    assert "recorder: end of stream at t=5 s while basestation has no live instance; waiting up to 0.05 s" in caplog.text
    assert "recorder: basestation did not come back within 0.05 s of the end of stream; finishing" in caplog.text


def test_replay_lingers_after_its_end_until_every_awaited_instance_reported_done(monkeypatch, caplog):
    monkeypatch.setattr(replay_gate, "SAY_AGAIN", 0.05)
    said = []

    async def scenario():
        stopping = asyncio.Event()
        gate = ReplayGate(["basestation", "recorder"], lambda: False, stopping)
        for service in ("basestation", "recorder", "watcher"):
            gate.on_presence(alive(service, "1"), True)
        lingering = asyncio.create_task(gate.linger(5.0, lambda: said.append(len(said))))
        gate.reported_done("recorder", "1", 5.0)
        gate.on_presence(alive("recorder", "1"), False)  # it ends with the stream: not waited for
        gate.on_presence(alive("basestation", "1"), False)  # killed after the end went out ...
        await asyncio.wait_for(gate_said(said, 0), 5)  # ... said again every SAY_AGAIN s meanwhile
        assert not lingering.done()  # ... and held for (hold)
        before = len(said)
        gate.on_presence(alive("basestation", "1"), True)  # ... back: told at once
        await asyncio.wait_for(gate_said(said, before), 5)
        assert not lingering.done()
        gate.reported_done("basestation", "1", 5.0)
        assert await lingering  # "watcher" is not awaited: not waited for

    async def gate_said(said, before):
        while len(said) == before:
            await asyncio.sleep(0.01)

    with caplog.at_level(logging.INFO, "bintrack"):
        run(scenario())
    assert "replay: end of stream at t=5 s said again, for basestation/1 (back after it went out)" in caplog.text


def test_replay_without_awaited_services_ends_at_once():
    async def scenario():
        gate = ReplayGate([], lambda: False, asyncio.Event())
        gate.on_presence(alive("basestation", "1"), True)
        assert await gate.linger(5.0, pytest.fail)

    run(scenario())


def test_the_recorder_records_an_end_or_done_said_again_once():
    recorder = RecordFilter(lambda key, reason: pytest.fail(f"{key}: {reason}"))
    for key, payload in [(KEYS.eos(), encode(EndOfStreamMessage(t=5.0, awaited=["recorder"]))),
                         (KEYS.done("sensor_agent", "a"), encode(EndOfStreamMessage(t=5.0)))]:
        admitted = recorder.admit(key, payload, None)
        assert admitted is not None
        recorder.recorded(admitted, key, payload)
        assert recorder.admit(key, payload, None) is None
    later = encode(EndOfStreamMessage(t=9.0))  # the next pass's end (--loop) is recorded
    assert recorder.admit(KEYS.eos(), later, None) is not None
