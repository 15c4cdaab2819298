"""The live services survive bad input and failures: real Zenoh sessions on loopback, real
service subprocesses, nothing mocked.

* Bad input: garbage bytes, msgpack of the wrong schema, an unknown sensor id, NaN in ``t``,
  duplicates and out-of-order messages, injected from a test session into each service that
  consumes messages. The service goes on (a good message afterwards is processed), logs one
  warning line per sender with the reason, and at SIGTERM exits 0 with a summary that counts them.
* Kill and restart: SIGKILL a peer agent, or a sensor agent, of a running stack; the others go
  on publishing, replay does not wait for the dead one, and the restarted one publishes again.
* Started before the router: the service waits with one clear line and comes up when the
  router does; with ``--wait 1`` and no router it exits 1 with a one-line message.
"""

from __future__ import annotations

import ast
import itertools
import math
import re
import signal
import threading
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import msgpack
import pytest
import zenoh

from bintrack.live.session_options import router_config
from bintrack.live.control_guard import control_attachment
from bintrack.formats import open_dataset
from bintrack.keys import Keys, parse_key
from bintrack.bus_payloads import Clock, EndOfStream, LocalEstimate, RawSample, SensorState, TrackSet, Transition
from bintrack.deployment_model import Deployment, DiskSensor, Region
from bintrack.message_codec import RESENT, decode, encode, encode_raw_sample, is_resent
from bintrack.live.recording import RecordingWriter, open_recording

from conftest import write_foreign_dataset
from support import HUNG, FakeBus, free_port, kind_of, wait_until

NET = "faults"
KEYS = Keys(NET)
# Five disk sensors on a line, neighbours of each other: n0 … n4 at x = 0 … 4.
DEPLOYMENT = Deployment(name=NET, units="m", region=Region(xmin=-5, ymin=-5, xmax=10, ymax=5),
                        sensors=[DiskSensor(id=f"n{i}", x=float(i), y=0.0, range=2.0) for i in range(5)])
TRACKER = "equal-weight"


@pytest.fixture
def bus(zenoh_router):
    handle = FakeBus(zenoh_router, DEPLOYMENT)
    yield handle
    handle.close()


# --------------------------------------------------------------------------- bad input

NAN_T = float("nan")


@dataclass(frozen=True)
class Bad:
    """A bad payload sent on ``key``: the count key it is summed under and part of its reason."""

    key: str
    payload: bytes
    kind: str
    reason: str


def packed(**fields) -> bytes:
    return msgpack.packb({"version": 1, **fields})


def send_bad(bus: FakeBus, cases: list[Bad]) -> None:
    for case in cases:
        bus.put(case.key, case.payload)


def check_bad_input_accounting(proc, service: str, cases: list[Bad]) -> None:
    """(b) one warning line per sender, with the reason of the first bad payload it sent, and
    (c) exit 0 at SIGTERM with a summary line that counts every bad payload by kind."""
    assert proc.proc.poll() is None, proc.log
    assert proc.stop() == 0, proc.log
    log = proc.log
    assert "Traceback" not in log, log
    warnings = [line for line in log.splitlines() if "dropped a bad payload from" in line]
    first: dict[str, Bad] = {}
    for case in cases:
        first.setdefault(case.key, case)
    assert len(warnings) == len(first), log
    for sender, case in first.items():
        lines = [line for line in warnings if f"dropped a bad payload from {sender}: " in line]
        assert len(lines) == 1, (sender, log)
        assert case.reason in lines[0], (case, lines[0])
        assert lines[0].startswith(tuple("0123456789")) and f"{service}: " in lines[0]  # a log line, not a trace
    summary = [line for line in log.splitlines() if re.search(rf"{service}: \d+ bad payloads", line)]
    assert len(summary) == 1 and log.strip().splitlines()[-1] == summary[0], log  # the final line
    match = re.search(rf"{service}: (\d+) bad payloads (\{{.*\}}), (\d+) dropped when the inbox was full", summary[0])
    assert match, summary[0]
    assert int(match.group(1)) == len(cases)
    assert Counter(ast.literal_eval(match.group(2))) == Counter(case.kind for case in cases)
    assert int(match.group(3)) == 0


def twice(*cases: Bad) -> list[Bad]:
    """Each case sent two times: still one warning line per sender, both counted."""
    return [case for case in cases for _ in range(2)]


