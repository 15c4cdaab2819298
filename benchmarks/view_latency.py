"""Push latency of the map: from a `tracks` message put on the bus to the page that draws it.

    python benchmarks/view_latency.py [--messages 600] [--rate 20] [--tracks 5]

An in-process Zenoh router, the view service as a subprocess (``python -m
bintrack.services.view``), a page open in headless chromium. This script puts ``TrackSet``
messages on ``bintrack/bench/tracks`` at ``--rate`` per second and stamps each with the wall
clock just before the put; the page stamps each scan when its WebSocket message arrives
(``performance.timeOrigin + performance.now()``, same machine clock). Baseline, in the same
run: a plain Zenoh subscriber in this process (a client of the same router) stamping the same
messages, i.e. the bus hop alone. Prints p50, p90, p99 and max of both, and their ratio.
"""

from __future__ import annotations

import argparse
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from bintrack.live.session_options import client_config, router_config
from bintrack.bus_payloads import Track, TrackSet
from bintrack.deployment_model import Deployment
from bintrack.message_codec import encode

from bench_support import REPO, free_port
LAUNCH_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync"]



def quantiles(values: list[float]) -> str:
    v = sorted(values)
    q = lambda p: v[min(len(v) - 1, int(p * len(v)))]  # noqa: E731
    return f"p50 {q(0.50):7.2f} ms | p90 {q(0.90):7.2f} ms | p99 {q(0.99):7.2f} ms | max {v[-1]:7.2f} ms"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=600)
    parser.add_argument("--rate", type=float, default=20.0, help="tracks messages per second")
    parser.add_argument("--tracks", type=int, default=5, help="tracks per message")
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))   # stop what was started (finally) on SIGTERM
    browser_path = next((p for p in ("/usr/bin/chromium-headless-shell", "/usr/bin/chromium") if Path(p).exists()),
                        shutil.which("chromium-headless-shell"))
    if browser_path is None:
        print("needs Debian's chromium-headless-shell (apt-get install chromium-headless-shell)", file=sys.stderr)
        return 2
    from playwright.sync_api import sync_playwright

    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    deployment = Deployment.model_validate_json((REPO / "datasets" / "darpa-grid-3" / "deployment.json").read_text())
    deployment = deployment.model_copy(update={"name": "bench"})
    router = zenoh.open(router_config([endpoint]))
    session = zenoh.open(client_config([endpoint]))
    # the deployment, as replay would serve it
    queryable = session.declare_queryable("bintrack/bench/deployment",
                                          lambda q: q.reply("bintrack/bench/deployment", encode(deployment)))
    bus_arrivals: dict[float, float] = {}
    lock = threading.Lock()

    def on_tracks(sample: zenoh.Sample) -> None:
        now = time.time() * 1000
        with lock:
            bus_arrivals[len(bus_arrivals)] = now

    subscriber = session.declare_subscriber("bintrack/bench/tracks", on_tracks)
    log = tempfile.NamedTemporaryFile("w+", suffix=".log", delete=False)
    view = subprocess.Popen([sys.executable, "-m", "bintrack.services.view", "--port", str(port), "-e", endpoint,
                             "--net", "bench"], stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    sent: list[float] = []
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=browser_path, args=LAUNCH_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 800})
            deadline = time.monotonic() + 60
            while True:
                try:
                    page.goto(f"http://127.0.0.1:{port}/")
                    break
                except Exception:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.3)
            page.wait_for_function("bintrack.S.deployment !== null", timeout=60_000)
            period = 1.0 / args.rate
            start = time.monotonic()
            for i in range(args.messages):
                tracks = [Track(track=k, x=5.0 * k + 0.01 * i, y=20.0 + 0.01 * i, vx=1.0, vy=0.5)
                          for k in range(args.tracks)]
                payload = encode(TrackSet(t=float(i + 1), tracker="bench", tracks=tracks))
                sent.append(time.time() * 1000)
                session.put("bintrack/bench/tracks", payload)
                time.sleep(max(0.0, start + (i + 1) * period - time.monotonic()))
            page.wait_for_function(f"bintrack.trackArrivals.length > 0 && "
                                   f"bintrack.trackArrivals[bintrack.trackArrivals.length - 1][0] >= {args.messages}",
                                   timeout=60_000)
            arrivals = page.evaluate("bintrack.trackArrivals")
            browser.close()
    finally:
        view.terminate()
        view.wait(timeout=30)
        subscriber.undeclare()
        queryable.undeclare()
        session.close()
        router.close()
    page_ms = [received - sent[int(t) - 1] for t, received in arrivals if 1 <= t <= args.messages]
    bus_ms = [bus_arrivals[i] - sent[i] for i in range(min(len(sent), len(bus_arrivals)))]
    print(f"{args.messages} tracks messages at {args.rate:g}/s, {args.tracks} tracks each; "
          f"{len(page_ms)} reached the page, {len(bus_ms)} the plain subscriber")
    print(f"bus -> view -> page (WebSocket): {quantiles(page_ms)}")
    print(f"bus -> plain Zenoh subscriber:   {quantiles(bus_ms)}")
    ratio = sorted(page_ms)[len(page_ms) // 2] / max(1e-9, sorted(bus_ms)[len(bus_ms) // 2])
    print(f"ratio of the medians (page / bus alone): {ratio:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
