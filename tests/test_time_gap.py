"""A gap in time is bounded (issue: no silent loss): one event 1e9 s after the data gives the
offline rows, offline and live, with memory and time of the data alone. The memory is the
largest resident set of the command's processes (a scan-by-scan loop through the gap took
gigabytes within seconds); the time is bounded only by a timeout such a loop would overrun by
orders of magnitude (speed is measured in benchmarks/, not asserted)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from bintrack.cli import main as cli
from bintrack.formats import read_tracks

from support import DATASETS, REPO, free_port

DARPA3 = DATASETS / "darpa-grid-3"
TIMEOUT = 120.0  # s: the data alone takes a few; 1e9 s of 0.5 s scans would take years
MAX_RSS_MB = 300

# runs argv, then prints the largest resident set (kB) of any process it waited for
_MEASURED = ("import resource, subprocess, sys; p = subprocess.run(sys.argv[1:]); "
             "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(p.returncode)")


def measured(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    """``bintrack ARGS`` under a timeout: the finished process and its peak memory (MB)."""
    done = subprocess.run([sys.executable, "-c", _MEASURED, sys.executable, "-m", "bintrack.cli", *args],
                          capture_output=True, text=True, cwd=REPO, timeout=TIMEOUT)
    return done, int(done.stderr.strip().splitlines()[-1]) / 1024


@pytest.fixture(scope="module")
def gap_dataset(tmp_path_factory) -> Path:
    """darpa-grid-3 with one more event, a detection at t = 1e9 s."""
    folder = tmp_path_factory.mktemp("gap") / "dataset"
    shutil.copytree(DARPA3, folder)
    with open(folder / "events.csv", "a") as events:
        events.write("1000000000,n070,1\n")
    return folder


@pytest.fixture(scope="module")
def offline_rows(tmp_path_factory):
    out = tmp_path_factory.mktemp("offline") / "tracks.csv"
    assert cli.main(["track", str(DARPA3), "--tracker", "mcmcda", "--out", str(out)]) == 0
    return read_tracks(out)


def test_offline_a_gap_of_1e9_s_costs_no_more_than_the_data(gap_dataset, offline_rows, tmp_path):
    out = tmp_path / "tracks.csv"
    done, peak = measured("track", str(gap_dataset), "--tracker", "mcmcda", "--out", str(out))
    assert done.returncode == 0, done.stderr[-2000:]
    assert read_tracks(out) == offline_rows
    assert peak < MAX_RSS_MB
    warnings = [line for line in done.stderr.splitlines() if "spans 1e+09 s of event time" in line]
    assert len(warnings) == 1 and "longest silence" in warnings[0]


def test_live_replay_jumps_the_gap_and_gives_the_offline_rows(gap_dataset, offline_rows, tmp_path):
    recording = tmp_path / "gap.mcap"
    done, peak = measured("up", str(gap_dataset), "--speed", "0", "--tracker", "mcmcda", "--record", str(recording),
                          "--exit-at-end", "--listen", f"tcp/127.0.0.1:{free_port()}", "--no-map")
    assert done.returncode == 0, done.stderr[-3000:]
    jumps = [line for line in done.stderr.splitlines() if "replay: jumping over" in line]
    assert len(jumps) == 1 and "1e+09 s of empty event time" in jumps[0]
    assert peak < MAX_RSS_MB
    exported = tmp_path / "tracks.csv"
    assert cli.main(["export", str(recording), "--what", "tracks", "--out", str(exported)]) == 0
    assert read_tracks(exported) == offline_rows