def test_sensor_agent_survives_bad_raw_samples(zenoh_router, services, bus):
    agent = services("sensor_agent", "--net", NET, endpoint=zenoh_router)
    bus.wait_for("sensor_agent", agent)
    garbage = twice(
        Bad(KEYS.raw("n0"), b"\xc1\xc1 not msgpack at all", "not msgpack", "not msgpack"),
        Bad(KEYS.raw("n1"), packed(temperature=21.5), "invalid RawSample", "invalid RawSample: t: Field required"),
        Bad(KEYS.raw("zz"), encode(RawSample(t=1.0, sensor="zz", value=1)), "unknown sensor id 'zz'", "unknown sensor id 'zz'"),
        Bad(KEYS.raw("n2"), packed(t=NAN_T, sensor="n2", value=1), "invalid RawSample", "invalid RawSample: t: Input should be a finite number"),
        Bad(KEYS.raw("n4"), encode(RawSample(t=1.0, sensor="n4", value=7)), "disk sensor reports 0 or 1, got 7", "disk sensor reports 0 or 1, got 7"),
    )
    send_bad(bus, garbage)
    # Order is checked per sensor: n3 at t=1 (a transition), the same sample again (a
    # duplicate repeats the status: no transition), then two samples older than t=1.
    bus.put(KEYS.raw("n3"), RawSample(t=1.0, sensor="n3", value=1))
    bus.put(KEYS.raw("n3"), RawSample(t=1.0, sensor="n3", value=1))
    out_of_order = twice(Bad(KEYS.raw("n3"), encode(RawSample(t=0.5, sensor="n3", value=0)), "out of order",
                             "out of order: t=0.5 after t=1.0"))
    send_bad(bus, out_of_order)
    # (a) good samples afterwards become transitions, and n3 continues from its status
    bus.put(KEYS.raw("n3"), RawSample(t=2.0, sensor="n3", value=0))
    bus.put(KEYS.raw("n4"), RawSample(t=2.0, sensor="n4", value=1))
    bus.tick(3.0, "sensor_agent", agent)
    wait_until(lambda: len(bus.messages("transition")) >= 3, "three transitions", logs=[agent])
    transitions = sorted(((m.sensor, m.seq, m.t, m.previous, m.value) for _, m in bus.messages("transition")))
    assert transitions == [("n3", 1, 1.0, 0, 1), ("n3", 2, 2.0, 1, 0), ("n4", 1, 2.0, 0, 1)]
    check_bad_input_accounting(agent, "sensor_agent", garbage + out_of_order)


def transition(sensor: str, seq: int, t: float, value: int) -> Transition:
    return Transition(t=t, sensor=sensor, value=value, previous=1 - value, seq=seq)


def test_peer_agent_survives_bad_transitions(zenoh_router, services, bus):
    bus.play("sensor_agent")
    agent = services("peer_agent", "--tracker", TRACKER, "--lateness", "1", "--net", NET, endpoint=zenoh_router)
    bus.wait_for("peer_agent", agent)
    garbage = twice(
        Bad(KEYS.transition("n0"), b"\x00garbage\xff", "not msgpack", "not msgpack"),
        Bad(KEYS.transition("n1"), encode(RawSample(t=1.0, sensor="n1", value=1)), "invalid Transition",
            "invalid Transition: previous: Field required"),
        Bad(KEYS.transition("zz"), encode(transition("zz", 1, 1.0, 1)), "transition of unknown or mismatched sensor 'zz'",
            "transition of unknown or mismatched sensor 'zz'"),
        Bad(KEYS.transition("n2"), packed(t=NAN_T, sensor="n2", value=1, previous=0, seq=1), "invalid Transition",
            "invalid Transition: t: Input should be a finite number"),
    )
    send_bad(bus, garbage)
    # n3: seq 1 and 2, with seq 1 again in between (a duplicate) and after 2 (out of order)
    bus.put(KEYS.transition("n3"), transition("n3", 1, 1.0, 1))
    duplicates = [Bad(KEYS.transition("n3"), encode(transition("n3", 1, 1.0, 1)), "duplicate",
                      "duplicate: seq 1 seen already")]
    send_bad(bus, duplicates)
    bus.put(KEYS.transition("n3"), transition("n3", 2, 1.5, 0))
    out_of_order = [Bad(KEYS.transition("n3"), encode(transition("n3", 1, 1.0, 1)), "duplicate",
                        "duplicate: seq 1 seen already")]
    send_bad(bus, out_of_order)
    bus.tick(3.0, "peer_agent", agent)  # watermark 2.0: n3's two transitions are released
    # out of order in event time: behind the watermark (lateness 1 s)
    late = [Bad(KEYS.transition("n4"), encode(transition("n4", 1, 1.2, 1)), "late",
                "late: t=1.2 is behind the watermark 2 s (lateness 1.0 s)"),
            Bad(KEYS.transition("n4"), encode(transition("n4", 2, 1.4, 0)), "late", "late")]
    send_bad(bus, late)
    # (a) a good transition afterwards contributes to an estimate after a clock tick
    bus.put(KEYS.transition("n1"), transition("n1", 1, 6.0, 1))
    bus.tick(8.0, "peer_agent", agent)
    wait_until(lambda: len(bus.messages("estimate")) >= 2, "two estimates", logs=[agent])
    estimates = [(key, m.t, m.node, m.x, m.y) for key, m in bus.messages("estimate")]
    # n3 alone detected at t=1 (its seq 2 at t=1.5 leaves nobody detecting: no estimate);
    # at t=6 only n1 detects (n4's late transitions were dropped, n3 is absent again)
    assert estimates == [(f"bintrack/{NET}/peer/n3/estimate", 1.0, "n3", 3.0, 0.0),
                         (f"bintrack/{NET}/peer/n1/estimate", 6.0, "n1", 1.0, 0.0)]
    check_bad_input_accounting(agent, "peer_agent", garbage + duplicates + out_of_order + late)


