"""One peer-agent process hosting all 800 nodes (arc tracker, R = 150): how much faster than
real time, beside the pure tracker in this process on the same data.

The live chain is real: a Zenoh router in this process on loopback, and replay (``--speed 0``,
as fast as flow control allows), a sensor agent, the peer agent and the base station as
subprocesses. This process counts the peer agent's estimates as they arrive; the live rate is
estimates / wall time from the first to the last, and the multiple of real time is the event
time they cover over that wall time.

Run: ``.venv/bin/python benchmarks/peer_agent.py [--runs 3] [--range 150]``
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from bintrack.live.session_options import router_config
from bintrack.formats import open_dataset, write_dataset
from bintrack.keys import Keys
from bintrack.bus_payloads import LocalEstimate
from bintrack.message_codec import decode
from bintrack.pipeline import run_tracker
from bintrack.sim.scenarios import simulate
from bintrack.live.stack import stack_commands
from bintrack.trackers import make_tracker


def free_endpoint() -> str:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


def live_run(folder: Path, expected: int) -> tuple[int, float, float]:
    """(estimates, wall s first→last, event-time s they span) through the real services;
    waits for the ``expected`` number of estimates (what the offline run gave)."""
    net = open_dataset(folder).deployment.name
    endpoint = free_endpoint()
    router = zenoh.open(router_config([endpoint]))
    arrivals: list[tuple[float, float]] = []
    lock = threading.Lock()

    def on_estimate(sample: zenoh.Sample) -> None:
        t = decode(LocalEstimate, sample.payload.to_bytes()).t
        with lock:
            arrivals.append((time.monotonic(), t))

    subscriber = router.declare_subscriber(Keys(net).estimate(), on_estimate)
    commands = stack_commands(tracker="arc", endpoint=endpoint, net=net, source=str(folder), speed=0)
    procs = [subprocess.Popen(c.argv(sys.executable), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for c in commands]
    try:
        if procs[-1].wait(timeout=600) != 0:  # replay ends after the last tick is acknowledged
            raise SystemExit("replay failed")
        deadline = time.monotonic() + 60
        while len(arrivals) < expected and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
        subscriber.undeclare()
        router.close()
    wall = arrivals[-1][0] - arrivals[0][0]
    span = max(t for _, t in arrivals) - min(t for _, t in arrivals)
    return len(arrivals), wall, span


def offline_run(folder: Path) -> tuple[int, float]:
    dataset = open_dataset(folder)
    start = time.perf_counter()
    count = sum(1 for _ in run_tracker(dataset, make_tracker("arc", dataset.deployment)))
    return count, time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs (seeds) (default: %(default)s)")
    parser.add_argument("--range", type=float, default=150.0, help="sensing range R (default: %(default)s)")
    args = parser.parse_args()
    live, offline = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.runs):
            result = simulate("uniform-800", seed=seed, sensing_range=args.range, trajectory="random")
            folder = write_dataset(Path(tmp) / f"r{seed}", *result)
            print(f"run {seed + 1}/{args.runs}: {len(result.events)} events, 800 nodes", file=sys.stderr)
            offline.append(offline_run(folder))
            count, wall, span = live_run(folder, expected=offline[-1][0])
            live.append((count, wall, span))
            print(f"  live: {count} estimates in {wall:.3f} s wall; pure: {offline[-1][0]} in {offline[-1][1]:.3f} s",
                  file=sys.stderr)
    print(f"arc tracker, 800 nodes on 800 × 800, R = {args.range:g}, speed R/15, random trajectory, {args.runs} runs (median)")
    rate = statistics.median(c / w for c, w, _ in live)
    multiple = statistics.median(s / w for _, w, s in live)
    pure_rate = statistics.median(c / s for c, s in offline)
    pure_multiple = statistics.median(span / s for (_, s), (_, _, span) in zip(offline, live))
    print(f"{'':38}{'estimates/s':>14}{'× real time':>14}")
    print(f"{'one peer-agent process (live, Zenoh)':38}{rate:>14,.0f}{multiple:>14,.1f}")
    print(f"{'the pure tracker in this process':38}{pure_rate:>14,.0f}{pure_multiple:>14,.1f}")
    print(f"ratio live / pure: {rate / pure_rate:.2f}; estimates per run: {statistics.median(c for c, _, _ in live):.0f} "
          f"over {statistics.median(s for _, _, s in live):.1f} s of event time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
