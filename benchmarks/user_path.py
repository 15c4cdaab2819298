"""The user's path, for ``benchmarks/bus.py`` part 5: whole commands as a user types them, each
a process timed from its start to its exit (start-up included), on the full stack's dataset.

* ``bintrack track DIR --tracker mcmcda`` (offline, one process);
* ``bintrack up DIR --tracker mcmcda --no-view --speed 0 --exit-at-end --record FILE``: the
  embedded router, the services as subprocesses and ``up``'s own watching of the bus; its
  start-up is the time from its start to the first raw sample's receipt in the recording
  (the recorder's clock), and its recorded track rows are held to the offline ones;
* ``bintrack demo --no-map`` (the shipped 3-person dataset, also exported, scored and plotted).

Each round runs the three once; bus.py alternates the rounds with the benchmark's own
full-stack run (the services started without ``up``) and reports medians.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from bintrack.cli.export_command import track_rows
from bintrack.live.recording import open_recording

from bench_support import REPO, free_port

UP_TIMEOUT = 1800.0  # s


@dataclass
class UserRound:
    track_wall: float  # s, `bintrack track`, whole process
    up_wall: float  # s, `bintrack up … --record`, whole process
    up_startup: float  # s, its start → the first raw sample recorded
    up_identical: bool  # its recorded track rows are the offline ones
    demo_wall: float  # s, `bintrack demo --no-map`, whole process


def _bintrack(args: list[str], log: Path, timeout: float = UP_TIMEOUT) -> tuple[float, float]:
    """Run ``bintrack ARGS`` (output to ``log``); (wall clock at its start, s since the epoch; its
    wall time, s). RuntimeError if it fails."""
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_CONFIG"}
    with open(log, "w") as out:
        started, t0 = time.time(), time.perf_counter()
        result = subprocess.run([sys.executable, "-m", "bintrack.cli", *args], stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, cwd=REPO, env=env, timeout=timeout)
        wall = time.perf_counter() - t0
    if result.returncode != 0:
        tail = "\n".join(log.read_text().splitlines()[-15:])
        raise RuntimeError(f"bintrack {args[0]} exited with status {result.returncode}; its output ends:\n{tail}")
    return started, wall


def user_round(source: Path, offline_rows: list, work: Path, k: int, say) -> UserRound:
    """One round: offline track, up with a recording, demo."""
    _, track_wall = _bintrack(["track", str(source), "--tracker", "mcmcda", "--out", str(work / f"user{k}-track.csv")],
                              work / f"user{k}-track.log")
    say(f"user's path round {k}: bintrack track in {track_wall:.1f} s")
    recording = work / f"user{k}-up.mcap"
    started, up_wall = _bintrack(["up", str(source), "--tracker", "mcmcda", "--no-view", "--speed", "0",
                                  "--exit-at-end", "--record", str(recording),
                                  "--listen", f"tcp/127.0.0.1:{free_port()}"], work / f"user{k}-up.log")
    recorded = open_recording(recording)
    first_raw = min(r.received_ns for r in recorded.records(lambda key: "/raw/" in key)) / 1e9
    identical = track_rows(recorded, "tracks") == offline_rows
    say(f"user's path round {k}: bintrack up --record in {up_wall:.1f} s, first raw sample after "
        f"{first_raw - started:.2f} s, rows identical: {identical}")
    _, demo_wall = _bintrack(["demo", "--no-map", "--out", str(work / f"user{k}-demo")], work / f"user{k}-demo.log")
    say(f"user's path round {k}: bintrack demo in {demo_wall:.1f} s")
    return UserRound(track_wall, up_wall, first_raw - started, identical, demo_wall)


def user_rows(rounds: list[UserRound], harness: list[float], span: float) -> list[tuple[str, str, str]]:
    """The table's rows (figure, value, unit): medians of ``rounds`` beside the median of the
    benchmark's own full-stack runs (``harness``, × real time) over the same ``span`` s."""
    def median(values) -> float:
        return statistics.median(values)

    n = len(rounds)
    up_wall, startup = median(r.up_wall for r in rounds), median(r.up_startup for r in rounds)
    return [
        (f"user's path, same dataset: services started by this benchmark (part 3), median of {len(harness)}",
         f"{median(harness):,.0f}", "× real time"),
        (f"  bintrack track DIR --tracker mcmcda, whole process, median of {n}",
         f"{span / median(r.track_wall for r in rounds):,.0f}", "× real time"),
        (f"  bintrack up DIR --tracker mcmcda --no-view --speed 0 --exit-at-end --record F, whole process, median "
         f"of {n}", f"{span / up_wall:,.0f}", "× real time"),
        ("    its wall time; after its start-up", f"{up_wall:.1f}; {span / (up_wall - startup):,.0f}",
         "s; × real time"),
        (f"    its start-up: start → first raw sample recorded, median of {n}", f"{startup:.2f}", "s"),
        ("    its recorded track rows identical to offline", "yes" if all(r.up_identical for r in rounds) else "NO", ""),
        (f"  bintrack demo --no-map (3 people, 90 s), whole process, median of {n}",
         f"{median(r.demo_wall for r in rounds):.1f}", "s"),
        ("  per round: harness × / up × / up start-up s",
         "; ".join(f"{h:.0f} / {span / r.up_wall:.0f} / {r.up_startup:.2f}" for h, r in zip(harness, rounds)), ""),
    ]