def estimate(node: str, t: float, x: float, tracker: str = TRACKER) -> LocalEstimate:
    return LocalEstimate(t=t, node=node, tracker=tracker, x=x, y=0.0)


def test_basestation_survives_bad_estimates(zenoh_router, services, bus):
    bus.play("peer_agent")
    station = services("basestation", "--tracker", TRACKER, "--lateness", "2", "--net", NET, endpoint=zenoh_router)
    bus.wait_for("basestation", station)
    garbage = twice(
        Bad(KEYS.estimate("n0"), b"\xc1", "not msgpack", "not msgpack"),
        Bad(KEYS.estimate("n1"), encode(transition("n1", 1, 1.0, 1)), "invalid LocalEstimate", "invalid LocalEstimate: "),
        Bad(KEYS.estimate("zz"), encode(estimate("zz", 1.0, 0.5)), "estimate of unknown or mismatched node 'zz'",
            "estimate of unknown or mismatched node 'zz'"),
        Bad(KEYS.estimate("n2"), packed(t=NAN_T, node="n2", tracker=TRACKER, x=1.0, y=0.0), "invalid LocalEstimate",
            "invalid LocalEstimate: t: Input should be a finite number"),
        Bad(KEYS.estimate("n4"), encode(estimate("n4", 1.0, 4.0, tracker="arc")),
            "estimate of tracker 'arc', this base station runs 'equal-weight'", "estimate of tracker 'arc'"),
    )
    send_bad(bus, garbage)
    # Out of order within the lateness bound is put in order; the very same estimate again (as
    # a peer agent restarted from its checkpoint sends) is dropped as a duplicate.
    bus.put(KEYS.estimate("n3"), estimate("n3", 1.5, 3.0))
    bus.put(KEYS.estimate("n2"), estimate("n2", 1.0, 2.0))
    duplicate = [Bad(KEYS.estimate("n2"), encode(estimate("n2", 1.0, 2.0)), "duplicate",
                     "duplicate: estimate at t=1.0 seen already")]
    send_bad(bus, duplicate)
    bus.tick(4.0, "basestation", station)  # watermark 2.0 (lateness 2 s)
    late = twice(Bad(KEYS.estimate("n1"), encode(estimate("n1", 0.5, 1.0)), "late",
                     "late: t=0.5 is behind the watermark 2 s (lateness 2.0 s)"))
    send_bad(bus, late)
    bus.put(KEYS.estimate("n1"), estimate("n1", 5.0, 1.5))  # (a) a good one afterwards
    bus.tick(8.0, "basestation", station)
    wait_until(lambda: len(bus.messages("tracks")) >= 3, "three track sets", logs=[station])
    tracks = [(m.t, m.tracker, [(k.track, k.x, k.y) for k in m.tracks]) for _, m in bus.messages("tracks")]
    assert tracks == [(1.0, TRACKER, [(0, 2.0, 0.0)]), (1.5, TRACKER, [(0, 3.0, 0.0)]),
                      (5.0, TRACKER, [(0, 1.5, 0.0)])]
    latest = [decode(TrackSet, r.ok.payload.to_bytes()) for r in bus.session.get(bus.keys.tracks(), timeout=HUNG) if r.ok]
    assert [m.t for m in latest] == [5.0]  # the tracks queryable answers too
    check_bad_input_accounting(station, "basestation", garbage + duplicate + late)


