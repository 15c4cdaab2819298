"""The map's memory over a long run: a page left open on `bintrack up` replaying darpa-grid-3 in a
loop at --speed 4 (mcmcda), the view server's RSS sampled, the page's frame rate measured.

    python benchmarks/view_memory.py [--minutes 10] [--every 10] [--speed 4]

Prints the view server's RSS (MiB) at each sample, then first minute vs last minute, the
largest, and the slope (MiB per minute, least squares after the first minute); beside it the
same figures for the base station in the same run, as a baseline of a service whose state is
bounded. Needs chromium-headless-shell (Debian) for the page.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from bench_support import REPO, free_port, rss_mib
DATASET = REPO / "datasets" / "darpa-grid-3"
LAUNCH_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync"]



def children(pid: int) -> dict[str, int]:
    """bintrack service name -> pid, of the processes whose parent is ``pid``."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and len(cmdline) > 2 and cmdline[1] == b"-m":
            found[cmdline[2].decode().rsplit(".", 1)[-1]] = int(entry)
    return found


def slope(points: list[tuple[float, float]]) -> float:
    n = len(points)
    if n < 2:
        return float("nan")
    mx = sum(x for x, _ in points) / n
    my = sum(y for _, y in points) / n
    sxx = sum((x - mx) ** 2 for x, _ in points)
    return sum((x - mx) * (y - my) for x, y in points) / sxx if sxx else float("nan")


def summary(name: str, samples: list[tuple[float, float]]) -> str:
    first = [m for t, m in samples if t <= 60]
    last = [m for t, m in samples if t >= samples[-1][0] - 60]
    after = [(t / 60, m) for t, m in samples if t > 60]
    return (f"{name:12s} first minute {sum(first) / len(first):7.1f} MiB | last minute {sum(last) / len(last):7.1f} MiB"
            f" | max {max(m for _, m in samples):7.1f} MiB | slope after 1 min {slope(after):+.3f} MiB/min")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--every", type=float, default=10.0, help="s between samples")
    parser.add_argument("--speed", type=float, default=4.0)
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))   # stop what was started (finally) on SIGTERM
    browser_path = next((p for p in ("/usr/bin/chromium-headless-shell", "/usr/bin/chromium") if Path(p).exists()),
                        shutil.which("chromium-headless-shell"))
    if browser_path is None:
        print("needs Debian's chromium-headless-shell (apt-get install chromium-headless-shell)", file=sys.stderr)
        return 2
    from playwright.sync_api import sync_playwright

    port = free_port()
    up = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", str(DATASET), "--tracker", "mcmcda",
                           "--speed", str(args.speed), "--loop", "--listen", f"tcp/127.0.0.1:{free_port()}",
                           "--map-port", str(port), "--progress-interval", "60"], cwd=REPO)
    samples: dict[str, list[tuple[float, float]]] = {"view": [], "basestation": []}
    try:
        deadline = time.monotonic() + 60
        pids = {}
        while time.monotonic() < deadline and not {"view", "basestation"} <= set(pids):
            time.sleep(0.5)
            pids = children(up.pid)
        while time.monotonic() < deadline:   # the view's port answers
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1):
                    break
            except OSError:
                time.sleep(0.3)
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=browser_path,
                                                 args=LAUNCH_ARGS + ["--enable-precise-memory-info"])
            page = browser.new_page(viewport={"width": 1100, "height": 800})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("bintrack.trackLabels().length > 0", timeout=120_000)
            start = time.monotonic()
            print(f"{'wall s':>7} {'event t s':>10} {'view MiB':>9} {'basestation MiB':>16} {'page JS heap MiB':>17} "
                  f"{'median frame ms':>16}", flush=True)
            while time.monotonic() - start < args.minutes * 60:
                now = time.monotonic() - start
                for name in samples:
                    samples[name].append((now, rss_mib(pids[name], missing_ok=False)))
                page.evaluate("bintrack.resetFrames()")
                page.wait_for_function("bintrack.frameIntervals().length >= 60", timeout=60_000)
                intervals = sorted(page.evaluate("bintrack.frameIntervals()"))
                heap = page.evaluate("performance.memory ? performance.memory.usedJSHeapSize / 1048576 : NaN")
                t = page.evaluate("bintrack.S.t")
                print(f"{now:7.0f} {t:10.1f} {samples['view'][-1][1]:9.1f} {samples['basestation'][-1][1]:16.1f} "
                      f"{heap:17.1f} {intervals[len(intervals) // 2]:16.1f}", flush=True)
                time.sleep(max(0.0, args.every - (time.monotonic() - start - now)))
            status = page.inner_text("#status")
            browser.close()
        print(f"\npage status line at the end: {status}")
        for name, points in samples.items():
            print(summary(name, points))
    finally:
        up.send_signal(signal.SIGINT)   # `up` stops its services on Ctrl-C (SIGTERM would orphan them)
        up.wait(timeout=60)
    return 0


if __name__ == "__main__":
    sys.exit(main())
