"""Replay: the pure schedule (ticks, acknowledgements, pacing, loop shift) and the live service
on a real Zenoh router with real subprocesses — dataset → recorder, recording → recorder,
--loop, flow control against a consumer that is slow to acknowledge, a late router."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from bintrack.keys import Keys
from bintrack.live.session_options import client_config, router_config
from bintrack.formats import Event, open_dataset, write_dataset
from bintrack.bus_payloads import Clock, EndOfStream, RawSample
from bintrack.deployment_model import Deployment, DiskSensor, Region
from bintrack.message_codec import decode, encode
from bintrack.live.recording import open_recording
from bintrack.live.replay_schedule import (Consumers, End, Gap, NothingToReplay, Pacer, Publish, Tick, default_clock_period,
                                           schedule)

from support import DATASETS, HUNG, REPO, bintrack, free_port, wait_logged, wait_until

def output(process) -> str:
    """What a service process has logged so far (also after it exited)."""
    return process.log_path.read_text()


EVENTS = [(0.1, "a"), (0.3, "b"), (0.5, "c"), (0.7, "d"), (1.2, "e")]


def plan(items, *, loop_passes: int | None = None, **options):
    """The schedule as a list (the first ``loop_passes`` passes when looping)."""
    actions = []
    for action in schedule(lambda: iter(items), **options):
        actions.append(action)
        if isinstance(action, End) and (action.last or loop_passes is not None and
                                        sum(isinstance(a, End) for a in actions) == loop_passes):
            break
    return actions


# --------------------------------------------------------------------------- pure schedule


def test_grid_ticks_acknowledgements_and_end():
    assert plan(EVENTS, period=0.5) == [
        Tick(0.0, None), Publish(0.1, "a", 0.0), Publish(0.3, "b", 0.0),
        Tick(0.5, 0.0), Publish(0.5, "c", 0.0), Publish(0.7, "d", 0.0),  # an event at a tick's time follows it
        Tick(1.0, 0.5), Publish(1.2, "e", 0.0),
        Tick(1.5, 1.0),  # the last tick: past the last event
        End(1.2, 1.5, True),
    ]


def test_default_clock_period_is_50_ms_of_wall_clock_within_bounds():
    assert default_clock_period(1.0) == pytest.approx(0.05)
    assert default_clock_period(0.25) == pytest.approx(0.05)  # never finer than 0.05 s of event time
    assert default_clock_period(4.0) == pytest.approx(0.2)
    assert default_clock_period(100.0) == pytest.approx(0.5)  # never coarser than a PIR scan
    assert default_clock_period(0.0) == pytest.approx(0.5)  # as fast as flow control allows
    for bad in (-1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="speed"):
            default_clock_period(bad)


def test_grid_starts_at_the_first_event_floored_and_skips_no_tick():
    actions = plan([(3.7, "a"), (5.2, "b")], period=1.0)
    assert [a.t for a in actions if isinstance(a, Tick)] == [3.0, 4.0, 5.0, 6.0]
    assert actions[-1] == End(5.2, 6.0, True)


def test_max_ahead_lets_more_ticks_go_unacknowledged():
    ticks = [a for a in plan(EVENTS, period=0.5, max_ahead=2) if isinstance(a, Tick)]
    assert ticks == [Tick(0.0, None), Tick(0.5, None), Tick(1.0, 0.0), Tick(1.5, 0.5)]


def test_loop_shifts_event_time_by_the_pass_plus_one_period():
    actions = plan(EVENTS, period=0.5, loop=True, loop_passes=3)
    ends = [a for a in actions if isinstance(a, End)]
    assert ends == [End(1.2, 1.5, False), End(3.2, 3.5, False), End(5.2, 5.5, False)]
    second = actions[len(actions) // 3:2 * len(actions) // 3]
    assert second[0] == Tick(2.0, 1.5)  # the grid goes on where the first pass ended
    assert [(a.t, a.item, a.shift) for a in second if isinstance(a, Publish)] == [(t + 2.0, s, 2.0) for t, s in EVENTS]
    times = [a.t for a in actions if not isinstance(a, End)]
    assert times == sorted(times)


def test_recorded_ticks_are_used_and_a_final_tick_added_when_missing():
    items = [(0.0, None), (0.1, "a"), (0.5, None), (0.5, "b"), (0.9, "c")]
    assert plan(items, period=0.5, recorded_ticks=True) == [
        Tick(0.0, None), Publish(0.1, "a", 0.0), Tick(0.5, 0.0), Publish(0.5, "b", 0.0), Publish(0.9, "c", 0.0),
        Tick(1.0, 0.5), End(0.9, 1.0, True),
    ]
    # a recording that has its final tick already gets no extra one
    assert plan(items + [(1.0, None)], period=0.5, recorded_ticks=True)[-2:] == [Tick(1.0, 0.5), End(0.9, 1.0, True)]


def test_a_gap_longer_than_max_gap_is_jumped_over_not_ticked_through():
    items = [(0.1, "a"), (0.7, "b"), (1e9 + 0.2, "c")]
    assert plan(items, period=0.5, max_gap=60.0) == [
        Tick(0.0, None), Publish(0.1, "a", 0.0), Tick(0.5, 0.0), Publish(0.7, "b", 0.0),
        Tick(1.0, 0.5),  # the first tick past the item before the gap
        Gap(1.0, 1e9), Tick(1e9, 1.0), Publish(1e9 + 0.2, "c", 0.0), Tick(1e9 + 0.5, 1e9), End(1e9 + 0.2, 1e9 + 0.5, True),
    ]
    # a gap up to max_gap is ticked through as before; recorded ticks jump to the next item
    assert not any(isinstance(a, Gap) for a in plan([(0.1, "a"), (59.0, "b")], period=0.5, max_gap=60.0))
    recorded = plan([(0.0, None), (0.1, "a"), (0.5, None), (1e6, "b"), (1e6 + 0.5, None)], period=0.5,
                    recorded_ticks=True, max_gap=60.0)
    assert recorded[3:5] == [Gap(0.5, 1e6), Publish(1e6, "b", 0.0)]


def test_pacer_skips_a_gap():
    pacer = Pacer(1.0)
    assert pacer.delay(10.0, now=100.0) == 0.0
    pacer.skip(1e9)
    assert pacer.delay(1e9 + 12.0, now=100.0) == pytest.approx(2.0)


def test_nothing_to_replay_and_bad_options():
    with pytest.raises(NothingToReplay):
        plan([], period=0.5)
    with pytest.raises(NothingToReplay):  # only ticks left after filtering
        plan([(0.0, None), (0.5, None)], period=0.5, recorded_ticks=True)
    with pytest.raises(ValueError):
        plan(EVENTS, period=0.0)
    with pytest.raises(ValueError):
        plan(EVENTS, period=0.5, max_ahead=0)


def test_pacer():
    pacer = Pacer(2.0)
    assert pacer.delay(10.0, now=100.0) == 0.0  # the first event time is due at once
    assert pacer.delay(11.0, now=100.1) == pytest.approx(0.4)  # 1 s of event time = 0.5 s of wall clock
    assert pacer.delay(11.0, now=101.0) == 0.0  # late: catch up
    assert Pacer(0).delay(1e6, now=0.0) == 0.0
    with pytest.raises(ValueError):
        Pacer(-1)


def test_consumers_owe_only_ticks_published_while_they_were_live():
    consumers = Consumers()
    consumers.appeared("a", None)
    consumers.appeared("b", 1.0)  # came after the tick at 1.0 went out
    assert consumers.owing(1.0) == ["a"]
    assert consumers.owing(1.5) == ["a", "b"]
    consumers.reported("a", 1.5)
    consumers.reported("a", 0.5)  # progress never goes back
    assert consumers.owing(1.5) == ["b"]
    consumers.vanished("b")
    assert consumers.owing(1.5) == [] and len(consumers) == 1


# --------------------------------------------------------------------------- live


def tiny_dataset(folder: Path, events: list[tuple[float, str, int]] | None = None) -> Path:
    deployment = Deployment(name="tiny", units="m", region=Region(xmin=0, ymin=0, xmax=10, ymax=10),
                            sensors=[DiskSensor(id=f"s{i}", x=2.0 * i, y=5.0, range=2.0) for i in range(3)])
    events = events or [(0.1, "s0", 1), (0.3, "s1", 1), (0.5, "s0", 0), (0.5, "s2", 1), (1.25, "s1", 0), (1.9, "s2", 0)]
    return write_dataset(folder, deployment, [Event(*e) for e in events])


def client(endpoint: str) -> zenoh.Session:
    return zenoh.open(client_config([endpoint]))


def kinds(recording) -> list[str]:
    return [r.kind for r in recording.records()]


def test_dataset_into_recorder(tmp_path, zenoh_router, services):
    data = tiny_dataset(tmp_path / "tiny")
    out = tmp_path / "run.mcap"
    recorder = services("recorder", "--out", str(out), "--net", "tiny", endpoint=zenoh_router)
    # no --clock-period: at --speed 0 the ticks are 0.5 s of event time apart (default_clock_period)
    replay = services("replay", str(data), "--speed", "0", "--wait-for", "recorder", endpoint=zenoh_router)
    assert replay.wait(HUNG) == 0, output(replay)
    assert recorder.wait(HUNG) == 0, output(recorder)

    recording = open_recording(out)
    assert recording.complete and recording.net == "tiny"
    assert recording.deployment == open_dataset(data).deployment
    records = list(recording.records())
    raw = [r for r in records if r.kind == "raw"]
    samples = [decode(RawSample, r.payload) for r in raw]
    assert [(s.t, s.sensor, s.value) for s in samples] == [tuple(e) for e in open_dataset(data).events()]
    assert [r.key for r in raw] == [f"bintrack/tiny/raw/{s.sensor}" for s in samples]
    assert [r.t for r in raw] == [s.t for s in samples]  # log time = event time
    ticks = [decode(Clock, r.payload).t for r in records if r.kind == "clock"]
    assert ticks == [0.0, 0.5, 1.0, 1.5, 2.0]
    eos = [decode(EndOfStream, r.payload).t for r in records if r.kind == "eos"]
    assert eos == [1.9]
    # a tick precedes the events at its own time, as it was published
    assert kinds(recording)[:5] == ["clock", "raw", "raw", "clock", "raw"]


def test_replay_of_a_recording_gives_the_same_raw_records(tmp_path, zenoh_router, services):
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    recorder = services("recorder", "--out", str(first), "--net", "darpa-grid", endpoint=zenoh_router)
    replay = services("replay", str(DATASETS / "darpa-grid-1"), "--speed", "0", "--wait-for", "recorder",
                      endpoint=zenoh_router)
    assert replay.wait(HUNG) == 0, output(replay)
    assert recorder.wait(HUNG) == 0, output(recorder)

    recorder = services("recorder", "--out", str(second), "--net", "darpa-grid", endpoint=zenoh_router)
    replay = services("replay", str(first), "--speed", "0", "--wait-for", "recorder", "--keys", "bintrack/*/raw/**",
                      endpoint=zenoh_router)
    assert replay.wait(HUNG) == 0, output(replay)
    assert recorder.wait(HUNG) == 0, output(recorder)

    a, b = open_recording(first), open_recording(second)
    assert b.deployment == a.deployment
    for kind in ("raw", "clock", "eos"):
        left = [(r.key, r.t, r.payload) for r in a.records() if r.kind == kind]
        right = [(r.key, r.t, r.payload) for r in b.records() if r.kind == kind]
        assert left == right, kind
    assert sum(r.kind == "raw" for r in a.records()) == 2535


def test_loop_keeps_event_time_increasing(tmp_path, zenoh_router, services):
    """Also `bintrack record` (records until Ctrl-C) and `bintrack replay`."""
    data = tiny_dataset(tmp_path / "tiny")
    out, log = tmp_path / "loop.mcap", tmp_path / "record.log"
    with open(log, "w") as sink:
        record = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "record", "--out", str(out), "--net", "tiny",
                                   "-e", zenoh_router], stdout=sink, stderr=subprocess.STDOUT, cwd=REPO)
    try:
        replay = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "replay", str(data), "--speed", "4", "--loop",
                                   "--clock-period", "0.5", "--wait-for", "recorder", "-e", zenoh_router], cwd=REPO)
        try:
            wait_until(lambda: log.read_text().count("end of stream at") >= 2, what="two passes")
            replay.send_signal(signal.SIGINT)
            assert replay.wait(HUNG) == 0
        finally:
            replay.kill()
        record.send_signal(signal.SIGINT)
        assert record.wait(HUNG) == 0, log.read_text()
    finally:
        record.kill()

    records = list(open_recording(out).records())
    raw = [decode(RawSample, r.payload) for r in records if r.kind == "raw"]
    events = list(open_dataset(data).events())
    shift = 2.0 + 0.5  # last tick 2.0 − first tick 0.0 + one period
    assert [(s.t, s.sensor, s.value) for s in raw[:2 * len(events)]] == \
        [tuple(e) for e in events] + [(e.t + shift, e.sensor, e.value) for e in events]
    assert [decode(EndOfStream, r.payload).t for r in records if r.kind == "eos"][:2] == [1.9, 1.9 + shift]
    ticks = [decode(Clock, r.payload).t for r in records if r.kind == "clock"]
    assert ticks[:10] == [0.5 * k for k in range(10)]  # one grid across passes, no tick twice


def test_replay_waits_for_each_consumer_to_acknowledge(tmp_path, zenoh_router, services):
    data = tiny_dataset(tmp_path / "tiny")
    session = client(zenoh_router)
    keys = Keys("tiny")
    ticks: list[float] = []  # each tick once: replay says its last one again while an acknowledgement is overdue

    every: list[float] = []  # every tick, repeats included

    def on_tick(sample) -> None:
        t = decode(Clock, sample.payload.to_bytes()).t
        every.append(t)
        if t not in ticks:
            ticks.append(t)

    subscriber = session.declare_subscriber(keys.clock(), on_tick)
    token = session.liveliness().declare_token(keys.alive("slow", "1"))
    try:
        replay = services("replay", str(data), "--speed", "0", "--clock-period", "0.5", "--max-ahead", "1",
                          "--wait-for", "slow", endpoint=zenoh_router)
        # replay says what it waits for (every 5 s of waiting): the acknowledgement of the tick
        # before; until then it publishes no tick
        wait_until(lambda: ticks == [0.0], what="the first tick")
        wait_logged(replay, "replay: waiting for progress >= 0 s from slow/1")
        assert ticks == [0.0], "replay ran ahead of an unacknowledged tick"
        # overdue: the last tick is said again (a consumer cut off may have lost it)
        wait_until(lambda: every.count(0.0) >= 2, what="the tick said again")
        session.put(keys.progress("slow", "1"), encode(Clock(t=0.0)))
        wait_until(lambda: ticks == [0.0, 0.5], what="the second tick")
        wait_logged(replay, "replay: waiting for progress >= 0.5 s from slow/1")
        assert ticks == [0.0, 0.5]
        token.undeclare()  # an awaited service that leaves: the clock holds until one is back
        wait_logged(replay, "slow gone; holding event time")
        assert ticks == [0.0, 0.5]
        # a new instance is not waited for on the ticks it never saw
        token = session.liveliness().declare_token(keys.alive("slow", "2"))
        wait_until(lambda: ticks == [0.0, 0.5, 1.0], what="the tick after the hold")
        ends: list[EndOfStream] = []
        heard = session.declare_subscriber(keys.eos(), lambda s: ends.append(decode(EndOfStream, s.payload.to_bytes())))
        session.put(keys.progress("slow", "2"), encode(Clock(t=10.0)))
        # after its end, replay says it again until the awaited service reports done, then ends
        wait_until(lambda: len(ends) >= 2, what="the end of stream said again")
        assert replay.proc.poll() is None and ends[0] == ends[1] and ends[0].awaited == ["slow"]
        session.put(keys.done("slow", "2"), encode(EndOfStream(t=ends[0].t)))
        assert replay.wait(HUNG) == 0, output(replay)
        heard.undeclare()
        assert ticks == [0.0, 0.5, 1.0, 1.5, 2.0]
    finally:
        if token is not None:
            token.undeclare()
        subscriber.undeclare()
        session.close()


def test_replay_before_the_router_retries_then_works(tmp_path, services):
    data = tiny_dataset(tmp_path / "tiny")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    replay = services("replay", str(data), "--speed", "0", "--wait-for", "recorder", "--wait", "30", endpoint=endpoint)
    wait_logged(replay, "waiting for the Zenoh router")
    assert replay.proc.poll() is None
    router = zenoh.open(router_config([endpoint]))
    try:
        recorder = services("recorder", "--out", str(tmp_path / "late.mcap"), "--net", "tiny", endpoint=endpoint)
        assert replay.wait(HUNG) == 0, output(replay)
        assert recorder.wait(HUNG) == 0, output(recorder)
    finally:
        router.close()
    assert sum(r.kind == "raw" for r in open_recording(tmp_path / "late.mcap").records()) == 6


def test_missing_service_times_out_with_a_clear_error(tmp_path, zenoh_router, services):
    data = tiny_dataset(tmp_path / "tiny")
    replay = services("replay", str(data), "--wait-for", "recorder,basestation", "--ready-timeout", "1",
                      endpoint=zenoh_router)
    assert replay.wait(HUNG) == 1
    assert "no liveliness token from recorder, basestation on bintrack/tiny/alive/*/* after 1 s" in output(replay)


@pytest.mark.parametrize("make, message", [
    (lambda p: p / "absent", "not a folder"),
    (lambda p: (p / "x.mcap").write_bytes(b"not mcap at all") and p / "x.mcap", "not an MCAP recording"),
    (lambda p: tiny_dataset(p / "d", [(0.5, "s0", 1), (0.1, "s1", 1)]), "earlier than the previous row"),
])
def test_bad_source_is_one_line_and_exit_2(tmp_path, make, message):
    source = make(tmp_path)
    # a port nobody listens on: the default 127.0.0.1:7447 may be another stack's router (CI's
    # compose test publishes one there), which this replay would join until it found the bad row
    result = bintrack("replay", str(source), "-e", f"tcp/127.0.0.1:{free_port()}", "--wait", "1")
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr, result.stderr