def test_recorder_survives_bad_payloads(tmp_path, zenoh_router, services, bus):
    out = tmp_path / "faults.mcap"
    recorder = services("recorder", "--out", str(out), "--net", NET, endpoint=zenoh_router)
    bus.wait_for("recorder", recorder)
    garbage = twice(
        Bad(KEYS.raw("n0"), b"\xc1 garbage", "not msgpack", "not msgpack"),
        Bad(KEYS.clock(), encode(RawSample(t=1.0, sensor="n1", value=1)), "invalid Clock", "invalid Clock: "),
        Bad(f"{KEYS.prefix}/no/such/key", encode(Clock(t=1.0)), "unknown key", "unknown key: not a key of a bintrack message"),
        Bad(KEYS.raw("n2"), packed(t=NAN_T, sensor="n2", value=1), "invalid RawSample",
            "invalid RawSample: t: Input should be a finite number"),
        Bad(KEYS.estimate("n1"), packed(t=-1.0, node="n1", tracker=TRACKER, x=1.0, y=0.0), "unrecordable",
            "unrecordable: event time -1.0 s cannot be an MCAP log time"),
    )
    send_bad(bus, garbage)
    # The recorder keeps what was on the bus: a sample of a sensor it does not know, a
    # duplicate and an out-of-order one are valid messages and are recorded as they came.
    bus.put(KEYS.raw("n3"), RawSample(t=1.0, sensor="n3", value=1))
    bus.put(KEYS.raw("n3"), RawSample(t=1.0, sensor="n3", value=1))
    bus.put(KEYS.raw("n3"), RawSample(t=0.5, sensor="n3", value=0))
    bus.put(KEYS.raw("zz"), RawSample(t=1.5, sensor="zz", value=1))
    bus.put(KEYS.raw("n4"), RawSample(t=2.0, sensor="n4", value=1))  # (a) a good one after the bad ones
    bus.tick(3.0, "recorder", recorder)
    check_bad_input_accounting(recorder, "recorder", garbage)
    recording = open_recording(out)
    assert recording.complete  # SIGTERM finalised the file
    assert [(r.key.removeprefix(f"bintrack/{NET}/"), r.t) for r in recording.records()] == [
        ("raw/n3", 0.5), ("raw/n3", 1.0), ("raw/n3", 1.0), ("raw/zz", 1.5), ("raw/n4", 2.0), ("clock", 3.0)]


# --------------------------------------------------------------------------- kill and restart


def sent(sensor: str, seq: int, t: float, value: int, source_seq: int) -> Transition:
    return Transition(t=t, sensor=sensor, value=value, previous=1 - value, seq=seq, source="test",
                      source_seq=source_seq)


def test_a_transition_lost_while_its_agent_restarts_is_fetched_at_its_next_progress_report(
        zenoh_router, services, bus):
    """n1's seq 2 is lost in flight (its agent killed with it unsent) and seq 3 arrives: the gap
    cannot be repaired while the agent is down (no state reply), so seq 3 is taken; the agent's
    next progress report (3 sent before n2's) shows the shortfall and the peer agent fetches
    seq 2 from its state then, although a later seq of n1 was taken already. The estimates are
    those of the transitions in event-time order."""
    bus.play("sensor_agent")
    agent = services("peer_agent", "--tracker", TRACKER, "--net", NET, endpoint=zenoh_router)
    bus.wait_for("peer_agent", agent)
    on, lost, n2_on, again = (sent("n1", 1, 1.0, 1, 1), sent("n1", 2, 2.0, 0, 2), sent("n2", 1, 2.5, 1, 3),
                              sent("n1", 3, 3.0, 1, 4))
    for transition in (on, n2_on, again):
        bus.put(KEYS.transition(transition.sensor), transition)
    wait_until(lambda: "seq gap before 3 of n1 could not be repaired" in agent.log, "the gap logged", logs=[agent])
    reply = encode(SensorState(t=3.0, sensor="n1", value=1, seq=3, missed=[lost, again]))
    state = bus.session.declare_queryable(bus.keys.state("n1"), lambda q: q.reply(bus.keys.state("n1"), reply))
    try:
        bus.tick(5.0, "peer_agent", agent, sent=4)
    finally:
        state.undeclare()
    wait_until(lambda: len(bus.messages("estimate")) >= 3, "three estimates", logs=[agent])
    # n2 alone detects at 2.5 s (n1 went at 2.0 s); both at 3.0 s
    assert [(m.t, m.node, m.x) for _, m in bus.messages("estimate")] == [(1.0, "n1", 1.0), (2.5, "n2", 2.0),
                                                                        (3.0, "n1", 1.5)]
    assert agent.stop() == 0
    assert "bad payloads" not in agent.log, agent.log


