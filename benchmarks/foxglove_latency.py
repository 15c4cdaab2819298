"""Latency of the live view in Foxglove: from a track scan on the bus to a Foxglove client.

    python benchmarks/foxglove_latency.py [--speed 1] [--dataset datasets/darpa-grid-3]

Runs ``bintrack up DATASET --tracker mcmcda --foxglove 0 --no-map --exit-at-end`` and, in this
process, a plain Zenoh subscriber on ``bintrack/<net>/tracks`` (the bus hop: the baseline) and a
client of Foxglove's WebSocket protocol (``websockets``, subprotocol foxglove.sdk.v1 /
foxglove.websocket.v1) subscribed to ``/scene``. Each scan is stamped on arrival at both, on
one clock; prints p50, p95 and max of the difference (what the bridge adds to the bus hop)
beside the goal of issue 40 (p50 within 1 s).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import subprocess
import sys
import threading
import time

import websockets
import zenoh

from bintrack.live.session_options import client_config
from bintrack.bus_payloads import TrackSet
from bintrack.message_codec import decode

from bench_support import REPO, free_port
GOAL_MS = 1000.0
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def ns(t: float) -> int:
    return max(0, round(t * 1e9))


async def foxglove_arrivals(url: str, done: threading.Event) -> dict[int, float]:
    arrivals: dict[int, float] = {}
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        while not done.is_set():
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                continue
            except websockets.ConnectionClosed:
                break
            now = time.monotonic()
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") == "advertise":
                    for channel in op["channels"]:
                        if channel["topic"] == "/scene":
                            await ws.send(json.dumps({"op": "subscribe",
                                                      "subscriptions": [{"id": 1, "channelId": channel["id"]}]}))
                continue
            for entity in json.loads(frame[13:])["entities"]:
                if entity["id"] == "tracks":
                    arrivals.setdefault(entity["timestamp"]["sec"] * 1_000_000_000 + entity["timestamp"]["nsec"], now)
    return arrivals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", default="1", help="replay speed (default: %(default)s, real time)")
    parser.add_argument("--dataset", default=str(REPO / "datasets" / "darpa-grid-3"))
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", args.dataset, "--tracker", "mcmcda",
                           "--speed", args.speed, "--exit-at-end", "--no-map", "--listen", endpoint,
                           "--foxglove", "0"], stderr=subprocess.PIPE, text=True, cwd=REPO)
    url = None
    for line in up.stderr:
        if "Foxglove on ws://" in line:
            url = line.split("Foxglove on ", 1)[1].split()[0]
            break
    if url is None:
        sys.exit("the stack ended before its Foxglove bridge served")
    threading.Thread(target=lambda: [None for _ in up.stderr], daemon=True).start()
    bus: dict[int, float] = {}
    session = zenoh.open(client_config([endpoint]))

    def on_tracks(sample: zenoh.Sample) -> None:
        bus.setdefault(ns(decode(TrackSet, sample.payload.to_bytes()).t), time.monotonic())

    subscriber = session.declare_subscriber("bintrack/darpa-grid/tracks", on_tracks)
    ended = threading.Event()
    threading.Thread(target=lambda: (up.wait(), ended.set()), daemon=True).start()
    try:
        arrivals = asyncio.run(foxglove_arrivals(url, ended))
    finally:
        subscriber.undeclare()
        session.close()
        if up.poll() is None:
            up.send_signal(signal.SIGINT)
        up.wait()
    delays = sorted(1000 * (arrivals[t] - bus[t]) for t in set(arrivals) & set(bus))
    if not delays:
        sys.exit("no scan reached both the bus subscriber and the Foxglove client")
    p50, p95 = delays[len(delays) // 2], delays[int(0.95 * (len(delays) - 1))]
    print(f"{len(delays)} scans at --speed {args.speed}: bus -> Foxglove client, beyond the bus hop")
    print(f"{'':24}{'p50 ms':>10}{'p95 ms':>10}{'max ms':>10}")
    print(f"{'Foxglove bridge':24}{p50:10.1f}{p95:10.1f}{delays[-1]:10.1f}")
    print(f"{'goal (issue 40), p50':24}{GOAL_MS:10.1f}")
    print(f"p50 is {p50 / GOAL_MS:.4f} of the goal")


if __name__ == "__main__":
    main()
