"""Shared fixtures: small datasets written the way another program would (json + csv only), a
Zenoh router, services in subprocesses. The helpers they use are in support.py."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from support import ServiceProcess, free_port


def pytest_configure(config):
    # pytest-xdist's workers ignore SIGINT (Ctrl-C is for the controller), and the programs a
    # test starts would inherit that; the tests interrupt them with SIGINT as a user would.
    if os.environ.get("PYTEST_XDIST_WORKER"):
        signal.signal(signal.SIGINT, signal.default_int_handler)


# Started first, so that one worker runs them while the others share out the rest of the files.
LONGEST_FILES = ("test_compose_engine.py",)


def pytest_collection_modifyitems(session, config, items):
    # the order pytest-xdist hands out files in (`make test` runs it with --no-loadscope-reorder):
    # these first, then as xdist would order them by itself, the files with most tests first
    per_file = Counter(item.path.name for item in items)
    items.sort(key=lambda item: (item.path.name not in LONGEST_FILES, -per_file[item.path.name]))


def write_foreign_dataset(folder: Path, *, nodes: int = 200, size: float = 200.0, sensing_range: float = 20.0,
                          speed: float = 2.0, seed: int = 1) -> Path:
    """A uniform disk deployment with a target on y = size/2, transitions computed by hand.

    Written with json and csv alone, as a program outside bintrack would.
    """
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, size, (nodes, 2))
    sensors = [{"id": f"n{i}", "kind": "disk", "x": float(x), "y": float(y), "range": sensing_range}
               for i, (x, y) in enumerate(xy)]
    (folder / "deployment.json").write_text(json.dumps({
        "format": "bintrack.deployment/1", "name": "foreign", "units": "m",
        "region": {"xmin": 0, "ymin": 0, "xmax": size, "ymax": size}, "sensors": sensors}))
    x_start, x_end, y_line = 0.1 * size, 0.9 * size, size / 2
    events = []
    for s in sensors:
        dy = s["y"] - y_line
        if abs(dy) < sensing_range:
            half = math.sqrt(sensing_range**2 - dy**2)
            for x, value in ((s["x"] - half, 1), (s["x"] + half, 0)):
                if x_start <= x <= x_end:
                    events.append(((x - x_start) / speed, s["id"], value))
    events.sort()
    with open(folder / "events.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", "sensor", "value"])
        writer.writerows((f"{t:.6f}", sid, v) for t, sid, v in events)
    with open(folder / "truth.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", "target", "x", "y"])
        writer.writerows([(0, "a", x_start, y_line), ((x_end - x_start) / speed, "a", x_end, y_line)])
    return folder


@pytest.fixture
def foreign_dataset(tmp_path: Path) -> Path:
    return write_foreign_dataset(tmp_path / "foreign")


# --------------------------------------------------------------------------- live system


@pytest.fixture
def zenoh_router():
    """A real Zenoh router in this process on a free loopback port; yields its endpoint."""
    import zenoh

    from bintrack.live.session_options import router_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(router_config([endpoint]))
    try:
        yield endpoint
    finally:
        router.close()


@pytest.fixture
def services(tmp_path):
    """Start services with ``services(name, *args, endpoint=...)``; all are stopped at the end."""
    started: list[ServiceProcess] = []

    def start(name: str, *args: str, endpoint: str) -> ServiceProcess:
        proc = ServiceProcess(name, list(args), endpoint, tmp_path)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        if proc.proc.poll() is None:
            proc.proc.kill()
            proc.proc.wait()