def test_a_restarted_sensor_agent_still_serves_what_it_sent_before_its_checkpoint(tmp_path, zenoh_router,
                                                                                  services, bus):
    """Transitions sent in the last seconds before a SIGKILL may have been in flight: the
    checkpoint keeps them, and the instance restarted from it answers a state query for them."""
    state_dir = tmp_path / "state"
    state_dir.mkdir(mode=0o700)
    args = ("--sensors", "n0", "--id", "s0", "--state-dir", str(state_dir), "--net", NET)
    recent = bus.session.declare_queryable(bus.keys.recent(), lambda q: q.reply(bus.keys.recent(),
                                                                                encode(Clock(t=2.5))))
    try:
        agent = services("sensor_agent", *args, endpoint=zenoh_router)
        bus.wait_for("sensor_agent", agent)
        for t, value in ((1.0, 1), (2.0, 0)):
            bus.put(KEYS.raw("n0"), RawSample(t=t, sensor="n0", value=value))
        bus.tick(2.5, "sensor_agent", agent)
        wait_until(lambda: len(bus.messages("transition")) >= 2, "two transitions", logs=[agent])
        before = [m for _, m in bus.messages("transition")]
        assert [(m.seq, m.source_seq) for m in before] == [(1, 1), (2, 2)]
        agent.proc.send_signal(signal.SIGKILL)
        assert agent.wait(HUNG) == -signal.SIGKILL
        wait_until(lambda: not bus.alive("sensor_agent"), "the killed agent's token to go")
        restarted = services("sensor_agent", *args, endpoint=zenoh_router)
        bus.wait_for("sensor_agent", restarted)
        replies = [decode(SensorState, r.ok.payload.to_bytes())
                   for r in bus.session.get(f"{bus.keys.state('n0')}?source=s0;after=0", timeout=HUNG) if r.ok]
    finally:
        recent.undeclare()
    assert [state.missed for state in replies] == [before], restarted.log
    assert [state.answers for state in replies] == [1]  # one reply to a query of n0's by source
    assert "restarted; resuming from its checkpoint" in restarted.log
    assert restarted.stop() == 0


def test_raw_samples_a_restarted_replay_sends_again_are_taken_once(tmp_path, zenoh_router, services, bus):
    """What a restarted replay sends again (marked RESENT) is handled by the sensor agent and
    recorded by the recorder only where it is newer than their last sample of that sensor: the
    ones the kill caught in the dead replay's send path. The others are dropped silently (they
    are no fault), and each says how many of each it saw."""
    out = tmp_path / "run.mcap"
    agent = services("sensor_agent", "--sensors", "n0,n1", "--net", NET, endpoint=zenoh_router)
    recorder = services("recorder", "--out", str(out), "--net", NET, endpoint=zenoh_router)
    bus.wait_for("sensor_agent", agent)
    bus.wait_for("recorder", recorder)
    bus.put(KEYS.raw("n0"), RawSample(t=1.0, sensor="n0", value=1))
    bus.tick(1.5, "sensor_agent", agent)
    bus.tick(1.5, "recorder", recorder)
    for sample in (RawSample(t=1.0, sensor="n0", value=1),  # had arrived
                   RawSample(t=2.0, sensor="n0", value=0), RawSample(t=2.0, sensor="n1", value=1)):  # had not
        bus.put(bus.keys.raw(sample.sensor), sample, RESENT)
    bus.tick(2.5, "sensor_agent", agent)
    bus.tick(2.5, "recorder", recorder)
    assert [(m.t, m.sensor, m.value) for _, m in bus.messages("transition")] == [
        (1.0, "n0", 1), (2.0, "n0", 0), (2.0, "n1", 1)]
    assert agent.stop() == 0 and recorder.stop() == 0
    assert "of the raw samples a restarted replay sent again, 2 were new and 1 already handled" in agent.log
    assert "1 raw samples a restarted replay sent again were already recorded; recorded once" in recorder.log
    for log in (agent.log, recorder.log):
        assert "bad payload" not in log, log
    raw = [(r.key.removeprefix(f"bintrack/{NET}/"), r.t) for r in open_recording(out).records() if "/raw/" in r.key]
    assert raw == [("raw/n0", 1.0), ("raw/n0", 2.0), ("raw/n1", 2.0)]


def record_dataset(dataset: Path, out: Path) -> Path:
    """A recording of ``dataset`` as a recorder would have made it: its raw samples, and a
    clock tick every second of event time."""
    data = open_dataset(dataset)
    keys = Keys(data.deployment.name)
    events = list(data.events())
    with RecordingWriter(out, data.deployment, keys.net) as writer:
        tick = math.floor(events[0].t) + 1.0
        for event in events:
            while tick <= event.t:
                writer.write(keys.clock(), tick, encode(Clock(t=tick)))
                tick += 1.0
            writer.write(keys.raw(event.sensor), event.t, encode_raw_sample(event.t, event.sensor, event.value))
        writer.write(keys.clock(), tick, encode(Clock(t=tick)))
    return out


