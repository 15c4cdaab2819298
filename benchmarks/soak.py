"""Soak: an hour of event time of a 10-person grid through the whole stack, memory sampled.

    nice -n 10 python benchmarks/soak.py [--duration 3600] [--people 10] [--seed 11]
        [--interval 30] [--out out/soak]

Simulates ``darpa-grid --people N --duration D`` (arrivals spread over the hour), runs
``bintrack up DATASET --tracker mcmcda --speed 0 --loop --record`` and samples the resident
memory (RSS, from /proc) of every service every ``--interval`` s of wall clock, until event
time passes D (the end of the first pass); then stops ``up`` with SIGTERM. Prints a table of
RSS per service against event time and its growth after the first 5 minutes of event time
(baseline: the first sample at ≥ 300 s; growth: the largest later sample over it), writes the
PNG ``OUT/soak.png``, and checks that the recording holds every track set of the pass: its
exported rows equal the rows of ``bintrack track`` on the dataset.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench_support import bintrack, free_port, rss_mib

SERVICES = ("sensor_agent", "basestation", "recorder", "replay")
BASELINE_T = 300.0  # s of event time: growth is measured from here on



def services_of(up_pid: int) -> dict[str, int]:
    """service name → pid of up's children (from their --id up<pid>-<name>)."""
    found = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmd = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            for i, arg in enumerate(cmd[:-1]):
                if arg == b"--id" and cmd[i + 1].startswith(f"up{up_pid}-".encode()):
                    found[cmd[i + 1].decode().split("-", 1)[1]] = int(entry)
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3600.0, help="event time of the dataset, s")
    parser.add_argument("--people", type=int, default=10)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--interval", type=float, default=30.0, help="wall-clock seconds between RSS samples")
    parser.add_argument("--out", default="out/soak")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    dataset, recording = out / "dataset", out / "soak.mcap"
    bintrack("simulate", "darpa-grid", "--people", str(args.people), "--seed", str(args.seed),
             "--duration", f"{args.duration:g}", "--out", str(dataset))

    up = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", str(dataset), "--tracker", "mcmcda",
                           "--speed", "0", "--loop", "--record", str(recording), "--no-view",
                           "--listen", f"tcp/127.0.0.1:{free_port()}", "--progress-interval", "1"],
                          stderr=subprocess.PIPE, text=True)
    event_time = [0.0]
    log_lines: list[str] = []

    def read() -> None:
        for line in up.stderr:
            log_lines.append(line)
            match = re.match(r"up: t=\s*([\d.]+) s", line)
            if match:
                event_time[0] = float(match.group(1))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    started = time.monotonic()
    samples: list[tuple[float, float, dict[str, float]]] = []  # (wall s, event s, service → MB)
    try:
        while event_time[0] < args.duration and up.poll() is None:
            pids = services_of(up.pid)
            samples.append((time.monotonic() - started, event_time[0],
                            {name: rss_mib(pid) for name, pid in pids.items()}))
            print(f"soak: wall {samples[-1][0]:7.0f} s  event {event_time[0]:7.1f} s  " +
                  "  ".join(f"{k} {v:.1f} MB" for k, v in sorted(samples[-1][2].items()) if v), flush=True)
            deadline = time.monotonic() + args.interval
            while time.monotonic() < deadline and event_time[0] < args.duration and up.poll() is None:
                time.sleep(0.5)
        pids = services_of(up.pid)
        samples.append((time.monotonic() - started, event_time[0], {n: rss_mib(p) for n, p in pids.items()}))
    finally:
        wall = time.monotonic() - started
        up.send_signal(signal.SIGTERM)
        status = up.wait()
        reader.join(timeout=10)
    if status not in (0, 128 + signal.SIGTERM):
        print("".join(log_lines[-40:]), file=sys.stderr)
        return 1

    names = sorted({n for _, _, rss in samples for n in rss})
    print(f"\nsoak: {args.duration:g} s of event time, {args.people} people, mcmcda at --speed 0 with --loop "
          f"--record, in {wall:.0f} s of wall clock ({args.duration / wall:.1f}× real time)\n")
    print(f"{'wall s':>7} {'event s':>8} " + " ".join(f"{n:>13}" for n in names))
    for w, t, rss in samples:
        print(f"{w:7.0f} {t:8.1f} " + " ".join(f"{rss.get(n) or float('nan'):10.1f} MB" for n in names))
    print(f"\nRSS growth after the first {BASELINE_T:.0f} s of event time (largest later sample / first at ≥ "
          f"{BASELINE_T:.0f} s):")
    worst = 0.0
    for n in names:
        later = [(t, rss[n]) for _, t, rss in samples if t >= BASELINE_T and rss.get(n)]
        if len(later) < 2:
            print(f"  {n:13} too few samples after {BASELINE_T:.0f} s")
            continue
        base = later[0][1]
        growth = (max(v for _, v in later) - base) / base
        worst = max(worst, growth)
        print(f"  {n:13} {base:7.1f} MB → max {max(v for _, v in later):7.1f} MB, end {later[-1][1]:7.1f} MB: "
              f"{100 * growth:+.1f} %  {'≤ 5 %' if growth <= 0.05 else '> 5 %'}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for n in names:
        ax.plot([t for _, t, rss in samples if rss.get(n)], [rss[n] for _, _, rss in samples if rss.get(n)],
                marker=".", label=n)
    ax.axvline(BASELINE_T, color="grey", linestyle=":", label="first 5 min")
    ax.set_xlabel("event time, s")
    ax.set_ylabel("RSS, MB")
    ax.set_title(f"soak: {args.people}-person grid, mcmcda, --speed 0 --loop --record")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "soak.png", dpi=120)
    print(f"\nsoak: wrote {out / 'soak.png'}")

    # every track set of the first pass is in the recording: exported rows = offline rows
    exported, offline = out / "exported.csv", out / "offline.csv"
    bintrack("export", str(recording), "--what", "tracks", "--out", str(exported))
    bintrack("track", str(dataset), "--tracker", "mcmcda", "--out", str(offline))
    from bintrack.formats import read_tracks

    offline_rows = read_tracks(offline)
    last = max(r.t for r in offline_rows)
    live_rows = [r for r in read_tracks(exported) if r.t <= last]
    same = live_rows == offline_rows
    print(f"soak: recording: {len(live_rows)} track rows of the first pass, offline {len(offline_rows)}: "
          f"{'identical' if same else 'DIFFERENT'} (track sets with t ≤ {last:.1f} s)")
    return 0 if same and worst <= 0.05 else 1


if __name__ == "__main__":
    raise SystemExit(main())
