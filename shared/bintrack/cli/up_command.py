"""``bintrack up [DIR] [--tracker NAME] [--speed X] [--record FILE] [--exit-at-end] [--no-view]``.

The whole stack on this machine without Docker: a Zenoh router in this process on loopback,
and every service as a subprocess with the commands docker-compose uses
(:mod:`bintrack.live.stack`), the map (``bintrack view``) among them unless ``--no-view``.
Shows live progress; stops everything on Ctrl-C or, with
``--exit-at-end``, once the replay's end has been processed by every service.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import zenoh

from bintrack.argtypes import positive_float
from bintrack.live.bus import DEFAULT_ENDPOINT, router_config
from bintrack.errors import CommandError
from bintrack.formats import open_dataset
from bintrack.keys import Keys, parse_key
from bintrack.messages import Clock, MessageError, decode
from bintrack.live.stack import stack_commands
from bintrack.live.secure_profile import secure_up
from bintrack.trackers.tracker_arguments import add_tracker_arguments, tracker_arguments, tracker_options
from bintrack.trackers import TRACKER_NAMES, check_options as make_tracker_check
from bintrack.view.map_server import page_url

SHOWN = (("raw", "events"), ("transition", "transitions"), ("estimate", "estimates"), ("tracks", "tracks"))
STOP_TIMEOUT = 15.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", nargs="?", metavar="DIR", help="dataset folder or recording (.mcap) to replay")
    parser.add_argument("--tracker", choices=TRACKER_NAMES, default="equal-weight", help="tracker (default: %(default)s)")
    add_tracker_arguments(parser)
    parser.add_argument("--speed", type=float, default=1.0,
                        help="replay speed: 1 real time, 0 as fast as flow control allows (default: %(default)s)")
    parser.add_argument("--loop", action="store_true", help="replay in a loop")
    parser.add_argument("--record", metavar="FILE.mcap", help="record everything into this file")
    parser.add_argument("--exit-at-end", action="store_true", help="stop once the replay's end has been processed")
    parser.add_argument("--listen", default=DEFAULT_ENDPOINT, metavar="ENDPOINT",
                        help="where the embedded router listens (default: %(default)s)")
    parser.add_argument("--net", help="network name (default: the dataset's deployment name, else 'default')")
    parser.add_argument("--no-view", dest="view", action="store_false",
                        help="do not start the map (the view service)")
    parser.add_argument("--view-port", type=int, default=8080, metavar="PORT",
                        help="HTTP port of the map (default: %(default)s)")
    parser.add_argument("--view-bind", default="127.0.0.1", metavar="ADDRESS",
                        help="address the map is served on (default: %(default)s, this machine only)")
    parser.add_argument("--secure", action="store_true",
                        help="mutual TLS and per-role access control (deploy/secure/); --listen must be a tls/ endpoint")
    parser.add_argument("--certs", default="certs", metavar="DIR",
                        help="with --secure: the certificates of `bintrack certs --out DIR` (default: %(default)s)")
    parser.add_argument("--progress-interval", type=positive_float, default=1.0, metavar="S",
                        help="seconds between progress lines (default: %(default)s)")


@dataclass
class Monitor:
    """Counts what crosses the bus (from Zenoh callbacks: counters only, no Zenoh calls)."""

    keys: Keys
    counts: Counter = field(default_factory=Counter)
    event_time: float | None = None
    done: set[str] = field(default_factory=set)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_sample(self, sample: zenoh.Sample) -> None:
        try:
            parsed = parse_key(str(sample.key_expr))
        except ValueError:
            return
        with self.lock:
            self.counts[parsed.kind] += 1
            if parsed.kind == "done":
                self.done.add(parsed.service)
            elif parsed.kind == "clock":
                try:
                    self.event_time = decode(Clock, sample.payload.to_bytes()).t
                except MessageError:
                    pass

    def snapshot(self) -> tuple[Counter, float | None, set[str]]:
        with self.lock:
            return Counter(self.counts), self.event_time, set(self.done)


def _progress_line(now: Counter, before: Counter, dt: float, event_time: float | None) -> str:
    parts = [f"t={event_time:9.2f} s" if event_time is not None else "t=        - s"]
    for kind, label in SHOWN:
        rate = (now[kind] - before[kind]) / dt if dt > 0 else 0.0
        parts.append(f"{label} {now[kind]} ({rate:.0f}/s)")
    return "up: " + " | ".join(parts)


def _source_net(source: str | None) -> str | None:
    if source is None:
        return None
    path = Path(source)
    if path.suffix == ".mcap":
        from bintrack.live.recording import open_recording

        return open_recording(path).net
    return open_dataset(path).deployment.name


def _stop(procs: dict[str, subprocess.Popen]) -> dict[str, int]:
    """SIGTERM every child (replay first, agents last), wait, kill what hangs; exit statuses."""
    for proc in reversed(list(procs.values())):
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT
    status = {}
    for name, proc in procs.items():
        try:
            status[name] = proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            status[name] = proc.wait()
            print(f"up: {name} did not stop within {STOP_TIMEOUT:.0f} s and was killed", file=sys.stderr)
    return status


def run(args: argparse.Namespace) -> int:
    if args.exit_at_end and args.source is None:
        raise CommandError("--exit-at-end needs a DIR to replay")
    if args.speed < 0:
        raise CommandError(f"--speed must be ≥ 0, got {args.speed}")
    if args.record is not None and not args.record.endswith(".mcap"):
        raise CommandError(f"--record {args.record}: a recording's name must end in .mcap")
    net = args.net or _source_net(args.source) or "default"
    options = replace(tracker_options(args), speed=None)  # --speed here is the replay's
    try:
        make_tracker_check(args.tracker, options)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    commands = stack_commands(tracker=args.tracker, endpoint=args.listen, net=net, source=args.source,
                              speed=args.speed, loop=args.loop, record=args.record, estimates=options.estimates,
                              tracker_args=tracker_arguments(options),
                              view_port=args.view_port if getattr(args, "view", False) else None,
                              view_bind=getattr(args, "view_bind", "127.0.0.1"))
    if args.secure:
        commands, config = secure_up(commands, args.certs, args.listen)
    else:
        config = router_config([args.listen])
    try:
        router = zenoh.open(config)
    except zenoh.ZError as exc:
        raise CommandError(f"cannot start the router on {args.listen} ({str(exc).split(' at ')[0]}); "
                           "is another one running? choose another with --listen") from None
    keys = Keys(net)
    monitor = Monitor(keys)
    subscriber = router.declare_subscriber(keys.all(), monitor.on_sample)
    procs: dict[str, subprocess.Popen] = {}
    interrupted = False
    failed: str | None = None
    last_stage = "recorder" if args.record else "basestation"
    try:
        for command in commands:
            procs[command.name] = subprocess.Popen(command.argv(sys.executable))
        print(f"up: router on {args.listen}, network {net}, services: {', '.join(procs)}", file=sys.stderr)
        if "view" in procs:
            print(f"up: map on {page_url(args.view_bind, args.view_port)}", file=sys.stderr, flush=True)
        before, t_before = Counter(), time.monotonic()
        while True:
            time.sleep(0.1)
            for name, proc in procs.items():
                code = proc.poll()
                # replay and the recorder end by themselves (status 0) at the end of the stream
                if code is not None and (code != 0 or name not in ("replay", "recorder")):
                    failed = f"{name} exited with status {code}"
                    if name == "view":
                        failed += f" (is port {args.view_port} taken? choose another with --view-port, or --no-view)"
            if failed:
                break
            counts, event_time, done = monitor.snapshot()
            now = time.monotonic()
            if now - t_before >= args.progress_interval:
                print(_progress_line(counts, before, now - t_before, event_time), file=sys.stderr)
                before, t_before = counts, now
            finished = last_stage in done or (last_stage == "recorder" and procs["recorder"].poll() == 0)
            if args.exit_at_end and finished:
                if counts != before:
                    print(_progress_line(counts, before, max(now - t_before, 1e-9), event_time), file=sys.stderr)
                print("up: the end of the replay has been processed; stopping", file=sys.stderr)
                break
    except KeyboardInterrupt:
        interrupted = True
        print("\nup: stopping", file=sys.stderr)
    finally:
        # children got Ctrl-C too when run from a terminal; SIGTERM covers the other cases
        status = _stop(procs)
        subscriber.undeclare()
        router.close()
    if failed:
        print(f"up: {failed}; stopped the others", file=sys.stderr)
        return 1
    bad = {name: code for name, code in status.items() if code not in (0, -signal.SIGTERM, -signal.SIGINT)}
    if bad:
        print(f"up: services ended with errors: {bad}", file=sys.stderr)
        return 1
    return 130 if interrupted else 0