@pytest.mark.parametrize("source", ["dataset", "recording"])
def test_a_restarted_replay_sends_the_samples_of_its_last_ticks_again_first(tmp_path, zenoh_router, services, source):
    """A replay SIGKILLed mid-run, restarted from its checkpoint: before its first tick it puts
    marked RESENT the raw samples of its last ticks (a kill may have caught them in its send
    path) and those after the tick it checkpointed (the killed one may have put them too),
    whether it plays a dataset or a recording."""
    dataset = write_foreign_dataset(tmp_path / "ds", nodes=400)
    played = dataset if source == "dataset" else record_dataset(dataset, tmp_path / "ds.mcap")
    state_dir = tmp_path / "state"
    state_dir.mkdir(mode=0o700)
    bus = FakeBus(zenoh_router, open_dataset(dataset).deployment, serve_deployment=False)
    lock, seen = threading.Lock(), []  # (kind, payload, marked RESENT) of raw samples and ticks, in arrival order

    def on_sample(sample: zenoh.Sample) -> None:
        kind = kind_of(str(sample.key_expr))
        if kind in ("raw", "clock"):
            with lock:
                seen.append((kind, sample.payload.to_bytes(),
                             sample.attachment is not None and is_resent(sample.attachment.to_bytes())))

    listener = bus.session.declare_subscriber(bus.keys.all(), on_sample)
    bus.play("sensor_agent")
    args = (str(played), "--speed", "0", "--clock-period", "1", "--max-ahead", "6", "--wait-for", "sensor_agent",
            "--id", "r0", "--state-dir", str(state_dir))
    try:
        replay = services("replay", *args, endpoint=zenoh_router)
        # once the first tick is out, the replay has seen the played agent (it waits for one):
        # the agent has handled everything up to 20 s, so the replay goes on to 26 s, then waits
        wait_until(lambda: any(kind == "clock" for kind, _, _ in seen), "the replay's first tick", logs=[replay])
        bus.put(bus.keys.progress("sensor_agent", "test"), Clock(t=20.0), control_attachment("sensor_agent", "test"))
        wait_until(lambda: any(float(ack) >= 20 for ack in re.findall(r"waiting for progress >= ([\d.]+)", replay.log)),
                   "the replay to wait for progress past 20 s", logs=[replay])
        replay.proc.send_signal(signal.SIGKILL)
        assert replay.wait(HUNG) == -signal.SIGKILL
        with lock:
            before = len(seen)
        first = [payload for kind, payload, _ in seen[:before] if kind == "raw"]
        wait_until(lambda: bus.keys.alive("replay", "r0") not in bus.alive("replay"), "the killed replay's token to go")
        restarted = services("replay", *args, endpoint=zenoh_router)
        wait_until(lambda: any(kind == "clock" for kind, _, _ in seen[before:]), "a tick of the restarted replay",
                   logs=[restarted])
        with lock:
            after = list(itertools.takewhile(lambda item: item[0] == "raw", seen[before:]))
    finally:
        listener.undeclare()
        bus.close()
    assert restarted.stop() == 0
    count = int(re.search(r"sent the (\d+) raw samples of its last \d+ ticks again", restarted.log).group(1))
    assert 0 < count <= len(after) < len(first)
    assert after == [("raw", payload, True) for payload in first[-len(after):]], restarted.log


def test_a_recorder_killed_after_the_last_tick_logs_its_loss_at_the_end_of_stream(tmp_path, zenoh_router,
                                                                                  services, bus):
    """What a killed recorder had not flushed is lost; the restarted one says so at the next
    clock tick, or at the end of stream when no tick follows (the kill came after the last)."""
    state_dir = tmp_path / "state"
    state_dir.mkdir(mode=0o700)
    out = tmp_path / "run.mcap"
    args = ("--out", str(out), "--id", "r0", "--state-dir", str(state_dir), "--net", NET)
    recorder = services("recorder", *args, endpoint=zenoh_router)
    bus.wait_for("recorder", recorder)
    bus.put(KEYS.raw("n0"), RawSample(t=1.0, sensor="n0", value=1))
    bus.tick(2.0, "recorder", recorder)  # the last tick; the recorder has not flushed it
    recorder.proc.send_signal(signal.SIGKILL)
    assert recorder.wait(HUNG) == -signal.SIGKILL
    wait_until(lambda: not bus.alive("recorder"), "the killed recorder's token to go")
    restarted = services("recorder", *args, endpoint=zenoh_router)
    bus.wait_for("recorder", restarted)
    bus.put(KEYS.eos(), EndOfStream(t=2.0))
    assert restarted.wait(HUNG) == 0, restarted.log
    assert "recorder: restarted; kept the 0 messages recorded before (up to t=0 s)" in restarted.log
    assert ("recording again from t=2 s; the raw samples, transitions and estimates published between t=0 s "
            "and then are missing") in restarted.log
    assert open_recording(out).complete


