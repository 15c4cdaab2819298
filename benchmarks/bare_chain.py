"""The least a Python pipeline of the bus's shape can cost: the ceiling for replay → sensor
agent → recorder in this Python, one Zenoh message per transition.

Three processes, each one client session on the router at ENDPOINT (loopback):

* ``source`` puts N pre-encoded msgpack raw samples (``{version, t, sensor, value}``, sensor ids
  from a pool of 1 444 like a 38 × 38 grid), each on its sensor's key, then an end marker;
* ``relay`` unpacks each, adds ``previous`` and ``seq`` and puts it on the sensor's transition key
  (what a sensor agent does, without validation, detection, history or flow control);
* ``sink`` hears both (what a recorder hears) and keeps each payload in memory (no file);
  it prints ``RATE <transitions/s>`` from its first sample to the relay's end marker.

Reliable, congestion control BLOCK, remote samples only; a liveliness token per process says
it is subscribed. ``benchmarks/bus.py`` runs it beside the pipeline, in the same run.

Run: ``.venv/bin/python benchmarks/bare_chain.py ROLE ENDPOINT N`` (ROLE = source, relay, sink).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import msgpack
import zenoh

from bintrack.live.session_options import client_config

PREFIX = "bench/bare"
SENSORS = [f"n{i}" for i in range(1444)]
TIMEOUT = 300.0  # s: only a hung run fails


def alive(role: str) -> str:
    return f"{PREFIX}/alive/{role}"


def source(session: zenoh.Session, n: int) -> None:
    while not all(any(r.ok is not None for r in session.liveliness().get(alive(role), timeout=1.0))
                  for role in ("relay", "sink")):
        time.sleep(0.05)
    keys = [f"{PREFIX}/raw/{s}" for s in SENSORS]
    samples = [(keys[i % len(keys)], msgpack.packb({"version": 1, "t": i * 0.01, "sensor": SENSORS[i % len(SENSORS)],
                                                    "value": (i // len(SENSORS)) % 2}))
               for i in range(n)]
    block = zenoh.CongestionControl.BLOCK
    for key, payload in samples:
        session.put(key, payload, congestion_control=block)
    session.put(f"{PREFIX}/raw/end", b"", congestion_control=block)


def relay(session: zenoh.Session) -> None:
    done = threading.Event()
    seq: dict[str, int] = {}
    keys = {s: f"{PREFIX}/transition/{s}" for s in SENSORS}
    block = zenoh.CongestionControl.BLOCK

    def on_sample(sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        if not payload:
            session.put(f"{PREFIX}/transition/end", b"", congestion_control=block)
            done.set()
            return
        message = msgpack.unpackb(payload)
        sensor = message["sensor"]
        seq[sensor] = seq.get(sensor, 0) + 1
        message["previous"], message["seq"] = 1 - message["value"], seq[sensor]
        session.put(keys[sensor], msgpack.packb(message), congestion_control=block)

    declared = (session.declare_subscriber(f"{PREFIX}/raw/*", on_sample, allowed_origin=zenoh.Locality.REMOTE),
                session.liveliness().declare_token(alive("relay")))
    done.wait(TIMEOUT)
    for entity in declared:
        entity.undeclare()


def sink(session: zenoh.Session) -> None:
    done = threading.Event()
    kept: list[bytes] = []
    first: list[float] = []
    end = f"{PREFIX}/transition/end"

    def on_sample(sample: zenoh.Sample) -> None:
        if not first:
            first.append(time.perf_counter())
        if str(sample.key_expr) == end:
            first.append(time.perf_counter())
            done.set()
            return
        kept.append(sample.payload.to_bytes())

    declared = (session.declare_subscriber(f"{PREFIX}/*/*", on_sample, allowed_origin=zenoh.Locality.REMOTE),
                session.liveliness().declare_token(alive("sink")))
    if not done.wait(TIMEOUT):
        raise SystemExit("sink: no end marker")
    for entity in declared:
        entity.undeclare()
    transitions = sum(1 for payload in kept if b"previous" in payload)
    print(f"RATE {transitions / (first[1] - first[0]):.1f} {transitions} {len(kept)}", flush=True)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("role", choices=("source", "relay", "sink"))
    parser.add_argument("endpoint", help="the router's endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("n", type=int, nargs="?", help="for source: how many samples to put")
    args = parser.parse_args(argv)
    if args.role == "source" and args.n is None:
        parser.error("source needs N, the number of samples to put")
    session = zenoh.open(client_config([args.endpoint]))
    try:
        if args.role == "source":
            source(session, args.n)
        elif args.role == "relay":
            relay(session)
        else:
            sink(session)
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
