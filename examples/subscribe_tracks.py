"""Print the live tracks of a bintrack network, using only `zenoh` and `msgpack`.

This is how a program outside bintrack reads its results: subscribe to
``bintrack/<net>/tracks`` and decode each payload, a msgpack map of a TrackSet::

    {"version": 1, "t": <event time, s>, "tracker": <name>,
     "tracks": [{"track": <id>, "x": ..., "y": ..., "vx": ... or None, "vy": ... or None}, ...]}

(positions in deployment units, velocities in units/s; ``bintrack schema`` prints the JSON
Schema of every message). One line is printed per track::

    t=12.500 track=0 x=10.00 y=20.00 vx=0.50 vy=-0.10

Run:  pip install eclipse-zenoh msgpack
      python subscribe_tracks.py [-e tcp/127.0.0.1:7447] [--net NAME]

Without --net it takes the one network alive on the bus (its services' liveliness tokens).
Stop with Ctrl-C.
"""

import argparse
import json
import signal
import sys

import msgpack
import zenoh


def number(value):
    return "-" if value is None else f"{value:.2f}"


def track_lines(payload):
    """The printed lines of one TrackSet payload; raises ValueError if it is not one."""
    try:
        scan = msgpack.unpackb(payload, raw=False)
        t, tracks = float(scan["t"]), scan["tracks"]
        return [f"t={t:.3f} track={k['track']} x={number(k['x'])} y={number(k['y'])} "
                f"vx={number(k.get('vx'))} vy={number(k.get('vy'))}" for k in tracks]
    except Exception as exc:  # msgpack errors, missing fields, wrong types
        raise ValueError(f"not a TrackSet: {type(exc).__name__}: {exc}") from None


def the_network(session):
    """The one network whose services hold liveliness tokens bintrack/<net>/alive/<service>/<id>."""
    nets = sorted({str(reply.ok.key_expr).split("/")[1]
                   for reply in session.liveliness().get("bintrack/*/alive/**", timeout=2.0) if reply.ok is not None})
    if len(nets) != 1:
        session.close()
        sys.exit("subscribe_tracks: " + (f"networks alive: {', '.join(nets)}; choose one with --net" if nets
                                         else "no bintrack network is alive on the bus; give --net"))
    return nets[0]


def main():
    parser = argparse.ArgumentParser(description="Print the live tracks of a bintrack network.")
    parser.add_argument("-e", "--connect", action="append", metavar="ENDPOINT",
                        help="Zenoh router to connect to, repeatable (default: tcp/127.0.0.1:7447)")
    parser.add_argument("--net", help="network name, the <net> of bintrack/<net>/tracks "
                        "(default: the one network alive on the bus)")
    args = parser.parse_args()

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(args.connect or ["tcp/127.0.0.1:7447"]))
    config.insert_json5("scouting/multicast/enabled", "false")

    # Turn SIGTERM into the same clean exit as Ctrl-C.
    signal.signal(signal.SIGTERM, signal.getsignal(signal.SIGINT))

    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        sys.exit(f"subscribe_tracks: cannot reach {args.connect or 'tcp/127.0.0.1:7447'}: {exc}")
    net = args.net or the_network(session)
    key = f"bintrack/{net}/tracks"
    # A ring channel keeps the latest 256 samples and drops older ones if we fall behind,
    # so a slow terminal never blocks Zenoh.
    subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(256))
    try:
        print(f"subscribed to {key} (Ctrl-C to stop)", file=sys.stderr, flush=True)
        for sample in subscriber.handler:
            try:
                lines = track_lines(sample.payload.to_bytes())
            except ValueError as exc:
                print(f"skipped a payload on {sample.key_expr}: {exc}", file=sys.stderr, flush=True)
                continue
            for line in lines:
                print(line, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        subscriber.undeclare()
        session.close()


if __name__ == "__main__":
    main()
