"""``bintrack up --foxglove``: a client speaking Foxglove's WebSocket protocol sees the stack live.

The client is the ``websockets`` package offering Foxglove's WebSocket subprotocols (what
Foxglove itself speaks): it reads the server's channel advertisements, subscribes to ``/scene``
and to the raw ``tracks`` key, and decodes the binary message frames (opcode 1, subscription
id, log time, payload). Each SceneUpdate's ``tracks`` entity must put a sphere where a TrackSet
the base station published on the bus put that track, at the same event time; the raw channel
must carry that TrackSet as JSON. The delay from the bus (a Zenoh subscriber in this process)
to the client is printed (p50, p95); it is not asserted (no wall-clock bounds in tests).
"""

from __future__ import annotations

import asyncio
import json
import signal
import struct
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from bintrack.live.session_options import client_config
from bintrack.bus_payloads import TrackSet
from bintrack.message_codec import decode
from support import HUNG, REPO, free_port

DARPA3 = REPO / "datasets" / "darpa-grid-3"
# Foxglove's WebSocket protocol: foxglove-sdk 0.30 names it foxglove.sdk.v1 (the same frames as
# foxglove.websocket.v1, which earlier servers answer to); a client offers both, as Foxglove does
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


class Stack:
    """`bintrack up … --foxglove 0`; ``url`` once the bridge says where it serves."""

    def __init__(self, *args: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", *args], cwd=REPO, text=True,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self.lines: list[str] = []
        self.found = threading.Event()
        self.url: str | None = None
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        for line in self.proc.stderr:
            self.lines.append(line.rstrip())
            if "Foxglove on ws://" in line and self.url is None:
                self.url = line.split("Foxglove on ", 1)[1].split()[0]
                self.found.set()
        self.found.set()

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        return self.proc.wait(timeout=HUNG)


async def watch(url: str, done: threading.Event) -> tuple[dict[int, float], dict[int, dict], dict[int, dict]]:
    """Subscribe to /scene and the tracks key until ``done``; (arrival time per scan time ns,
    the tracks entity per scan time ns, the raw TrackSet JSON per scan time ns)."""
    import websockets

    arrivals: dict[int, float] = {}
    scenes: dict[int, dict] = {}
    raw: dict[int, dict] = {}
    subscribed: dict[int, str] = {}
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        next_id = 1
        while not done.is_set():
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                continue
            except websockets.ConnectionClosed:   # the stack ended: its bridge stopped serving
                break
            now = time.monotonic()
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") == "advertise":
                    wanted = [c for c in op["channels"]
                              if c["topic"] in ("/scene", "bintrack/darpa-grid/tracks")]
                    for channel in wanted:
                        assert channel["encoding"] == "json"
                        subscribed[next_id] = channel["topic"]
                        await ws.send(json.dumps({"op": "subscribe",
                                                  "subscriptions": [{"id": next_id, "channelId": channel["id"]}]}))
                        next_id += 1
                continue
            opcode, subscription, _log_time = struct.unpack_from("<BIQ", frame)
            assert opcode == MESSAGE_DATA
            payload = json.loads(frame[13:])
            if subscribed[subscription] == "/scene":
                for entity in payload["entities"]:
                    if entity["id"] == "tracks":
                        stamp = entity["timestamp"]["sec"] * 1_000_000_000 + entity["timestamp"]["nsec"]
                        scenes[stamp] = entity
                        arrivals.setdefault(stamp, now)
            else:
                raw[_ns(payload["t"])] = payload
    return arrivals, scenes, raw


@pytest.mark.slow
def test_a_foxglove_client_sees_the_tracks_where_the_bus_has_them(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stack = Stack(str(DARPA3), "--tracker", "mcmcda", "--speed", "2", "--exit-at-end", "--no-map",
                  "--listen", endpoint, "--foxglove", "0", "--record", str(tmp_path / "run.mcap"))
    bus: dict[int, tuple[float, TrackSet]] = {}
    session = None
    try:
        assert stack.found.wait(HUNG) and stack.url, "\n".join(stack.lines[-30:])
        session = zenoh.open(client_config([endpoint]))

        def on_tracks(sample: zenoh.Sample) -> None:
            message = decode(TrackSet, sample.payload.to_bytes())
            bus.setdefault(_ns(message.t), (time.monotonic(), message))

        subscriber = session.declare_subscriber("bintrack/darpa-grid/tracks", on_tracks)
        ended = threading.Event()
        threading.Thread(target=lambda: (stack.proc.wait(), ended.set()), daemon=True).start()
        arrivals, scenes, raw = asyncio.run(watch(stack.url, ended))
        subscriber.undeclare()
    finally:
        if session is not None:
            session.close()
        code = stack.stop()
    assert code == 0, "\n".join(stack.lines[-30:])

    common = sorted(set(bus) & set(scenes))
    assert len(common) >= 20, (len(bus), len(scenes))
    for stamp in common:
        _, scan = bus[stamp]
        spheres = sorted((s["pose"]["position"]["x"], s["pose"]["position"]["y"]) for s in scenes[stamp]["spheres"])
        assert spheres == sorted((k.x, k.y) for k in scan.tracks)   # JSON carries floats exactly
        texts = sorted(int(text["text"]) for text in scenes[stamp]["texts"])
        assert texts == sorted(k.track for k in scan.tracks)
    with_tracks = [s for s in common if bus[s][1].tracks]
    assert with_tracks, "no scan with a track"
    for stamp in set(raw) & set(bus):
        assert TrackSet.model_validate(raw[stamp]) == bus[stamp][1]
    # The recorder wrote Foxglove's copy beside the recording: the same /scene schema and tracks.
    from mcap.reader import make_reader

    with open(tmp_path / "run.foxglove.mcap", "rb") as handle:
        recorded = {}
        for schema, channel, message in make_reader(handle).iter_messages(topics=["/scene"]):
            assert schema.name == "foxglove.SceneUpdate" and channel.message_encoding == "json"
            for entity in json.loads(message.data)["entities"]:
                if entity["id"] == "tracks":
                    recorded[entity["timestamp"]["sec"] * 1_000_000_000 + entity["timestamp"]["nsec"]] = entity
    assert set(recorded) >= set(common) and all(recorded[s] == scenes[s] for s in common)
    delays = sorted(arrivals[s] - bus[s][0] for s in common)
    p50, p95 = delays[len(delays) // 2], delays[int(0.95 * (len(delays) - 1))]
    print(f"\nbus -> Foxglove client over {len(delays)} scans: p50 {1000 * p50:.1f} ms, p95 {1000 * p95:.1f} ms "
          f"(goal: p50 within 1000 ms)")