@pytest.fixture(scope="module")
def crossing(tmp_path_factory) -> Path:
    """A 5 s crossing of 300 disk sensors (about 90 transitions a pass), played in a loop."""
    return write_foreign_dataset(tmp_path_factory.mktemp("crossing") / "crossing", nodes=300, speed=32.0)


class Stack:
    """Two sensor agents and two peer agents, each on one half of the sensors, a base station,
    and replay at real time in a loop; a test session that watches the whole network."""

    def __init__(self, dataset: Path, endpoint: str, services):
        self.deployment = open_dataset(dataset).deployment
        ids = [s.id for s in self.deployment.sensors]
        self.halves = {"a": ids[0::2], "b": ids[1::2]}
        self.endpoint = endpoint
        self.services = services
        self.net = ("--net", self.deployment.name)
        self.bus = FakeBus(endpoint, self.deployment, serve_deployment=False)  # replay serves it
        self.sensor_agents = {half: self.sensor_agent(half) for half in self.halves}
        self.peer_agents = {half: self.peer_agent(half) for half in self.halves}
        self.basestation = services("basestation", "--tracker", TRACKER, *self.net, endpoint=endpoint)
        self.replay = services("replay", str(dataset), "--speed", "1", "--loop",
                               "--wait-for", "sensor_agent,peer_agent,basestation", endpoint=endpoint)

    def sensor_agent(self, half: str):
        # an explicit id: restarted, it is the same instance id again, as a container restarted
        # under its hostname and pid 1 would be (so source_seq restarts at 1 too)
        return self.services("sensor_agent", "--sensors", ",".join(self.halves[half]), "--id", f"sensors-{half}",
                             *self.net, endpoint=self.endpoint)

    def peer_agent(self, half: str):
        return self.services("peer_agent", "--tracker", TRACKER, "--sensors", ",".join(self.halves[half]), *self.net,
                             endpoint=self.endpoint)

    @property
    def procs(self) -> list:
        return [*self.sensor_agents.values(), *self.peer_agents.values(), self.basestation, self.replay]

    def last_tick(self) -> float:
        ticks = self.bus.messages("clock")
        return ticks[-1][1].t if ticks else -math.inf

    def wait(self, condition, what: str, timeout: float = HUNG) -> None:
        wait_until(condition, what, timeout, self.procs)

    def arrived(self, kind: str, half: str, start: int, after: float = -math.inf) -> list:
        """Messages of ``kind`` about the sensors of ``half`` seen since index ``start``, with t > ``after``."""
        nodes = set(self.halves[half])
        return [m for key, m in self.bus.messages(kind, start) if parse_key(key).sensor in nodes and m.t > after]

    def kill(self, proc) -> tuple[int, float]:
        """SIGKILL ``proc``; (index into what the bus saw, last tick) once it is dead and gone."""
        before = len(self.bus.alive(proc.name))
        proc.proc.send_signal(signal.SIGKILL)
        assert proc.wait(HUNG) == -signal.SIGKILL
        self.wait(lambda: len(self.bus.alive(proc.name)) == before - 1, f"the token of the killed {proc.name} to go")
        return self.bus.mark(), self.last_tick()

    def stop_all(self) -> dict[str, int]:
        """SIGTERM everything still running; the exit status of each."""
        codes = {p.log_path.name: p.stop() for p in self.procs if p.proc.poll() is None}
        self.bus.close()
        return codes

    def check_exits(self, codes: dict[str, int]) -> None:
        """Every service exited 0 at SIGTERM (replay included: it never hung)."""
        assert len(codes) == 6 and set(codes.values()) == {0}, (codes, [p.log[-2000:] for p in self.procs])


def test_killed_peer_agent_others_go_on_and_restart_publishes_again(crossing, zenoh_router, services):
    stack = Stack(crossing, zenoh_router, services)
    try:
        stack.wait(lambda: stack.last_tick() >= 2.0 and stack.arrived("estimate", "a", 0), "the stack to run")
        start, t_kill = stack.kill(stack.peer_agents["a"])
        # the other processes keep running and publishing: replay's ticks go on (it does not
        # wait for the dead agent), and the surviving agent's nodes keep getting estimates
        stack.wait(lambda: stack.last_tick() >= t_kill + 2.0, "clock ticks after the kill")
        stack.wait(lambda: stack.arrived("estimate", "b", start, after=t_kill), "estimates of the surviving agent")
        assert stack.arrived("estimate", "a", start) == []  # nobody publishes the dead agent's nodes
        assert all(p.proc.poll() is None for p in stack.procs if p is not stack.peer_agents["a"])
        stack.peer_agents["a"] = stack.peer_agent("a")  # the same arguments
        stack.bus.wait_for("peer_agent", stack.peer_agents["a"])
        restarted, t_restart = stack.bus.mark(), stack.last_tick()
        stack.wait(lambda: stack.arrived("estimate", "a", restarted, after=t_restart),
                   "estimates from the restarted peer agent")
        stack.wait(lambda: stack.arrived("estimate", "b", restarted, after=t_restart), "estimates of the other agent")
        stack.wait(lambda: [m for _, m in stack.bus.messages("tracks", restarted) if m.t > t_restart],
                   "tracks from the base station after the restart")
    finally:
        codes = stack.stop_all()
    stack.check_exits(codes)


