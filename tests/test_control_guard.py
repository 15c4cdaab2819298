"""Control-plane integrity without access control: forged clock ticks and ends of stream from
a client that holds no replay token are rejected, logged with the sender, and the run gives
the offline rows."""

from __future__ import annotations

import subprocess
import sys
import threading

import msgpack
import zenoh

from bintrack.formats import TruthRow, open_dataset, read_tracks, write_dataset
from bintrack.keys import Keys
from bintrack.live.session_options import client_config, open_session
from bintrack.live.control_guard import control_attachment
from bintrack.bus_payloads import Clock, EndOfStream
from bintrack.deployment_model import Deployment
from bintrack.message_codec import decode, encode

from support import DATASETS, HUNG, REPO, bintrack, free_port, wait_until

DARPA3 = DATASETS / "darpa-grid-3"


def test_forged_clock_and_end_of_stream_do_not_change_the_run(tmp_path):
    ds = open_dataset(DARPA3)
    folder = write_dataset(tmp_path / "slice", ds.deployment, [e for e in ds.events() if 10.0 <= e.t < 45.0],
                           [TruthRow(*r) for r in ds.truth() if 10.0 <= r.t < 45.0])
    keys = Keys(ds.deployment.name)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    recording = tmp_path / "run.mcap"
    up = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", str(folder), "--speed", "0", "--tracker",
                           "equal-weight", "--record", str(recording), "--exit-at-end", "--no-view", "--listen", endpoint],
                          stderr=subprocess.PIPE, text=True, cwd=REPO)
    log: list[str] = []
    reader = threading.Thread(target=lambda: log.extend(up.stderr), daemon=True)
    reader.start()
    first_tick = threading.Event()
    forger = open_session(client_config([endpoint]), wait=HUNG)
    try:
        subscriber = forger.declare_subscriber(keys.clock(), lambda s: first_tick.set())
        assert first_tick.wait(HUNG), "".join(log)
        # the two forgeries: an anonymous clock far ahead, an end of stream mid-run
        # from a sender that claims to be a replay but holds no token
        forger.put(keys.clock(), encode(Clock(t=1e6)))
        forger.put(keys.eos(), encode(EndOfStream(t=30.0)), attachment=control_attachment("replay", "intruder"))
        assert up.wait(HUNG) == 0, "".join(log)
        subscriber.undeclare()
    finally:
        forger.close()
        if up.poll() is None:
            up.kill()
        reader.join(HUNG)
    text = "".join(log)
    assert "forged control: clock from an anonymous sender" in text, text
    assert "forged control: eos from replay/intruder, which holds no" in text, text
    for service in ("sensor_agent", "peer_agent", "basestation", "recorder"):
        assert f"{service}: dropped a bad payload from bintrack/{keys.net}/control/eos from replay/intruder" in text
    exported, offline = tmp_path / "live.csv", tmp_path / "offline.csv"
    assert bintrack("export", str(recording), "--what", "tracks", "--out", str(exported)).returncode == 0
    assert bintrack("track", str(folder), "--tracker", "equal-weight", "--out", str(offline)).returncode == 0
    expected = read_tracks(offline)
    assert len(expected) > 20
    assert read_tracks(exported) == expected


def test_a_replay_clock_that_jumps_too_far_is_rejected(zenoh_router, services):
    """A sender holding a replay token (claimed step 0.5 s) moves the clock by one step, then
    jumps 1000 s: the sensor agent acknowledges the first tick and rejects the jump."""
    keys = Keys("tiny")
    deployment = Deployment.model_validate({
        "name": "tiny", "units": "m", "region": {"xmin": 0, "ymin": 0, "xmax": 10, "ymax": 10},
        "sensors": [{"id": "n0", "kind": "disk", "x": 1.0, "y": 1.0, "range": 2.0}]})
    session = zenoh.open(client_config([zenoh_router]))
    progress: list[float] = []
    got = threading.Condition()

    def on_progress(sample: zenoh.Sample) -> None:
        with got:
            progress.append(decode(Clock, sample.payload.to_bytes()).t)
            got.notify_all()

    entities = [session.declare_queryable(keys.deployment(), lambda q: q.reply(keys.deployment(), encode(deployment))),
                session.declare_subscriber(keys.progress(), on_progress),
                session.liveliness().declare_token(keys.alive("replay", "t1"))]
    agent = services("sensor_agent", "--net", "tiny", endpoint=zenoh_router)
    try:
        wait_until(lambda: [r for r in session.liveliness().get(keys.alive("sensor_agent"), timeout=HUNG) if r.ok],
                   "the sensor agent's token", logs=[agent], interval=0.1)
        with got:
            attachment = control_attachment("replay", "t1", step=0.5)
            for t in (0.0, 0.5, 1000.0, 1.0):
                session.put(keys.clock(), encode(Clock(t=t)), attachment=attachment)
            assert got.wait_for(lambda: 1.0 in progress, HUNG), agent.log
    finally:
        for entity in entities:
            entity.undeclare()
        session.close()
        agent.stop()
    # progress reports may join ticks (every 8 ticks or 5 ms): never the jump, and 1.0 last
    assert progress[0] == 0.0 and progress[-1] == 1.0 and set(progress) <= {0.0, 0.5, 1.0}, progress
    assert "clock jump: t=1000 s after t=0.5 s, more than 4 steps of 0.5 s" in agent.log
    assert msgpack.unpackb(control_attachment("replay", "t1", 0.5)) == {"sender": "replay/t1", "step": 0.5}