def test_killed_sensor_agent_others_go_on_and_restart_publishes_again(crossing, zenoh_router, services):
    stack = Stack(crossing, zenoh_router, services)
    try:
        stack.wait(lambda: stack.last_tick() >= 2.0 and stack.arrived("transition", "a", 0), "the stack to run")
        start, t_kill = stack.kill(stack.sensor_agents["a"])
        heard: dict[str, int] = {}  # sensor → its last seq before the kill
        for m in stack.arrived("transition", "a", 0):
            heard[m.sensor] = max(m.seq, heard.get(m.sensor, 0))
        stack.wait(lambda: stack.last_tick() >= t_kill + 2.0, "clock ticks after the kill")
        stack.wait(lambda: stack.arrived("transition", "b", start, after=t_kill),
                   "transitions of the surviving sensor agent")
        stack.wait(lambda: stack.arrived("estimate", "b", start, after=t_kill), "estimates of its sensors")
        assert stack.arrived("transition", "a", start) == []
        assert all(p.proc.poll() is None for p in stack.procs if p is not stack.sensor_agents["a"])
        stack.sensor_agents["a"] = stack.sensor_agent("a")
        stack.bus.wait_for("sensor_agent", stack.sensor_agents["a"])
        restarted, t_restart = stack.bus.mark(), stack.last_tick()
        # The restarted agent numbers its sensors' transitions from 1 again; the peer agents
        # take them, also for sensors they heard of before the kill (in the next pass): a
        # sensor entered again gets its estimate at that very transition.
        def reentered() -> list[Transition]:
            return [m for m in stack.arrived("transition", "a", restarted, after=t_restart)
                    if m.sensor in heard and m.value == 1]

        stack.wait(reentered, "a transition from the restarted sensor agent of a sensor heard before")
        again = reentered()[0]
        assert again.source == "sensors-a" and again.seq <= heard[again.sensor]  # its numbering restarted
        stack.wait(lambda: [e for e in stack.arrived("estimate", "a", restarted) if (e.node, e.t) == (again.sensor, again.t)],
                   f"the estimate of {again.sensor} at t={again.t}")
    finally:
        codes = stack.stop_all()
    stack.check_exits(codes)
    for proc in stack.peer_agents.values():
        assert "sensors-a counts its transitions from 1 again (a sensor agent restarted)" in proc.log, proc.log
    for proc in stack.procs:
        assert "duplicate" not in proc.log, proc.log


# --------------------------------------------------------------------------- no router yet


def test_service_started_before_the_router_waits_then_comes_up(tmp_path, services):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    agent = services("sensor_agent", "--net", NET, "--wait", "60", endpoint=endpoint)
    wait_until(lambda: "waiting for the Zenoh router" in agent.log, "the waiting line", logs=[agent])
    assert agent.proc.poll() is None
    waiting = [line for line in agent.log.splitlines() if "waiting for the Zenoh router" in line]
    assert waiting[0].split(" ", 1)[1].startswith("sensor_agent: waiting for the Zenoh router (")
    assert waiting[0].endswith("); retrying")
    router = zenoh.open(router_config([endpoint]))
    try:
        bus = FakeBus(endpoint, DEPLOYMENT)
        try:
            bus.wait_for("sensor_agent", agent)
            assert "ready on bintrack/faults" in agent.log
        finally:
            bus.close()
        assert agent.stop() == 0, agent.log
    finally:
        router.close()
    log = agent.log
    assert "Traceback" not in log, log
    assert all(re.match(r"\d\d:\d\d:\d\d ", line) for line in log.splitlines()), log  # log lines only


def test_service_without_a_router_gives_up_after_wait_with_one_line(services):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    agent = services("peer_agent", "--tracker", TRACKER, "--net", NET, "--wait", "1", endpoint=endpoint)
    assert agent.wait(HUNG) == 1
    lines = agent.log.strip().splitlines()
    assert "Traceback" not in agent.log, agent.log
    assert re.fullmatch(r"\d\d:\d\d:\d\d peer_agent: no Zenoh router reachable after \d+ attempts: .+", lines[-1]), lines
    assert all(re.match(r"\d\d:\d\d:\d\d peer_agent: waiting for the Zenoh router \(.+\); retrying$", line)
               for line in lines[:-1]), lines
